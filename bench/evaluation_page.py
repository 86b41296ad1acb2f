"""The evaluation page of the documentation, generated from a ``cdpr evaluate --out`` file.

    cdpr evaluate --cases 200 --seed 12800 --jobs 2 --out eval.jsonl
    cdpr evaluate --kind new --cases 12 --seed 14000 --jobs 1 --out new.jsonl
    python -m bench.evaluation_page eval.jsonl [new.jsonl] --out docs/evaluation.md

The page gives the blind evaluation's figures (exact detection, false positives, physics
outside the vocabulary, how often the reported 95 % intervals hold the truth per effect
kind) and where they were measured: the commit(s), dates and machine each case's record
names (``run``, stamped by ``cdpr evaluate``), and the command that makes the cases again.
A second file (the new kinds, ``--kind new``: a bench's logger, hours long, load changes)
adds a section of its own, with its own commit, dates, machine and command, and a row per
case. Never edit the page by hand.
"""

from __future__ import annotations

import sys
from pathlib import Path

from bench.commands.evaluate import _pct

#: options of ``cdpr evaluate`` for the keys of a case configuration (the --out header)
_OPTIONS = {"robot": "--robot", "kind": "--kind", "sensors": "--sensors", "oov": "--oov",
            "tracker": "--tracker-error"}


def command(config: dict, seeds: list[int]) -> str:
    """The ``cdpr evaluate`` command that makes the cases of ``seeds`` (consecutive) with the
    case configuration ``config`` again."""
    parts = ["cdpr evaluate", f"--cases {len(seeds)}", f"--seed {min(seeds)}"]
    for key, opt in _OPTIONS.items():
        if config.get(key) not in (None, "mix"):
            parts.append(f"{opt} {config[key]}")
    if config.get("effects") is not None:
        parts.append(f"--effects {','.join(config['effects']) or 'none'}")
    poses = config.get("poses") or {}
    if "n" in poses:
        parts.append("--grid " + ",".join(str(v) for v in poses["n"]))
    if "visits" in poses:
        parts.append(f"--visits {poses['visits']}")
    return " ".join(parts)


def _ci(ci: list[float]) -> str:
    return f"{_pct(ci[0])} to {_pct(ci[1])}"


def _where(cases: list[dict]) -> list[str]:
    """Rows of the 'where' table: the commits, dates and machines the records name."""
    runs = [c.get("run") or {} for c in cases]
    commits = sorted({r.get("commit", "not recorded") for r in runs})
    dates = sorted(r["date"] for r in runs if "date" in r)
    cpus = sorted({r.get("cpu", "not recorded") for r in runs})
    span = f"{dates[0]} to {dates[-1]}" if dates else "not recorded"
    return [f"| diagnosis commit | {', '.join(f'`{c}`' for c in commits)} |",
            f"| evaluation run started | {span} |", f"| CPU | {'; '.join(cpus)} |"]


def _headline(s: dict) -> list[str]:
    z, oov = s["z_scores"], s["out_of_vocabulary"]
    zs = ("none" if not z["n"] else
          f"robust SD {z['robust_std']:.2f}, within ±2: {_pct(z['within_2'])} (n {z['n']})")
    return [
        "| figure | value |", "| --- | --- |",
        f"| cases scored | {s['cases']} (in the vocabulary: {s['in_vocabulary']}) |",
        f"| exact detection | {_pct(s['exact_detection'])} "
        f"(95 % interval {_ci(s['exact_detection_ci95'])}) |",
        f"| false positives (effects not concealed, named) | {_pct(s['false_positive_rate'])} "
        f"(95 % interval {_ci(s['false_positive_ci95'])}) |",
        f"| null cases naming something | {s['null_cases_named_something']} of "
        f"{s['null_cases']} |",
        f"| `unexplained` declared in the vocabulary | "
        f"{s['unexplained_declared_in_vocabulary']} of {s['in_vocabulary']} |",
        f"| outside the vocabulary: declared / confidently wrong | "
        f"{oov['declared_unexplained']} / {oov['confident_wrong']} of {oov['cases']} |",
        f"| parameters within tolerance | {_pct(s['params_within_tolerance'])} of "
        f"{s['params_total']} |",
        f"| z-scores of cases named right | {zs} |",
        "| diagnosis seconds, median / max | "
        + ("n/a" if s["median_case_s"] is None else
           f"{s['median_case_s']:.1f} / {s['max_case_s']:.1f}") + " |",
    ]


