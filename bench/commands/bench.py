"""``cdpr bench``: speed benchmarks (medians on this machine), one JSON object with ``--json``."""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time

from bench.benchmarks import registry

NAME = "bench"
HELP = "run the speed benchmarks and print their medians"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--only", action="append", metavar="GROUP",
                   help="run only this benchmark group (repeatable); see --list")
    p.add_argument("--list", action="store_true", help="list the benchmark groups")
    p.add_argument("--quick", action="store_true", help="fewer repetitions (smoke run)")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")


def run(args: argparse.Namespace) -> int:
    reg = registry()
    if args.list:
        for name in reg:
            print(name)
        return 0
    names = list(reg) if not args.only else args.only
    unknown = [n for n in names if n not in reg]
    if unknown:
        print(f"cdpr bench: unknown group(s) {', '.join(unknown)} (known: {', '.join(reg)})",
              file=sys.stderr)
        return 2
    out: dict[str, object] = {}
    failed = 0
    for name in names:
        print(f"bench {name} ...", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        try:
            res = reg[name](args.quick)
        except Exception as e:  # a failing group must not hide the others
            failed += 1
            print(f"bench {name}: FAILED: {type(e).__name__}: {e}", file=sys.stderr)
            out[f"{name}_error"] = f"{type(e).__name__}: {e}"
            continue
        out.update(res)
        print(f"bench {name}: done in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    out["machine"] = f"{platform.machine()} {platform.python_implementation()} " \
                     f"{platform.python_version()}"
    if args.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(f"{k:28} {v:.4g}" if isinstance(v, float) else f"{k:28} {v}")
    return 1 if failed else 0
