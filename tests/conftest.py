"""Shared test fixtures and hypothesis profiles.

``make test`` runs the property-based tests with the "ci" profile: a fixed seed
(derandomized) and bounded examples, seconds per test. ``make test-deep``
(``CDPR_HYPOTHESIS=deep``) runs many more examples and longer step sequences; "dev" is
in between. ``HYPOTHESIS_PROFILE`` is read too (older name).
"""

from __future__ import annotations

import os

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
