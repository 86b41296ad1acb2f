"""The benchmarks of ``cdpr bench``: this registry, and one module per subject beside it.

A benchmark is a plain function ``fn(quick: bool) -> dict[str, float]`` that
returns one or more keys (medians, in the unit its key names: ``_us``, ``_ms``,
``_s``). Modules register theirs with :func:`register`; ``cdpr bench`` imports
the modules listed in :data:`MODULES` and runs every registered function.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

BenchFn = Callable[[bool], dict[str, float]]

#: Modules whose import registers benchmarks. Add one line per module.
MODULES: tuple[str, ...] = (
    "bench.benchmarks.physics",
    "bench.benchmarks.diagnose",
    "bench.benchmarks.hil_modbus",
    "bench.benchmarks.hil_can",
    "bench.benchmarks.hil",
    "bench.benchmarks.trajectory",
    "bench.benchmarks.dryrun",
    "bench.benchmarks.paper",
    "bench.benchmarks.commission",
    "bench.benchmarks.master_loss",
    "bench.benchmarks.realtime_load",
    "bench.benchmarks.learn",
    "bench.benchmarks.live",
)

_REGISTRY: dict[str, BenchFn] = {}


def register(name: str) -> Callable[[BenchFn], BenchFn]:
    """Decorator: register ``fn`` under ``name`` (a group name shown in progress)."""

    def deco(fn: BenchFn) -> BenchFn:
        _REGISTRY[name] = fn
        return fn

    return deco


def registry() -> dict[str, BenchFn]:
    import importlib

    for m in MODULES:
        importlib.import_module(m)
    return dict(_REGISTRY)


def median_time(fn: Callable[[], object], repeat: int, warmup: int = 3) -> float:
    """Median wall time of ``fn()`` in seconds over ``repeat`` calls (after ``warmup``)."""
    for _ in range(warmup):
        fn()
    samples = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t0)
    return statistics.median(samples)
