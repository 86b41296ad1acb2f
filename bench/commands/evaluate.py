"""``cdpr evaluate --cases N``: blind evaluation of the diagnosis on generated cases.

Case ``k`` is :func:`bench.evaluate.run_case` of seed ``S + k``: a scenario with randomly
drawn concealed effects, its campaign on the plant, the diagnosis, and the score against
the truth. Cases run on a local process pool (``--jobs``) or, with ``--scheduler
ADDRESS``, on a Dask distributed cluster (every worker needs cdpr-bench installed).

``--out FILE`` appends one JSON line per case as it completes (a header line first
holds the case configuration): an interruption loses nothing, and a re-run with the same
FILE skips the seeds already there (``--retry-errors``: except the ones that raised). A
FILE made with another configuration (robot, effects, pose set) is refused.

A case that raises is recorded as an error (seed and message) and counted; the others
go on. A case that kills its worker process is an error too (``BrokenProcessPool``); the
cases that ran beside it run again (see :mod:`bench.parallel`).

``--compare A B`` runs nothing: it reads two evaluations (``--out`` files or ``--json``
outputs, A before a change and B after) and lists the cases whose answers differ
(:func:`bench.evaluate.compare`); exit status 1 when some differ, 0 when none.

Exit status: 0 all cases scored, 1 some case raised, 2 bad arguments or FILE, or the
scheduler cannot be reached, 130 interrupted (Ctrl-C), 143 terminated (SIGTERM): under
``--json`` the object then holds ``"error"`` and the cases finished so far (``summary`` with
``not_run``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from contextlib import closing
from pathlib import Path
from typing import Any, TextIO

from bench.commands.argtypes import nonnegative_int, positive_float

NAME = "evaluate"
HELP = "blind evaluation of the diagnosis on N generated cases (process pool or Dask)"

#: format of the header line of an --out file
OUT_FORMAT = "cdpr-evaluation/1"


def add_arguments(p: argparse.ArgumentParser) -> None:
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--cases", type=int, metavar="N", help="number of cases")
    what.add_argument("--compare", nargs=2, metavar=("A", "B"),
                   help="run nothing: compare two evaluations (--out files or --json "
                        "outputs), A before and B after a change: the cases whose answers "
                        "differ (effects named, unexplained declared, exact, parameters moved "
                        "by more than half a standard error); exit 1 when some differ")
    p.add_argument("--seed", type=nonnegative_int, default=0, metavar="S",
                   help="seed of the first case; case k has seed S + k [0]")
    p.add_argument("--jobs", type=int, default=2, metavar="J",
                   help="local worker processes (1: in this process) [2]")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="Dask scheduler, e.g. tcp://127.0.0.1:8786 (then --jobs is unused)")
    p.add_argument("--connect-timeout", type=positive_float, default=10.0, metavar="SECONDS",
                   help="time allowed to reach the scheduler [10]")
    p.add_argument("--effects", metavar="A,B",
                   help="conceal exactly these effects in every case ('none': no effect); "
                        "default: a random mix of 0 to 2 per case")
    p.add_argument("--robot", default="mix",
                   help="model of every case: shipped name (e.g. hexa6, six cables) or "
                        "robot.toml path; 'mix': ROCASPECT, CoGiRo- and IPAnema-class robots, "
                        "half of them with a perturbed geometry; 'mix_new': the IPAnema-class "
                        "rigid frame with swivel pulleys of radii that differ cable by cable, "
                        "or the six-cable hexa6, half of them perturbed [mix]")
    p.add_argument("--kind", default="mix", choices=("mix", "dwell", "continuous",
                                                     "continuous_dwell", "logger", "hour",
                                                     "load_change", "new"),
                   help="recording kind: dwells with replicate visits, continuous rows along "
                        "moves (without or with dwells at the targets) [mix: one of these]; "
                        "drawn only when asked: logger (streams at their own rates with "
                        "gaps, as a bench's logger writes them), hour (the same, an hour "
                        "long), load_change (dwells, the platform's load changed after the "
                        "first visit: physics outside the vocabulary), new (one of these "
                        "three)")
    p.add_argument("--sensors", default="mix", choices=("mix", "all", "no_tensions",
                                                        "no_tracker"),
                   help="column groups the recordings hold [mix]")
    p.add_argument("--oov", choices=("backlash", "thermal", "friction", "none"),
                   help="physics outside the vocabulary in every case (default: in some)")
    p.add_argument("--tracker-error", choices=("tracker_frame", "tracker_latency"),
                   help="every case's laser tracker carries this error of its own and nothing "
                        "else is concealed (all sensors; tracker_latency: continuous "
                        "recordings unless --kind says otherwise)")
    p.add_argument("--grid", metavar="NX,NY,NZ",
                   help="pose grid of each case's campaign (default: random grids and counts)")
    p.add_argument("--visits", type=int, metavar="V",
                   help="visits of each pose (default: 2 to 4)")
    p.add_argument("--out", metavar="FILE",
                   help="append per-case results as JSON lines; a re-run skips seeds in FILE")
    p.add_argument("--keep", metavar="DIR",
                   help="keep each case's recording and scenario (truth included) in "
                        "DIR/<seed>/ (rec/, case.json), to diagnose it again by hand")
    p.add_argument("--reuse-kept", action="store_true",
                   help="with --keep: a case already kept in DIR by a run of the same "
                        "configuration is diagnosed again from its recording, not drawn and "
                        "recorded again (to compare two versions of the diagnosis on the "
                        "same recordings)")
    p.add_argument("--retry-errors", action="store_true",
                   help="with --out: run again the seeds whose case raised")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.add_argument("--json", action="store_true",
                   help="print {summary, cases, errors, config} as one JSON object")


class UsageError(ValueError):
    """Bad arguments or --out file (exit 2)."""


def case_config(args: argparse.Namespace) -> dict[str, Any]:
    """What every case is made with (recorded in the --out header), from the arguments."""
    from bench.evaluate import DRAWN

    effects: list[str] | None = None
    if args.effects is not None:
        names = [e.strip() for e in args.effects.split(",") if e.strip()]
        if names == ["none"]:
            effects = []
        else:
            bad = [e for e in names if e not in DRAWN]
            if bad or not names:
                raise UsageError(f"--effects {args.effects}: unknown effect(s) "
                                 f"{', '.join(bad) or '(empty)'} (known: {', '.join(DRAWN)}, "
                                 f"or 'none')")
            effects = sorted(set(names), key=names.index)
    poses: dict[str, Any] = {}
    if args.grid is not None:
        try:
            n = [int(v) for v in args.grid.split(",")]
        except ValueError:
            n = []
        if len(n) != 3 or min(n) < 1:
            raise UsageError(f"--grid {args.grid}: must be three counts >= 1, e.g. 5,4,2")
        poses["n"] = n
    if args.visits is not None:
        if args.visits < 1:
            raise UsageError(f"--visits {args.visits}: must be >= 1")
        poses["visits"] = args.visits
    tracker = getattr(args, "tracker_error", None)
    if tracker and (effects is not None or args.sensors != "mix" or args.oov is not None):
        raise UsageError(f"--tracker-error {tracker}: conceals the tracker's error alone "
                         f"(all sensors, nothing outside the vocabulary); drop --effects, "
                         f"--sensors and --oov")
    config = {"robot": args.robot, "effects": effects, "poses": poses, "kind": args.kind,
              "sensors": args.sensors, "oov": args.oov}
    return config | ({"tracker": tracker} if tracker else {})


def case_kwargs(config: dict[str, Any]) -> dict[str, Any]:
    """Keyword arguments of :func:`bench.evaluate.run_case` for a configuration."""
    kw: dict[str, Any] = {"robot": config["robot"]}
    if config["effects"] is not None:
        kw["effects"] = tuple(config["effects"])
    if config["poses"]:
        kw["poses"] = dict(config["poses"])
    for k in ("kind", "sensors", "oov", "tracker"):
        if config.get(k) not in (None, "mix"):
            kw[k] = config[k]
    return kw


def _plain(o: Any) -> Any:
    """JSON fallback for numpy scalars and arrays."""
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


def _dumps(o: Any) -> str:
    return json.dumps(o, default=_plain)


# ----- the --out file ---------------------------------------------------------------------

def read_results(path: Path) -> tuple[dict | None, dict[int, dict]]:
    """The header and the records by seed (the last line of a seed wins) of an --out file.

    A line that is not a JSON object is reported on stderr with its file and line and
    skipped (the last line of an interrupted run may be cut short).
    """
    header, records = None, {}
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None, {}
    except OSError as e:
        raise UsageError(f"{path}: cannot read: {e.strerror or e}") from e
    for i, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except json.JSONDecodeError as e:
            print(f"cdpr evaluate: {path}:{i}: not JSON ({e.msg}), line skipped",
                  file=sys.stderr)
            continue
        if not isinstance(rec, dict):
            print(f"cdpr evaluate: {path}:{i}: not a JSON object, line skipped", file=sys.stderr)
        elif "format" in rec:
            if rec["format"] != OUT_FORMAT:
                raise UsageError(f"{path}:{i}: format {rec['format']!r}, expected {OUT_FORMAT!r}")
            header = rec
        elif isinstance(rec.get("seed"), int):
            records[rec["seed"]] = rec
        else:
            print(f"cdpr evaluate: {path}:{i}: no integer 'seed', line skipped", file=sys.stderr)
    if records and header is None:
        raise UsageError(f"{path}: no {OUT_FORMAT} header line: not written by cdpr evaluate")
    return header, records


def _open_out(path: Path, config: dict, header: dict | None,
              created: list[Path] | None = None) -> TextIO:
    from bench.outputs import make_dirs

    if header is not None and header.get("config") != config:
        raise UsageError(f"{path}: made with another case configuration "
                         f"{_dumps(header.get('config'))}; this run: {_dumps(config)} "
                         f"(use another --out FILE)")
    try:
        make_dirs(path.parent, created)
        f = path.open("a+", encoding="utf-8")
    except OSError as e:
        raise UsageError(f"{path}: cannot write: {e.strerror or e}") from e
    f.seek(0, os.SEEK_END)
    if f.tell() > 0:  # an interrupted run may have left a line without its newline
        f.seek(f.tell() - 1)
        if f.read(1) != "\n":
            f.write("\n")
    if header is None:
        _append(f, {"format": OUT_FORMAT, "config": config})
    return f


def run_stamp() -> dict[str, str]:
    """Where a case was diagnosed, kept with its record (``run``): the commit of the
    diagnosis, the date (UTC) and the machine (CPU model and count)."""
    from bench.benchmarks.page import machine

    m = machine()
    return {"commit": m["commit"], "date": m["date"], "cpu": m["cpu"]}


def _append(f: TextIO, rec: dict) -> None:
    f.write(_dumps(rec) + "\n")
    f.flush()
    os.fsync(f.fileno())


# ----- report -----------------------------------------------------------------------------

def _abbrev(name: str) -> str:
    return "".join(w[0] for w in name.split("_")).upper()


def _pct(x: float | None) -> str:
    return "n/a" if x is None else f"{100 * x:.1f} %"


def matrix_lines(matrix: dict[str, dict[str, int]]) -> list[str]:
    """The detection matrix as text: rows concealed effect (or none), columns named effects."""
    from controller.effects import EFFECT_NAMES

    if not matrix:
        return ["  (no scored case)"]
    cols = [e for e in EFFECT_NAMES
            if e in matrix or any(row.get(e, 0) for row in matrix.values())]
    rows = [e for e in (*EFFECT_NAMES, "none") if e in matrix]
    label = "concealed \\ named"
    w = max(len(label), *(len(r) for r in rows))
    out = [f"  {label:<{w}} {'cases':>5} " + " ".join(f"{_abbrev(c):>4}" for c in cols)]
    for r in rows:
        row = matrix[r]
        out.append(f"  {r:<{w}} {row['cases']:>5} "
                   + " ".join(f"{row.get(c, 0):>4}" for c in cols))
    out.append("  columns: " + ", ".join(f"{_abbrev(c)} {c}" for c in cols))
    return out


def _rate_line(label: str, r: dict) -> str:
    fp = r["false_positive_rate"]
    return (f"  {label:<22} {r['cases']:>4} cases: exact {_pct(r['exact_detection'])} of "
            f"{r['in_vocabulary']}, false positives {_pct(fp)}, unexplained declared "
            f"{r['unexplained_declared_in_vocabulary']}, seconds median "
            + ("n/a" if r.get("median_case_s") is None else f"{r['median_case_s']:.1f}")
            + ", max " + ("n/a" if r.get("max_case_s") is None else f"{r['max_case_s']:.1f}")
            + ("" if r.get("median_case_cpu_s") is None else
               f" (processor {r['median_case_cpu_s']:.1f}, max {r['max_case_cpu_s']:.1f})"))


def human(summary: dict, errors: list[dict], seeds: range) -> str:
    """The evaluation in words."""
    s = summary
    z = s["z_scores"]
    lo, hi = s["false_positive_ci95"]
    elo, ehi = s["exact_detection_ci95"]
    med = s["median_case_s"]
    oov = s["out_of_vocabulary"]
    lines = [f"evaluation: {len(seeds)} cases (seeds {seeds.start}..{seeds.stop - 1}): "
             f"{s['cases']} scored, {len(errors)} raised",
             f"  exact detection      {_pct(s['exact_detection'])} of {s['in_vocabulary']} "
             f"cases without physics outside the vocabulary "
             f"(95 % CI {_pct(elo)} .. {_pct(ehi)})",
             f"  false positives      {_pct(s['false_positive_rate'])} of effects not concealed "
             f"(95 % CI {_pct(lo)} .. {_pct(hi)}); null cases naming something: "
             f"{s['null_cases_named_something']} of {s['null_cases']}",
             f"  unexplained declared {s['unexplained_declared_in_vocabulary']} of "
             f"{s['in_vocabulary']} cases without physics outside the vocabulary",
             f"  outside the vocab.   {oov['cases']} cases: unexplained declared "
             f"{oov['declared_unexplained']}, confident wrong answers {oov['confident_wrong']}, "
             f"exact without declaring {oov['silent_exact']}",
             f"  parameters in tol.   {_pct(s['params_within_tolerance'])} "
             f"of {s['params_total']}",
             "  z-scores             " + ("none" if not z["n"] else
                                          f"n {z['n']}, mean {z['mean']:+.2f}, "
                                          f"std {z['std']:.2f} (robust {z['robust_std']:.2f}), "
                                          f"|z| < 2: {_pct(z['within_2'])} (cases named "
                                          f"exactly)"),
             "  z-scores, all cases  " + ("none" if not s["z_scores_all_cases"]["n"] else
                                          f"n {s['z_scores_all_cases']['n']}, std "
                                          f"{s['z_scores_all_cases']['std']:.2f} (robust "
                                          f"{s['z_scores_all_cases']['robust_std']:.2f})"),
             "  held-out / noise     " + ("n/a" if s["heldout_over_noise_median"] is None
                                          else f"{s['heldout_over_noise_median']:.2f} (median)"),
             "  diagnosis seconds    " + ("n/a" if med is None else
                                          f"{med:.1f} (median), {s['max_case_s']:.1f} (max)")
             + ("" if s.get("median_case_cpu_s") is None else
                f"; processor seconds {s['median_case_cpu_s']:.1f} (median), "
                f"{s['max_case_cpu_s']:.1f} (max), {s['cases_over_60_cpu_s']} over 60")
             + ("" if s.get("median_record_cpu_s") is None else
                f"; making the cases {s['median_record_cpu_s']:.1f} (median), "
                f"{s['max_record_cpu_s']:.1f} (max) processor seconds"),
             "  by robot:"]
    lines += [_rate_line(k, v) for k, v in s["by_robot"].items()]
    lines.append("  by recording kind:")
    lines += [_rate_line(k, v) for k, v in s["by_kind"].items()]
    lines.append("  by sensors:")
    lines += [_rate_line(k, v) for k, v in s["by_sensors"].items()]
    lines.append("  by concealed effect (cases, named, exact):")
    lines += [f"    {e:<22} {v['cases']:>4} {v['named']:>4} {v['exact']:>4}"
              for e, v in s["by_effect"].items()]
    cov = s.get("coverage", {})
    if cov:
        lines.append("  95 % intervals holding the truth (cases named exactly; parameters, "
                     "report's intervals, value +- 1.96 standard errors, widened by refits):")
        lines += [f"    {e:<22} {v['params']:>4} {_pct(v['covered']):>7} "
                  f"{_pct(v['covered_linearised']):>7} {v['profiled']:>4}"
                  for e, v in cov.items()]
    lines.append("  equilibrium solver per robot (calls, by Newton, energy-descent fallbacks, "
                 "failures):")
    lines += [f"    {r:<12} {v['calls']:>7} {v['newton']:>7} {v['fallbacks']:>5} "
              f"{v['failures']:>5}" for r, v in s["equilibrium"].items()]
    lines.append("  detection matrix (counts of cases without physics outside the vocabulary):")
    lines += ["  " + ln for ln in matrix_lines(s["matrix"])]
    lines.append("    (a case concealing two effects counts in both rows)")
    for e in errors:
        lines.append(f"  error: seed {e['seed']}: {e['error']}")
    return "\n".join(lines)


# ----- compare ------------------------------------------------------------------------------

def load_records(path: Path) -> dict[int, dict]:
    """The case records by seed of an evaluation: an ``--out`` file (JSON lines) or the
    ``--json`` output (one object with ``cases`` and ``errors``)."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise UsageError(f"{path}: cannot read: {e.strerror or e}") from e
    try:
        whole = json.loads(text)
    except json.JSONDecodeError:
        whole = None
    if isinstance(whole, dict) and "format" not in whole:
        if not isinstance(whole.get("cases"), list):
            raise UsageError(f"{path}: a JSON object without 'cases': not the output of "
                             f"cdpr evaluate --json")
        return {int(r["seed"]): r for r in [*whole["cases"], *whole.get("errors", [])]}
    header, records = read_results(path)
    if header is None:
        raise UsageError(f"{path}: no {OUT_FORMAT} header line and no --json output: not "
                         f"written by cdpr evaluate")
    return records


