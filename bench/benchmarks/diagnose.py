"""Diagnosis benchmark: a campaign of about 200 samples with the paper's 36-parameter case."""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from importlib import resources
from pathlib import Path

from bench.benchmarks import register
from bench.parallel import worker_pool


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
        with worker_pool(min(2, os.cpu_count() or 1), share_cores=True) as pool:
            for _ in range(1 if quick else 3):
                t0 = time.perf_counter()
                dg = diagnose(rec, pool=pool)
                times.append(time.perf_counter() - t0)
        named = sorted(e["name"] for e in dg.report["effects"])
        if named != ["exit_point_offset", "mast_compliance"]:
            raise RuntimeError(f"benchmark diagnosis named {named}")
        return {"diagnose_s": statistics.median(times),
                "diagnose_samples": float(dg.report["samples"])}


@register("diagnose_no_cells")
def bench_diagnose_no_cells(quick: bool) -> dict[str, float]:
    """``diagnose_no_cells_s``: wall time of ``cdpr diagnose`` (one process) on the paper's
    campaign (:func:`paper_campaign`, 3 visits; 2 with ``--quick``) recorded without load
    cells, whose answer is still the paper's set: the tensions of every sample are fitted to
    the cables' stretch (:mod:`bench.diagnosis.internal_forces`) in every evaluation and
    every finite-difference column, the costliest path per sample (three quarters of a
    sensors-only log's time: 32006); ``diagnose_no_cells_cpu_s`` its processor time."""
    from dataclasses import replace

    from bench.campaign import run_campaign
    from bench.diagnosis.report import diagnose
    from bench.parallel import single_blas_thread
    from firmware_sim.scenario import load_scenario

    single_blas_thread()  # as `cdpr diagnose` runs
    sc = load_scenario(Path(str(resources.files("bench") / "data" / "paper_scenario.toml")))
    sc = replace(sc, recording=replace(sc.recording, load_cells=False),
                 poses=replace(sc.poses, visits=2 if quick else 3))
    with tempfile.TemporaryDirectory() as d:
        rec = run_campaign(sc, Path(d) / "rec")
        t0, c0 = time.perf_counter(), time.process_time()
        dg = diagnose(rec)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    named = sorted(e["name"] for e in dg.report["effects"])
    if named != ["exit_point_offset", "mast_compliance"]:
        raise RuntimeError(f"benchmark diagnosis without load cells named {named}")
    return {"diagnose_no_cells_s": wall, "diagnose_no_cells_cpu_s": cpu,
            "diagnose_no_cells_samples": float(dg.report["samples"])}


#: length of the long continuous recording [s] (the issue's "one-hour dry run")
HOUR_S = 3600.0


