"""``cdpr bench``: speed benchmarks (medians on this machine), one JSON object with ``--json``
(``--list --json``: ``{"groups": [...]}``; an unknown group: ``{"error", "unknown", "groups"}``,
exit status 2)."""

from __future__ import annotations

import argparse
import json
import platform
import sys
import threading
import time

NAME = "bench"
HELP = "run the speed benchmarks and print their medians"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--only", action="append", metavar="GROUP",
                   help="run only this benchmark group (repeatable); see --list")
    p.add_argument("--list", action="store_true", help="list the benchmark groups")
    p.add_argument("--quick", action="store_true", help="fewer repetitions (smoke run)")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")


def _tick(name: str, t0: float, done: threading.Event, every_s: float = 5.0) -> None:
    """Progress while a benchmark group runs: a line every few seconds on stderr."""
    while not done.wait(every_s):
        print(f"bench {name}: running for {time.perf_counter() - t0:.0f} s ...",
              file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    from bench.benchmarks import registry

    reg = registry()
    if args.list:
        if args.json:
            print(json.dumps({"groups": list(reg)}))
        else:
            for name in reg:
                print(name)
        return 0
    names = list(reg) if not args.only else args.only
    unknown = [n for n in names if n not in reg]
    if unknown:
        msg = f"unknown group(s) {', '.join(unknown)} (known: {', '.join(reg)})"
        print(f"cdpr bench: {msg}", file=sys.stderr)
        if args.json:
            print(json.dumps({"error": msg, "unknown": unknown, "groups": list(reg)}))
        return 2
    out: dict[str, object] = {}
    failed = 0
    for i, name in enumerate(names, 1):
        print(f"bench {name} ({i}/{len(names)}) ...", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        done = threading.Event()
        ticker = threading.Thread(target=_tick, args=(name, t0, done), daemon=True)
        ticker.start()
        try:
            res = reg[name](args.quick)
        except Exception as e:  # a failing group must not hide the others
            failed += 1
            print(f"bench {name}: FAILED: {type(e).__name__}: {e}", file=sys.stderr)
            out[f"{name}_error"] = f"{type(e).__name__}: {e}"
            continue
        finally:
            done.set()
            ticker.join()
        out.update(res)
        keys = ", ".join(f"{k} {v:.4g}" for k, v in res.items() if isinstance(v, float))
        print(f"bench {name}: done in {time.perf_counter() - t0:.1f} s: {keys}",
              file=sys.stderr)
    out["machine"] = f"{platform.machine()} {platform.python_implementation()} " \
                     f"{platform.python_version()}"
    if args.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(f"{k:28} {v:.4g}" if isinstance(v, float) else f"{k:28} {v}")
    return 1 if failed else 0
