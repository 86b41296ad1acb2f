"""The evaluation page of the documentation, generated from a ``cdpr evaluate --out`` file.

    cdpr evaluate --cases 200 --seed 12800 --jobs 2 --out eval.jsonl
    python -m bench.evaluation_page eval.jsonl --out docs/evaluation.md

The page gives the blind evaluation's figures (exact detection, false positives, physics
outside the vocabulary, how often the reported 95 % intervals hold the truth per effect
kind) and where they were measured: the commit(s), dates and machine each case's record
names (``run``, stamped by ``cdpr evaluate``), and the command that makes the cases again.
Never edit the page by hand.
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


def page(header: dict, cases: list[dict], errors: int, made: str, source: str | None = None
         ) -> str:
    """The Markdown page of the scored ``cases`` of one ``--out`` file (its ``header``;
    ``source`` its path as the page names it)."""
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
        "Regenerate (about ten minutes at `--jobs 2` once the cases are kept and only "
        "diagnosed again, `--keep DIR --reuse-kept`; hours to record them):", "",
        "```sh", "cdpr evaluate --cases 200 --seed 12800 --jobs 2 --keep cases --out eval.jsonl",
        "cp eval.jsonl docs/data/evaluation.jsonl",
        "python -m bench.evaluation_page docs/data/evaluation.jsonl --out docs/evaluation.md",
        "```", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """``EVAL.jsonl [--out PAGE]``: the page on stdout, or written to PAGE."""
    from datetime import UTC, datetime

    from bench.benchmarks.page import page_arguments, write_page
    from bench.commands.evaluate import UsageError, read_results

    args = page_arguments(argv, "python -m bench.evaluation_page EVAL.jsonl "
                                "[--out docs/evaluation.md]")
    if args is None:
        return 2
    src, out = args
    try:
        header, records = read_results(Path(src))
    except UsageError as e:
        print(str(e), file=sys.stderr)
        return 1
    if header is None or not records:
        print(f"{src}: no cases: not an --out file of `cdpr evaluate`", file=sys.stderr)
        return 1
    cases = [r for _, r in sorted(records.items()) if "error" not in r]
    made = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    write_page(page(header, cases, len(records) - len(cases), made, src), out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