def hour_campaign(out: Path, rate_hz: float = 20.0, targets: int | None = None) -> Path:
    """Record the paper's case as a continuous log of at least an hour (a dry run's, without
    stops): the 40 grid targets (the first ``targets`` of them) visited in turn at 0.25 m/s,
    rows at ``rate_hz``, as many rounds as make an hour of straight-line motion (the moves'
    angles and accelerations make it longer: about two hours, 145,000 rows at 20 Hz)."""
    from dataclasses import replace

    import numpy as np

    from bench.campaign import run_campaign
    from firmware_sim.scenario import RecordingSpec, load_scenario

    path = Path(str(resources.files("bench") / "data" / "paper_scenario.toml"))
    sc = load_scenario(path)
    if targets is not None:
        chosen = sc.poses.generate(np.random.default_rng(sc.seed))[:targets]
        sc.poses = replace(sc.poses, kind="list", poses=tuple(map(tuple, chosen)))
    pts = sc.poses.generate(np.random.default_rng(0))[:, :3]
    hop = float(np.mean(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
    per_round = len(pts) * hop / sc.poses.speed_m_s
    sc.poses = replace(sc.poses, visits=max(1, int(np.ceil(HOUR_S / per_round))), dwell_s=0.0)
    sc.recording = RecordingSpec(kind="continuous", dwell_at_targets=False, rate_hz=rate_hz)
    return run_campaign(sc, out)


@register("diagnose_hour")
def bench_diagnose_hour(quick: bool) -> dict[str, float]:
    """``diagnose_hour_s``: wall time of ``cdpr diagnose`` (one process) on a one-hour
    continuous recording of the paper's case (``diagnose_hour_rows`` rows over
    ``diagnose_hour_recorded_s`` seconds);
    ``diagnose_hour_cpu_s`` its processor time. Recording it (the
    simulated plant settles at every row) takes minutes and is not timed."""
    from bench.diagnosis.report import diagnose
    from bench.parallel import single_blas_thread
    from bench.recording import read_recording

    single_blas_thread()  # as `cdpr diagnose` runs
    with tempfile.TemporaryDirectory() as d:
        rec = hour_campaign(Path(d) / "rec", rate_hz=10.0 if quick else 20.0)
        t0, c0 = time.perf_counter(), time.process_time()
        dg = diagnose(rec)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        named = sorted(e["name"] for e in dg.report["effects"])
        if named != ["exit_point_offset", "mast_compliance"]:
            raise RuntimeError(f"benchmark diagnosis of the one-hour recording named {named}")
        rows = float(dg.report["mismatch"]["samples"]["rows"])
        t = read_recording(rec).t
        return {"diagnose_hour_s": wall, "diagnose_hour_cpu_s": cpu,
                "diagnose_hour_rows": rows, "diagnose_hour_recorded_s": float(t[-1] - t[0])}


#: the three-rate log of ``diagnose_300k``: rows at the encoders' 250 Hz, load cells at
#: 50 Hz and the tracker at 25 Hz in the rows nearest their instants, empty fields where a
#: sensor had no sample, no controller columns
LOG_300K = {"rows_hz": 250.0, "encoders_hz": 250.0, "load_cells_hz": 50.0,
            "tracker_hz": 25.0, "empty": "", "controller_columns": False}


def three_rate_log(out: Path, targets: int = 16, visits: int = 2, physics_hz: float = 25.0
                   ) -> Path:
    """A 20-minute three-rate log (:data:`LOG_300K`, about 280,000 rows) of the ROCASPECT
    with nothing concealed: ``targets`` poses of the paper's grid visited ``visits`` times
    with 3 s dwells (:mod:`bench.logger_sim`)."""
    from dataclasses import replace

    import numpy as np

    from bench.logger_sim import LoggerSpec, write_log
    from firmware_sim.scenario import load_scenario

    path = Path(str(resources.files("bench") / "data" / "paper_scenario.toml"))
    sc = load_scenario(path)
    chosen = sc.poses.generate(np.random.default_rng(sc.seed))[:targets]
    sc = replace(sc, truth=sc.model, effects={},
                 poses=replace(sc.poses, kind="list", poses=tuple(map(tuple, chosen)),
                               visits=visits))
    return write_log(out, sc, LoggerSpec(**LOG_300K, physics_hz=physics_hz))


@register("diagnose_300k")
def bench_diagnose_300k(quick: bool) -> dict[str, float]:
    """``diagnose_300k_rows_s``: wall time of ``cdpr diagnose`` (2 processes) on a 20-minute
    three-rate log (:func:`three_rate_log`, ``diagnose_300k_rows`` rows, nothing concealed:
    the diagnosis must name nothing). Writing the log (the plant settles 28,000 times)
    takes minutes and is not timed; ``--quick``: 4 targets. (The reader's speed is measured
    on the 8-hour log: ``diagnose_8h``.)"""
    from bench.diagnosis.report import diagnose

    with tempfile.TemporaryDirectory() as d:
        rec = three_rate_log(Path(d) / "rec", targets=4 if quick else 16)
        _, rows = read_rate(rec)
        with worker_pool(min(2, os.cpu_count() or 1), share_cores=True) as pool:
            t0 = time.perf_counter()
            dg0 = diagnose(rec, pool=pool)
            wall = time.perf_counter() - t0
        named = sorted(e["name"] for e in dg0.report["effects"])
        if named or dg0.report["unexplained"]:
            raise RuntimeError(f"the three-rate log with nothing concealed: named {named}, "
                               f"unexplained {bool(dg0.report['unexplained'])}")
        return {"diagnose_300k_rows_s": wall, "diagnose_300k_rows": rows}


#: the 8-hour log of ``diagnose_8h``: rows at the encoders' 250 Hz (7.2 million), load cells
#: at 50 Hz and the tracker at 25 Hz in the rows nearest their instants, empty fields where a
#: sensor had no sample, no controller columns
LOG_8H = {**LOG_300K}
#: hours of the long log, dwell at each pose [s], physics steps [Hz] of its truth
HOURS_8H, DWELL_8H_S, PHYSICS_8H_HZ = 8.0, 180.0, 10.0
#: the long log's generator; a new version makes a new cached file
LOG_8H_VERSION = 2


def long_log(out: Path, hours: float = HOURS_8H) -> Path:
    """An ``hours``-long three-rate log (:data:`LOG_8H`) of the ROCASPECT with nothing
    concealed: the paper's grid of poses visited in turn, :data:`DWELL_8H_S` at each, as
    many rounds as fill the hours (:func:`bench.logger_sim.write_long_log`). The scenario's
    hysteresis is kept, its encoder drift is not: over hours a drift is a change during
    the campaign (0.4 mm in 8 h), something to find, not nothing."""
    from dataclasses import replace

    from bench.logger_sim import LoggerSpec, simulate_truth, write_long_log
    from firmware_sim.scenario import load_scenario

    path = Path(str(resources.files("bench") / "data" / "paper_scenario.toml"))
    sc = load_scenario(path)
    per_visit = DWELL_8H_S + 20.0  # a dwell and a move
    visits = int(hours * 3600.0 / per_visit / 40) + 2  # enough rounds; cut at the hours
    sc = replace(sc, truth=sc.model, effects={}, drift_m_per_s=0.0,
                 poses=replace(sc.poses, visits=visits, dwell_s=DWELL_8H_S))
    truth = simulate_truth(sc, PHYSICS_8H_HZ, until_s=hours * 3600.0)
    return write_long_log(out, sc, LoggerSpec(**LOG_8H, physics_hz=PHYSICS_8H_HZ), truth)


def cached_long_log() -> tuple[Path, float]:
    """The 8-hour log in the cache under the system's temporary folder (made once per
    :data:`LOG_8H_VERSION`) and the seconds it took to make (now or when it was made)."""
    import json
    import shutil

    cache = Path(tempfile.gettempdir()) / "cdpr-bench-cache" / f"log8h-v{LOG_8H_VERSION}"
    done = cache / "made.json"
    if done.exists():
        return cache / "rec", float(json.loads(done.read_text())["seconds"])
    shutil.rmtree(cache, ignore_errors=True)
    cache.mkdir(parents=True)
    t0 = time.perf_counter()
    long_log(cache / "rec")
    secs = time.perf_counter() - t0
    done.write_text(json.dumps({"seconds": secs}))
    return cache / "rec", secs


def run_measured(cmd: list[str]) -> tuple[float, float, bytes]:
    """Run ``cmd``; its wall time [s], its peak resident memory [MB] (the kernel's maximum
    resident set of that process, from wait4) and its standard output."""
    import subprocess

    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    out = proc.stdout.read() if proc.stdout else b""
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} ended with {proc.returncode}")
    return wall, usage.ru_maxrss / 1024.0, out


def read_rate(rec: Path) -> tuple[float, float]:
    """Rows per second of the block-by-block columnar reader (:func:`bench.chunked.iter_blocks`)
    over the samples files of ``rec`` (every row parsed into arrays), and the rows."""
    from bench.chunked import iter_blocks
    from bench.recording import _read_header, open_recording

    _, _, robot, _, samples = open_recording(rec)
    rows = 0
    t0 = time.perf_counter()
    for p in samples if isinstance(samples, list) else [samples]:
        for cols, _, _ in iter_blocks(p, _read_header(p, robot)):
            rows += len(cols["t"])
    return rows / (time.perf_counter() - t0), float(rows)


@register("diagnose_8h")
def bench_diagnose_8h(quick: bool) -> dict[str, float]:
    """``diagnose_8h_s``: wall time of ``cdpr diagnose --json`` (its own process, 2 jobs) on an
    8-hour three-rate log (:func:`long_log`: 7.2 million rows, nothing concealed: it must
    name nothing); ``diagnose_8h_rss_mb`` that process's peak resident memory;
    ``read_csv_rows_per_s`` the block reader's rows per second on that file (one pass,
    before the diagnosis); ``diagnose_8h_rows``; ``diagnose_8h_generate_s`` the
    time the log took to make (cached under the system's temporary folder per generator
    version; not part of the diagnosis). ``--quick``: a 1-hour log."""
    import json
    import sys

    if quick:
        d = tempfile.mkdtemp()
        t0 = time.perf_counter()
        rec = long_log(Path(d) / "rec", hours=1.0)
        gen = time.perf_counter() - t0
    else:
        rec, gen = cached_long_log()
    rate, rows = read_rate(rec)
    wall, rss, out = run_measured([sys.executable, "-m", "bench.cli", "diagnose", str(rec),
                                   "--json", "--quiet", "--jobs", "2"])
    rep = json.loads(out)
    named = sorted(e["name"] for e in rep.get("effects", []))
    if "error" in rep or named or rep.get("unexplained"):
        raise RuntimeError(f"the 8-hour log with nothing concealed: named {named}, "
                           f"unexplained {bool(rep.get('unexplained'))}, "
                           f"error {rep.get('error')} (in {wall:.0f} s, {rss:.0f} MB; "
                           f"reader {rate:.3g} rows/s)")
    if quick:
        import shutil

        shutil.rmtree(d, ignore_errors=True)
    return {"diagnose_8h_s": wall, "diagnose_8h_rss_mb": rss, "read_csv_rows_per_s": rate,
            "diagnose_8h_rows": rows, "diagnose_8h_generate_s": gen}