def compare_lines(cmp: dict, a: str, b: str) -> str:
    """The comparison in words: counts, then one block per case whose answer differs."""
    lines = [f"compared {cmp['common']} cases (A {a}, B {b}): {cmp['same']} same answers, "
             f"{len(cmp['differ'])} differ; exact A {cmp['exact']['a']}, B {cmp['exact']['b']}"]
    for k in ("only_a", "only_b"):
        if cmp[k]:
            lines.append(f"  seeds only in {k[-1].upper()}: {len(cmp[k])} "
                         f"({cmp[k][0]}..{cmp[k][-1]})")
    for d in cmp["differ"]:
        case = " ".join(str(v) for v in d["case"].values())
        lines.append(f"  seed {d['seed']} ({case}; concealed "
                     f"{','.join(d['truth'] or []) or 'none'}): {'; '.join(d['differences'])}")
        for k in ("a", "b"):
            x = d[k]
            said = x["error"] if "error" in x else (
                f"named {','.join(x['named']) or 'none'}"
                + (", unexplained" if x["unexplained"] else "")
                + (", exact" if x["exact"] else ""))
            lines.append(f"    {k.upper()}: {said}")
    return "\n".join(lines)


def _compare(args: argparse.Namespace) -> int:
    from bench.evaluate import compare

    try:
        a, b = (load_records(Path(p)) for p in args.compare)
    except UsageError as e:
        return _fail(args, 2, f"--compare: {e}")
    cmp = compare(a, b)
    if args.json:
        print(_dumps(cmp | {"a": args.compare[0], "b": args.compare[1]}))
    else:
        print(compare_lines(cmp, *args.compare))
    return 1 if cmp["differ"] else 0


