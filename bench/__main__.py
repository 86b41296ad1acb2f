"""``python -m bench``: the ``cdpr`` command."""

import sys

from bench.cli import main

if __name__ == "__main__":
    sys.exit(main())
