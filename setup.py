"""Build step only: bake the git commit into the wheel (``bench/_build_commit.py``):
``CDPR_BUILD_COMMIT`` if set, else the checkout's, else ``unknown``.

Everything else is in pyproject.toml.
"""

import os
import sys
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent


class BuildWithCommit(build_py):
    def run(self) -> None:
        super().run()
        if getattr(self, "editable_mode", False):
            return  # an editable install looks the commit up with git at run time
        sys.path.insert(0, str(HERE))
        from bench.version import git_commit

        commit = os.environ.get("CDPR_BUILD_COMMIT") or git_commit(HERE) or "unknown"
        target = Path(self.build_lib) / "bench" / "_build_commit.py"
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(f'"""Written at build time."""\n\nCOMMIT = {commit!r}\n')


setup(cmdclass={"build_py": BuildWithCommit})
