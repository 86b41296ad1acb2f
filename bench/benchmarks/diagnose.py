"""Diagnosis benchmark: a campaign of about 200 samples with the paper's 36-parameter case."""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from importlib import resources
from pathlib import Path

from bench.benchmarks import register


def paper_campaign(out: Path, visits: int = 5) -> Path:
    """Record the paper's case (exit offsets + compliant masts, initialised on the side):
    40 target poses x ``visits`` visits + the initialisation dwell."""
    from bench.campaign import run_campaign
    from firmware_sim.scenario import load_scenario

    path = Path(str(resources.files("bench") / "data" / "paper_scenario.toml"))
    sc = load_scenario(path)
    sc.poses = type(sc.poses)(**{**sc.poses.__dict__, "visits": visits})
    return run_campaign(sc, out)


@register("diagnose")
def bench_diagnose(quick: bool) -> dict[str, float]:
    """``diagnose_s``: median wall time of ``cdpr diagnose`` (selection, fits, held-out checks,
    look-alikes, forward figures) on a 201-sample campaign whose answer is the paper's
    36-parameter set, with candidate fits on a 2-process pool; ``diagnose_samples``."""
    from bench.diagnosis.report import diagnose

    with tempfile.TemporaryDirectory() as d:
        rec = paper_campaign(Path(d) / "rec")
        times = []
        with ProcessPoolExecutor(min(2, os.cpu_count() or 1)) as pool:
            for _ in range(1 if quick else 3):
                t0 = time.perf_counter()
                dg = diagnose(rec, pool=pool)
                times.append(time.perf_counter() - t0)
        named = sorted(e["name"] for e in dg.report["effects"])
        if named != ["exit_point_offset", "mast_compliance"]:
            raise RuntimeError(f"benchmark diagnosis named {named}")
        return {"diagnose_s": statistics.median(times),
                "diagnose_samples": float(dg.report["samples"])}
