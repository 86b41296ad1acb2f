"""The paper's path campaign as a benchmark.

- ``paper_paths_s``: wall time of the whole ``cdpr dry-run paper-paths`` campaign of the
  issue: the four path runs of Table 3 with the nominal, the true compliant and the
  diagnosed model, plus the calibration run (``calibration-quick``) and its diagnosis, on
  two processes (the command's default ``--jobs``), lock-step, at the campaign's rates.
  One run (it lasts minutes); not in ``--quick``. The remeasured model and the
  measured-vs-planned comparison, which the command also runs by default, are left out.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from bench.benchmarks import register


@register("paper")
def bench_paper(quick: bool) -> dict[str, float]:
    if quick:
        return {}
    from bench.dryrun import paper

    with tempfile.TemporaryDirectory(prefix="cdpr-bench-paper-") as tmp:
        opt = paper.PathsOptions(work=Path(tmp), models=("nominal", "compliant", "diagnosed"),
                                 planned=False)
        t0 = time.perf_counter()
        first, second = paper.paths_plan(opt)
        prog = paper.Progress("paper-paths", len(first) + len(second), quiet=True)
        results, failures = paper.run_campaign([first, second], 2, prog)
        wall = time.perf_counter() - t0
    if failures:
        raise RuntimeError("; ".join(f"{f['label']}: {f['error']}" for f in failures))
    return {"paper_paths_s": wall}