# ----- run --------------------------------------------------------------------------------

def _fail(args: argparse.Namespace, code: int, msg: str) -> int:
    print(f"cdpr evaluate: {msg}", file=sys.stderr)
    if args.json:
        print(json.dumps({"error": msg}))
    return code


def run(args: argparse.Namespace) -> int:
    from bench.outputs import removing_created

    # refused (another configuration in --out) or failed: no directory made for --keep or
    # --out left unless something was written there
    return removing_created(lambda created: _run(args, created))


def _run(args: argparse.Namespace, created: list[Path]) -> int:
    from bench.parallel import SchedulerError, single_blas_thread

    single_blas_thread()
    if args.compare is not None:
        return _compare(args)
    try:
        config, out_path, previous, out = _setup(args, created)
    except UsageError as e:
        return _fail(args, 2, str(e))
    seeds = range(args.seed, args.seed + args.cases)
    results = {s: previous[s] for s in seeds if s in previous
               and not (args.retry_errors and "error" in previous[s])}
    todo = [s for s in seeds if s not in results]
    if results and not args.quiet:
        print(f"cdpr evaluate: {len(results)} of {len(seeds)} seeds already in {out_path}, "
              f"{len(todo)} to run", file=sys.stderr)
    interrupted: KeyboardInterrupt | None = None
    try:
        _run_cases(args, config, todo, results, out)
    except SchedulerError as e:
        return _fail(args, 2, str(e))
    except KeyboardInterrupt as e:  # Ctrl-C, SIGTERM: the cases finished so far, then out
        interrupted = e
    finally:
        if out is not None:
            out.close()
    return _report(args, config, seeds, results, interrupted)


