"""The benchmarks page of the documentation, generated from ``cdpr bench --json``.

    cdpr bench --json > bench.json
    python -m bench.benchmarks.page bench.json --out docs/benchmarks.md

The page says what each figure measures, and where it was measured: the date, the git
commit, the CPU model and count, the load average of the machine when the page was made
(run this right after the benchmarks) and the Python. Never edit the page by hand.
"""

from __future__ import annotations

import json
import math
import os
import platform
import sys
from datetime import UTC, datetime
from pathlib import Path

#: What each key measures (the unit is in the key's suffix).
WHAT: dict[str, str] = {
    "control_cycle_us": "IK + wrench matrix + tension distribution + mast update, 8 cables",
    "control_cycle_pulley_us": "the same with swivel pulleys of 0.1 m on every cable",
    "control_cycle_learn_us": "the control cycle with online identification: the sample "
                              "kept each cycle, the model handed over every 13 cycles, "
                              "the estimator updating on its own thread",
    "learn_handover_us": "one hand-over of the identified model to the controller",
    "ident_update_ms": "one online-identification update, 4 tracked samples",
    "equilibrium_ms": "warm-started elasto-static equilibrium, compliant masts",
    "dryrun_speedup": "lock-step dry run in one process: simulated time over wall time",
    "dryrun_cpu_speedup": "the same, simulated time over processor time",
    "realtime_rate_hz": "highest real-time rate against `cdpr sim` in another process with "
                        "deadline misses <= 0.1 % over 60 s",
    "realtime_sched_fifo": "1 when the loop's thread ran under SCHED_FIFO",
    "deadline_miss_ratio": "deadline misses at that rate, loop thread in SCHED_FIFO",
    "deadline_miss_ratio_normal_sched": "the same rate under the normal scheduler",
    "jitter_p99_ms": "99th percentile of the cycle start jitter at that rate",
    "realtime_process_completion": "real-time `--rig process` dry runs (10 s of path) that "
                                   "completed while another process kept one core busy",
    "realtime_process_runs": "how many such runs",
    "realtime_process_sched_fifo": "1 when their loop's thread ran under SCHED_FIFO",
    "diagnose_s": "`cdpr diagnose` of 201 samples (the paper's 36-parameter answer), "
                  "2 processes",
    "diagnose_hour_s": "`cdpr diagnose` (one process) of a continuous dry-run log of at "
                       "least an hour",
    "diagnose_hour_cpu_s": "the same, processor time",
    "diagnose_hour_recorded_s": "length of that recording",
    "diagnose_hour_rows": "rows of that recording",
    "diagnose_no_cells_s": "`cdpr diagnose` (one process) of the paper's campaign recorded "
                           "without load cells (tensions fitted to the cables' stretch)",
    "diagnose_no_cells_cpu_s": "the same, processor time",
    "diagnose_no_cells_samples": "samples of that campaign",
    "diagnose_300k_rows_s": "`cdpr diagnose` (2 processes) of a 20-minute three-rate log "
                            "(250 / 50 / 25 Hz, empty fields, no controller columns)",
    "diagnose_300k_rows": "rows of that log",
    "diagnose_8h_s": "`cdpr diagnose --json` (its own process) of an 8-hour three-rate log "
                     "read in blocks",
    "diagnose_8h_rss_mb": "peak resident memory of that process",
    "diagnose_8h_rows": "rows of that log",
    "diagnose_8h_generate_s": "time the 8-hour log took to make (cached; not diagnosis)",
    "read_csv_rows_per_s": "rows per second of the block-by-block columnar CSV reader on "
                           "the 8-hour log",
    "hil_can_cycle_ms": "8 RPDO + SYNC + 8 TPDO, in-process",
    "hil_can_cycle_tcp_ms": "the same over the socketcand hub",
    "hil_cycle_ms": "the same plus 8 Modbus reads and `read()`, in-process",
    "hil_cycle_tcp_ms": "the same against `cdpr sim`",
    "modbus_read_ms": "one synchronous read of the 8 load cells (Modbus/TCP)",
    "modbus_rtu_tcp_read_ms": "the same with RTU framing over TCP",
    "loadcell_read_us": "one poll of the 8 load cells, decoded",
    "paper_paths_s": "`cdpr dry-run paper-paths` without remeasured and paper-heavy: "
                     "calibration, diagnosis, 12 path runs, 2 processes",
    "trajectory_sample_us": "one trajectory sample (position)",
    "trajectory_sample_rot_us": "one trajectory sample with rotation",
    "path_check_calibration_s": "feasibility check of the whole calibration path",
    "commission_scan_s": "`cdpr commission scan` against the simulated robot",
    "commission_check_s": "`cdpr commission check` against the simulated robot",
    "commission_monitor_poll_ms": "one `cdpr commission monitor` poll",
    "qsa_s": "master loss: until every drive holds in Quick Stop Active",
    "qsa_each_s": "the same, per drive",
    "detect_lag_s": "master loss: until the first drive reacts",
    "stopped_s": "master loss: until every drive stands still",
    "speed_m_s": "cable speed when the master was lost",
    "realtime_rate_hz_live": "highest real-time rate (5 s of path, `--rig process`) with "
                             "deadline misses <= 0.1 % with `--live`, `--format mcap` and a "
                             "subscribed Foxglove client",
    "deadline_miss_ratio_live": "deadline misses at that rate",
    "realtime_rate_hz_plain": "the same run without the live view and the recording",
    "deadline_miss_ratio_plain": "deadline misses at that rate",
    "live_messages_received": "messages the Foxglove client received in that live run",
}


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def machine() -> dict[str, str]:
    """Where and when: date (UTC), commit, CPU model and count, load average, Python."""
    from bench.version import build_commit

    try:
        load = "{:.2f} / {:.2f} / {:.2f}".format(*os.getloadavg())
    except OSError:
        load = "unknown"
    return {
        "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "commit": build_commit(),
        "cpu": f"{_cpu_model()}, {os.cpu_count()} logical CPUs",
        "load": load,
        "python": f"{platform.python_implementation()} {platform.python_version()} "
                  f"({platform.machine()})",
    }