def _rates(title: str, by: dict) -> list[str]:
    out = [f"| {title} | cases | in vocabulary | exact detection | 95 % interval |",
           "| --- | --- | --- | --- | --- |"]
    out += [f"| {k} | {v['cases']} | {v['in_vocabulary']} | {_pct(v['exact_detection'])} | "
            f"{_ci(v['exact_detection_ci95'])} |" for k, v in by.items()]
    return out


def _coverage(cov: dict) -> list[str]:
    out = ["| effect kind | parameters | cases | report's interval | 95 % interval of the rate "
           "| value ± 1.96 SE | widened by refits | selective |",
           "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    out += [f"| {e} | {v['params']} | {v['cases']} | {_pct(v['covered'])} | "
            f"{_ci(v['covered_ci95'])} | {_pct(v['covered_linearised'])} | {v['profiled']} | "
            f"{v['selective']} |" for e, v in cov.items()]
    return out


#: the stream a case's sensors leave out (``info.sensors``)
_ABSENT = {"no_tracker": "tracker", "no_tensions": "load_cells"}


def _streams_of(info: dict) -> str:
    """How a case's logger wrote (rows [Hz], dropouts per stream it has), or ``-``."""
    lg = info.get("logger")
    if not lg:
        return "-"
    drops = ", ".join(f"{d[0]} {d[1]:.2g}/min {d[2]:.2g}-{d[3]:.2g} s"
                      for d in lg.get("dropouts") or []
                      if d[0] != _ABSENT.get(info.get("sensors", "")))
    return f"rows {lg['rows_hz']:g} Hz; dropouts: {drops or 'none'}"


def _case_rows(cases: list[dict]) -> list[str]:
    """One row per case: kind, robot, what was concealed, what was named, and the time."""
    out = ["| seed | kind | robot | sensors | logger | concealed | named | unexplained "
           "| exact | diagnosis s |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- "
           "| --- |"]
    for c in sorted(cases, key=lambda c: c["seed"]):
        info = c.get("info", {})
        truth = sorted(c.get("truth", []))
        oov = info.get("oov", "none")
        hidden = ", ".join(truth + ([f"*{oov}*"] if oov != "none" else [])) or "none"
        out.append(f"| {c['seed']} | {info.get('kind', '?')} | {info.get('robot', '?')} | "
                   f"{info.get('sensors', '?')} | {_streams_of(info)} | {hidden} | "
                   f"{', '.join(sorted(c.get('named', []))) or 'none'} | "
                   f"{'yes' if c.get('unexplained') else 'no'} | "
                   f"{'yes' if c.get('exact') else 'no'} | {c.get('seconds', 0.0):.1f} |")
    return out


def new_section(header: dict, cases: list[dict], errors: int, source: str | None) -> list[str]:
    """The section of a second ``--out`` file (the new kinds): where and how its cases were
    made, the headline figures, exact detection by kind, and one row per case."""
    from bench.evaluate import summarise

    s = summarise(cases)
    seeds = sorted(c["seed"] for c in cases)
    return [
        "## The new kinds: a bench's logger, hours long, load changes", "",
        "Cases of `--kind new`: *logger*, the sensors' streams at their own rates as a bench's "
        "logger writes them (jittered stamps, empty fields, files split by time or sensor, "
        "with or without the controller's columns, sensor dropouts); *hour*, the same an "
        "hour long; *load_change*, dwells whose platform load changes after the first visit "
        "of every pose (physics outside the vocabulary: declaring it `unexplained` is the "
        "right answer). Measured apart from the cases above: its own commit, dates and "
        "machine.", "",
        "| | |", "| --- | --- |",
        f"| cases | `{command(header.get('config') or {}, seeds)}` |",
        *_where(cases),
        *([f"| records | `{source}` |"] if source else []),
        f"| cases that raised | {errors} |", "",
        *_headline(s), "",
        *_rates("kind", s["by_kind"]), "",
        *_case_rows(cases), ""]