def _setup(args: argparse.Namespace, created: list[Path]
           ) -> tuple[dict[str, Any], Path | None, dict[int, dict], TextIO | None]:
    """The options checked (:class:`UsageError`), the cases' configuration, the ``--out``
    file with the records it holds already (opened to append), the ``--keep`` folder made."""
    if args.cases < 1:
        raise UsageError(f"--cases {args.cases}: must be >= 1")
    if args.jobs < 1:
        raise UsageError(f"--jobs {args.jobs}: must be >= 1")
    if not args.connect_timeout > 0:
        raise UsageError(f"--connect-timeout {args.connect_timeout}: must be > 0")
    if args.retry_errors and not args.out:
        raise UsageError("--retry-errors needs --out FILE")
    if args.reuse_kept and args.keep is None:
        raise UsageError("--reuse-kept needs --keep DIR")
    config = case_config(args)
    from controller.robot import RobotFileError, resolve_robot

    try:
        if args.robot not in ("mix", "mix_new"):
            resolve_robot(args.robot)
    except RobotFileError as e:
        raise UsageError(f"--robot: {e}") from e
    out_path = Path(args.out) if args.out else None
    header, previous = read_results(out_path) if out_path else (None, {})
    if args.keep is not None:
        from bench.outputs import make_dirs

        try:
            make_dirs(args.keep, created)
        except OSError as e:
            raise UsageError(f"--keep {args.keep}: cannot make the folder: {e}") from e
    out = _open_out(out_path, config, header, created) if out_path else None
    return config, out_path, previous, out


