"""The MCAP recording's names where older code imports them: see :mod:`bench.mcap`."""

from bench.mcap import *  # noqa: F403
from bench.mcap import __all__  # noqa: F401
from bench.mcap.can_tap import CanTap  # noqa: F401
from bench.mcap.recorders import TeeRecorder, dry_run_recorder  # noqa: F401
from bench.mcap.scene import quaternion  # noqa: F401