def page(header: dict, cases: list[dict], errors: int, made: str, source: str | None = None,
         new: tuple[dict, list[dict], int, str | None] | None = None) -> str:
    """The Markdown page of the scored ``cases`` of one ``--out`` file (its ``header``;
    ``source`` its path as the page names it); ``new``: a second file's (header, cases,
    errors, source), its section after the first's figures (:func:`new_section`)."""
    from bench.evaluate import summarise

    s = summarise(cases)
    seeds = sorted(c["seed"] for c in cases)
    lines = [
        "# Evaluation", "",
        "<!-- generated by `python -m bench.evaluation_page`: do not edit by hand -->", "",
        "The diagnosis scored blind on generated cases ([the diagnosis "
        "report](guide/diagnosis-report.md) says how `cdpr evaluate` draws them). A case is "
        "*exact* when the effects named are the ones concealed; a case is scored for its "
        "intervals when it is exact, declares nothing `unexplained` and holds no physics "
        "outside the vocabulary.", "",
        "| | |", "| --- | --- |",
        f"| cases | `{command(header.get('config') or {}, seeds)}` |",
        *_where(cases),
        *([f"| records | `{source}` |"] if source else []),
        f"| cases that raised | {errors} |",
        f"| page made | {made} |", "",
        *_headline(s), "",
        "## 95 % intervals holding the truth, per effect kind", "",
        "Parameters of the cases named right; the report's `interval95` (linearised, widened "
        "by profile refits or the jackknife where in doubt, selective where a parameter was "
        "reported for passing a threshold) and the plain value ± 1.96 standard errors, each "
        "with the Wilson 95 % interval of the rate.", "",
        *_coverage(s["coverage"]), "",
        "## Exact detection by robot, recording kind and sensors", "",
        *_rates("robot", s["by_robot"]), "", *_rates("recording kind", s["by_kind"]), "",
        *_rates("sensors", s["by_sensors"]), "",
        "## By concealed effect", "",
        "| effect | cases | named | exact |", "| --- | --- | --- | --- |",
        *[f"| {e} | {v['cases']} | {v['named']} | {v['exact']} |"
          for e, v in s["by_effect"].items()], "",
        *(new_section(*new) if new is not None else []),
        "Regenerate (about ten minutes at `--jobs 2` once the cases are kept and only "
        "diagnosed again, `--keep DIR --reuse-kept`; hours to record them):", "",
        "```sh", "cdpr evaluate --cases 200 --seed 12800 --jobs 2 --keep cases --out eval.jsonl",
        "cp eval.jsonl docs/data/evaluation.jsonl",
        *([f"cdpr evaluate --kind new --cases {len(new[1])} --seed "
           f"{min(c['seed'] for c in new[1])} --jobs 1 --out {new[3]}"] if new else []),
        "python -m bench.evaluation_page docs/data/evaluation.jsonl "
        + (f"{new[3]} " if new else "") + "--out docs/evaluation.md",
        "```", ""]
    return "\n".join(lines)


def load(src: str) -> tuple[dict, list[dict], int]:
    """An ``--out`` file's header, its scored cases (by seed) and how many raised; a
    UsageError when it is no such file or holds no case."""
    from bench.commands.evaluate import UsageError, read_results

    header, records = read_results(Path(src))
    if header is None or not records:
        raise UsageError(f"{src}: no cases: not an --out file of `cdpr evaluate`")
    cases = [r for _, r in sorted(records.items()) if "error" not in r]
    return header, cases, len(records) - len(cases)


def main(argv: list[str] | None = None) -> int:
    """``EVAL.jsonl [NEW.jsonl] [--out PAGE]``: the page on stdout, or written to PAGE."""
    from datetime import UTC, datetime

    from bench.benchmarks.page import write_page
    from bench.commands.evaluate import UsageError

    argv = list(sys.argv[1:] if argv is None else argv)
    out = None
    if "--out" in argv and argv.index("--out") == len(argv) - 2:
        out = Path(argv.pop())
        argv.pop()
    if len(argv) not in (1, 2) or any(a.startswith("-") for a in argv):
        print("usage: python -m bench.evaluation_page EVAL.jsonl [NEW.jsonl] "
              "[--out docs/evaluation.md]", file=sys.stderr)
        return 2
    try:
        first = load(argv[0])
        new = (*load(argv[1]), argv[1]) if len(argv) == 2 else None
    except UsageError as e:
        print(str(e), file=sys.stderr)
        return 1
    made = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    write_page(page(*first, made, argv[0], new=new), out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