def _run_cases(args: argparse.Namespace, config: dict[str, Any], todo: list[int],
               results: dict[int, dict], out: TextIO | None) -> None:
    """Run the seeds ``todo`` (in this process, local workers or a Dask cluster), each
    record into ``results`` and appended to ``out`` as it comes, with progress on stderr:
    a line at start, one per case started and finished, and the progress line (cases done,
    those running) every 15 s (every second on a terminal)."""
    from bench import evaluate
    from bench.parallel import interrupt_on_term, run_each
    from bench.progress import Progress

    if not todo:
        return
    prog = Progress("evaluate", len(todo), args.quiet, unit="cases")
    started = [0]

    def on_start(seed: int) -> None:
        started[0] += 1
        prog.running[f"seed {seed}"] = None
        prog.say(f"[{prog.elapsed_s():6.1f} s] seed {seed} started "
                 f"({started[0]}/{len(todo)})")

    where = (f"on the Dask cluster at {args.scheduler}" if args.scheduler else
             "in this process (--jobs 1)" if args.jobs == 1 else
             f"on {min(args.jobs, len(todo))} local worker processes (--jobs {args.jobs})")
    prog.say(f"cdpr evaluate: {len(todo)} cases (seeds {todo[0]}..{todo[-1]}, --seed "
             f"{args.seed}) {where}")
    stamp = run_stamp()
    outcomes = run_each(evaluate.run_case, todo, jobs=args.jobs, scheduler=args.scheduler,
                        connect_timeout_s=args.connect_timeout, keep=args.keep,
                        reuse=args.reuse_kept, on_start=on_start, **case_kwargs(config))
    with interrupt_on_term(), closing(outcomes), prog:
        for done, o in enumerate(outcomes, 1):
            rec = (o.value if o.ok else {"seed": o.item, "error": o.error, "trace": o.trace})
            rec = json.loads(_dumps(rec | {"run": stamp}))  # as read back from --out
            results[o.item] = rec
            if out is not None:
                _append(out, rec)
            prog.running.pop(f"seed {o.item}", None)
            prog.done = done
            prog.say(_case_line(o, done, len(todo), results))


