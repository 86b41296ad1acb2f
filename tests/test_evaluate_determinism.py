"""One case's answer does not depend on what ran before it in the same process.

``cdpr evaluate --jobs 1`` runs its cases one after the other in one process (and a pool
worker runs many): warm starts, memos or caches that outlived a case would make its report
depend on the cases before it. A small case is run alone in a fresh interpreter and again
here after a case of another kind (sagging cables: the plant's and the diagnosis's
catenary warm starts, the equilibrium solver's per-robot memory); the two reports must be
identical but for the time they took.
"""

from __future__ import annotations

import json
import subprocess
import sys

from bench import evaluate

SMALL_KW = {"poses": {"n": [3, 2, 1], "visits": 2}, "robot": "rocaspect", "kind": "dwell",
            "sensors": "all", "oov": "none"}
#: the case compared (about 1.5 s of processor time)
CASE = (5, SMALL_KW | {"effects": ["drum_scale"]})
#: the case run before it in this process (about 3.5 s)
BEFORE = (7, SMALL_KW | {"effects": ["cable_sag"]})
#: what legitimately differs between two runs of one case
TIMES = ("seconds", "case_seconds", "cpu_seconds", "record_seconds", "record_cpu_seconds")

ALONE = """
import json, sys
from bench import evaluate
seed, kw = json.loads(sys.argv[1])
print(json.dumps(evaluate.run_case(seed, **kw), default=lambda o: o.item()))
"""


def without_times(case: dict) -> dict:
    """The case's result, timings out, as JSON would carry it."""
    out = json.loads(json.dumps(case, default=lambda o: o.item()))
    for k in TIMES:
        out.pop(k, None)
        out.get("info", {}).pop(k, None)
    return out


def run_here(seed: int, kw: dict) -> dict:
    return evaluate.run_case(seed, **(kw | {"effects": tuple(kw["effects"])}))


def test_a_case_run_alone_gives_the_report_it_gives_after_another_case():
    got = subprocess.run([sys.executable, "-c", ALONE, json.dumps(CASE)], capture_output=True,
                         text=True, timeout=600, check=True)
    alone = json.loads(got.stdout.strip().splitlines()[-1])
    run_here(*BEFORE)
    after = run_here(*CASE)
    assert without_times(after) == without_times(alone)
