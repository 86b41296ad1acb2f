"""Replicates of one kept evaluation case: same truth, fresh noise, to tell a tail draw from a
biased standard error.

A case kept by ``cdpr evaluate --keep DIR`` is ``DIR/SEED/case.json`` (the scenario with its
concealed truth). Each replicate records that scenario again with another campaign seed (the
scenario's ``seed``: the measurement and process noise, and for drawn pose sets the visit
order; the truth, poses and nuisances are the case's own), diagnoses it and scores it as the
evaluation does. Printed per parameter named right: the replicates' rms of
z = (estimate - truth) / stderr, the coverage of the report's 95 % intervals and the median
interval quantile. rms z near 1 with a 200-case miss means the miss was a tail draw; rms z well
above 1 means the standard error is biased for that recording class.

    PYTHONPATH=$PWD python tools/replicates.py /tmp/s40/k200/12935 -n 10 --out /tmp/r.jsonl

Only scenarios recorded by the project's recorder (not the logger or change kinds) are
supported; the recording uses the plant's predicted rest searches (the same rows within the
plant's force tolerance, as the tests record).
"""
from __future__ import annotations

import argparse
import copy
import json
import math
import tempfile
import time
from collections import defaultdict
from pathlib import Path

#: added to a replicate's index to make its campaign seed (far from the evaluation's seeds)
SEED_BASE = 900_000


def with_values(case: dict, settings: list[str]) -> dict:
    """A copy of ``case`` with ``PATH=VALUE`` settings applied (``PATH`` dotted keys into the
    scenario, ``VALUE`` a number: e.g. ``nuisance.drift_m_per_h=0`` to see whether a fixed
    nuisance is what biases an estimate over the replicates)."""
    case = copy.deepcopy(case)
    for s in settings:
        path, value = s.split("=", 1)
        *head, last = path.split(".")
        d = case
        for k in head:
            d = d[k]
        if last not in d:
            raise KeyError(f"{path}: no such key (has: {', '.join(sorted(d))})")
        d[last] = float(value)
    return case


def replicate(case: dict, index: int, workdir: str | None = None) -> dict:
    """Record ``case`` again with campaign seed ``SEED_BASE + 1000 * case seed + index``,
    diagnose and score it: the evaluation's record of one case (``intervals`` per parameter)."""
    from bench.campaign import campaign_plant, run_campaign
    from bench.evaluate import _diagnose_case, scenario_of

    info = case.get("case", {})
    if "logger" in info or "change" in info:
        raise ValueError("replicates: logger and change cases are not supported")
    case = copy.deepcopy(case)
    case.pop("kept", None)  # how the evaluation made it (not part of the scenario)
    case["seed"] = SEED_BASE + 1000 * (int(case["seed"]) % 1000) + index
    with tempfile.TemporaryDirectory(dir=workdir) as d:
        rec = Path(d) / "rec"
        sc = scenario_of(case)
        run_campaign(sc, rec, plant=campaign_plant(sc, predict=True))
        return _diagnose_case(int(case["seed"]), case, rec, {"replicate": index},
                              time.perf_counter())


def summary(records: list[dict]) -> dict[str, dict]:
    """Per ``effect.key``: replicates named, rms z, covered share, median quantile."""
    zs: dict[str, list[float]] = defaultdict(list)
    cov: dict[str, list[bool]] = defaultdict(list)
    for r in records:
        for iv in r.get("intervals", []):
            if not iv.get("stderr"):
                continue
            k = f"{iv['effect']}.{iv['key']}"
            zs[k].append((iv["value"] - iv["truth"]) / iv["stderr"])
            lo, hi = (-math.inf if v is None else v for v in iv["interval"])
            cov[k].append(lo <= iv["truth"] <= hi)
    return {k: {"n": len(z), "rms_z": math.sqrt(sum(x * x for x in z) / len(z)),
                "mean_z": sum(z) / len(z), "covered": sum(cov[k]) / len(cov[k])}
            for k, z in sorted(zs.items())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case_dir", type=Path, help="a kept case folder (holds case.json)")
    ap.add_argument("-n", type=int, default=10, help="replicates")
    ap.add_argument("--first", type=int, default=0, help="first replicate index")
    ap.add_argument("--set", action="append", default=[], metavar="PATH=VALUE",
                    help="change a scenario value first (e.g. nuisance.hysteresis_m=0)")
    ap.add_argument("--out", type=Path, help="append each replicate's record (JSON lines)")
    a = ap.parse_args()
    from bench.evaluate import one_blas_thread

    one_blas_thread()
    case = with_values(json.loads((a.case_dir / "case.json").read_text()), a.set)
    records = []
    for i in range(a.first, a.first + a.n):
        r = replicate(case, i)
        records.append(r)
        if a.out:
            with a.out.open("a") as f:
                f.write(json.dumps(r) + "\n")
        print(f"replicate {i}: exact={r.get('exact')} {r.get('seconds', 0):.1f} s", flush=True)
    for k, s in summary(records).items():
        print(f"{k:40s} n={s['n']:2d} rms_z={s['rms_z']:.2f} mean_z={s['mean_z']:+.2f} "
              f"covered={s['covered']:.2f}")


if __name__ == "__main__":
    main()
