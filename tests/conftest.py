"""Shared test fixtures and hypothesis profiles.

``make test`` runs the property-based tests with the "ci" profile: a fixed seed
(derandomized) and bounded examples, seconds per test. ``make test-deep``
(``CDPR_HYPOTHESIS=deep``) runs many more examples and longer step sequences; "dev" is
in between. ``HYPOTHESIS_PROFILE`` is read too (older name).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

settings.register_profile(
    "ci", max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow],
    derandomize=True,
)
settings.register_profile("dev", max_examples=200, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile(
    "deep", max_examples=2000, deadline=None, stateful_step_count=100,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
settings.load_profile(os.environ.get("CDPR_HYPOTHESIS")
                      or os.environ.get("HYPOTHESIS_PROFILE", "ci"))


@pytest.fixture(scope="session")
def record_scenario() -> Callable[[dict, Path], Path]:
    """``record(scenario, folder)``: the campaign of a scenario (its JSON text as a dict)
    recorded into the directory ``folder``, as ``cdpr sim`` records it but with the rest
    searches along a move started from the extrapolated rest
    (:attr:`firmware_sim.plant.Plant.predict`: the same rows within the plant's force
    tolerance, about 1e-8 m; a continuous recording in up to ten times less CPU). Returns
    ``folder``."""
    from bench.campaign import campaign_plant, run_campaign
    from firmware_sim.scenario import parse_scenario

    def record(scenario: dict, folder: Path) -> Path:
        sc = parse_scenario(scenario)
        return run_campaign(sc, folder, plant=campaign_plant(sc, predict=True))

    return record