def _case_line(o, done: int, n_todo: int, results: dict[int, dict]) -> str:
    """The progress line of the case just finished: what it named, the exact detection
    rate so far and the time left."""
    scored = [r for r in results.values() if "error" not in r]
    exact = sum(bool(r["exact"]) for r in scored)
    rate = f"{exact}/{len(scored)} = {_pct(exact / len(scored))}" if scored else "n/a"
    eta = o.elapsed_s / done * (n_todo - done)
    what = (f"error {o.error}" if not o.ok else
            ("exact" if o.value["exact"] else
             f"named {','.join(o.value['named']) or 'none'} "
             f"(concealed {','.join(o.value['truth']) or 'none'})"))
    return (f"[{o.elapsed_s:6.1f} s] case {done}/{n_todo} seed {o.item}: {what}; "
            f"exact detection {rate}; ETA {math.ceil(eta)} s")


def _report(args: argparse.Namespace, config: dict[str, Any], seeds: range,
            results: dict[int, dict], interrupted: KeyboardInterrupt | None) -> int:
    """The summary of the cases run (``--json``: the whole report); after an interruption
    the cases finished so far, then the interruption raised again (bench.cli reports it on
    stderr and exits with its status). Exit status 1 when a case failed."""
    from bench import evaluate
    from bench.parallel import interruption

    cases = [results[s] for s in seeds if s in results and "error" not in results[s]]
    errors = [{"seed": s, "error": results[s]["error"], "trace": results[s].get("trace")}
              for s in seeds if s in results and "error" in results[s]]
    summary = evaluate.summarise(cases) | {"errors": len(errors), "requested": len(seeds)}
    report = {"summary": summary, "cases": cases, "errors": errors, "config": config,
              "seeds": [seeds.start, seeds.stop - 1]}
    if interrupted is not None:
        msg = interruption(interrupted)[1]
        summary["not_run"] = len(seeds) - len(results)
        if args.json:
            print(_dumps({"error": msg} | report), flush=True)
        elif results:
            print(f"{msg} with {summary['not_run']} of {len(seeds)} cases not run: the cases "
                  f"finished so far")
            print(human(summary, errors, seeds), flush=True)
        raise interrupted
    if args.json:
        print(_dumps(report))
    else:
        print(human(summary, errors, seeds))
    return 1 if errors else 0