def _value(v: object) -> str:
    if isinstance(v, float):
        return "n/a" if not math.isfinite(v) else f"{v:.4g}"
    return str(v)


def page(results: dict[str, object], where: dict[str, str]) -> str:
    """The Markdown page."""
    lines = [
        "# Benchmarks", "",
        "<!-- generated by `python -m bench.benchmarks.page`: do not edit by hand -->", "",
        "Medians of `cdpr bench` (the unit is the key's suffix: `_us` microseconds, `_ms` "
        "milliseconds, `_s` seconds, `_hz` hertz; a `_ratio` is a fraction). A benchmark "
        "group not run for this page (`cdpr bench --only`) has no rows here.", "",
        "| | |", "| --- | --- |",
        f"| date | {where['date']} |", f"| commit | `{where['commit']}` |",
        f"| CPU | {where['cpu']} |",
        f"| load average (1 / 5 / 15 min) | {where['load']} |",
        f"| Python | {where['python']} |", "",
        "| key | median | what |", "| --- | --- | --- |",
    ]
    for key, v in results.items():
        if key == "machine":
            continue
        what = WHAT.get(key, "the benchmark failed" if key.endswith("_error") else "")
        lines.append(f"| `{key}` | {_value(v)} | {what} |")
    lines += ["", "Regenerate (the whole set takes tens of minutes on two cores; "
              "`--only GROUP` runs a subset, `cdpr bench --list` lists the groups):", "",
              "```sh", "make benchmarks              # or: make benchmarks BENCH='--only physics'",
              "```", ""]
    return "\n".join(lines)


def page_arguments(argv: list[str] | None, usage: str) -> tuple[str, Path | None] | None:
    """A page generator's arguments ``INPUT [--out PAGE]`` (``sys.argv`` when None): the
    input and the page's path (None: stdout); None, the usage printed, when they are not."""
    argv = list(sys.argv[1:] if argv is None else argv)
    out = None
    if len(argv) == 3 and argv[1] == "--out":
        out = Path(argv.pop(2))
        argv.pop(1)
    if len(argv) != 1:
        print(f"usage: {usage}", file=sys.stderr)
        return None
    return argv[0], out


def write_page(text: str, out: Path | None) -> None:
    """The page on stdout, or written to ``out``."""
    if out is None:
        sys.stdout.write(text)
    else:
        out.write_text(text, encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    """``BENCH.json [--out PAGE]``: the page on stdout, or written to PAGE once made (the
    commit is read before the page is touched, so it is not marked dirty by it)."""
    args = page_arguments(argv, "python -m bench.benchmarks.page BENCH.json "
                                "[--out docs/benchmarks.md]")
    if args is None:
        return 2
    src, out = args
    try:
        results = json.loads(Path(src).read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as e:
        print(f"{src}: cannot read the benchmark results: {e}", file=sys.stderr)
        return 1
    if not isinstance(results, dict) or "error" in results:
        print(f"{src}: not the output of `cdpr bench --json`", file=sys.stderr)
        return 1
    write_page(page(results, machine()), out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
