"""Helpers of the property-based state machines (tests/test_prop_*.py).

- :func:`machine_settings`: one machine's examples and steps in the profile that runs
  (tests/conftest.py): the numbers given for the "ci" profile (``make test``), scaled up
  for "dev" and "deep" (``make test-deep``);
- :class:`RuleCounter`: how often each rule ran (module-level, for the coverage tests that
  assert every rule ran many times), with :func:`hypothesis.event` so that
  ``--hypothesis-show-statistics`` lists the rules reached too.
"""

from __future__ import annotations

import collections
import functools
import os
import time

from hypothesis import HealthCheck, Phase, settings
from hypothesis import event as _event

#: examples of the "deep" and "dev" profiles relative to "ci"
SCALE = {"ci": 1, "dev": 2, "deep": 5}


def profile() -> str:
    return os.environ.get("CDPR_HYPOTHESIS") or os.environ.get("HYPOTHESIS_PROFILE", "ci")


def phases(scale: int) -> list[Phase]:
    """Hypothesis phases of a state machine: no explanation (minutes of replays); in the
    "ci" profile no shrinking either (a failure is reported at once with the whole
    sequence that failed; replaying a HAL or loop run a few hundred times while shrinking
    takes many minutes on a loaded machine). ``CDPR_HYPOTHESIS_SHRINK=1`` shrinks anyway."""
    out = [Phase.explicit, Phase.reuse, Phase.generate, Phase.target]
    if scale > 1 or os.environ.get("CDPR_HYPOTHESIS_SHRINK") == "1":
        out.append(Phase.shrink)
    return out


def machine_settings(examples: int, steps: int) -> settings:
    """Settings of one state machine: ``examples`` runs of up to ``steps`` rules in the "ci"
    profile, ``SCALE[profile]`` times as many runs (and twice the steps) in the others."""
    scale = SCALE.get(profile(), 1)
    return settings(
        settings.default,
        max_examples=examples * scale,
        stateful_step_count=steps * (2 if scale > 1 else 1),
        deadline=None,
        phases=phases(scale),
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much,
                               HealthCheck.data_too_large],
    )


def event(text: str) -> None:
    """hypothesis.event inside a hypothesis run; nothing when a rule is called by hand."""
    try:
        _event(text)
    except Exception:
        pass


class RuleCounter(collections.Counter):
    """Counts of the rules that ran (``@counter.counted`` on each rule); ``seconds`` the
    wall time spent in each (nested rules counted in both)."""

    def __init__(self, *a, **kw) -> None:
        super().__init__(*a, **kw)
        self.seconds: collections.Counter = collections.Counter()

    def counted(self, fn):
        name = fn.__name__

        @functools.wraps(fn)
        def wrapper(*a, **kw):
            self[name] += 1
            event(f"rule {name}")
            t0 = time.perf_counter()
            try:
                return fn(*a, **kw)
            finally:
                self.seconds[name] += time.perf_counter() - t0

        return wrapper

    def report(self) -> str:
        """``rule: runs, seconds`` per rule, most time first."""
        return ", ".join(f"{name}: {self[name]} in {sec:.1f} s"
                         for name, sec in self.seconds.most_common())

    def missing(self, rules: list[str], at_least: int) -> dict[str, int]:
        """Rules that ran fewer than ``at_least`` times: {rule: count}."""
        return {r: self[r] for r in rules if self[r] < at_least}
