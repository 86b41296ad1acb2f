"""Benchmark registry for ``cdpr bench``.

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
    "bench.bench_physics",
    "bench.bench_diagnose",
    "bench.bench_hil_modbus",
    "bench.bench_hil_can",
    "bench.bench_hil",
    "bench.bench_trajectory",
    "bench.bench_dryrun",
    "bench.bench_paper",
    "bench.bench_commission",
    "bench.bench_master_loss",
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
