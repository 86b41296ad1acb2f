"""The ``unexplained`` object made only of effects not named (the refit without them no
longer shows the structure outside the vocabulary) carries the fit's figures like every
other ``unexplained`` object (docs/formats/diagnosis-report.md)."""

from bench.diagnosis.probes import with_not_named

GONE = [{"effect": "cable_length_offset", "probe": "thermal", "cable": None,
         "delta_bic": -3.0, "needed_beyond_bic": 4.0}]
FIGURES = {"reduced_chi2": 1.1, "rms_over_noise": 1.0488, "noise_source": "replicate visits"}


def test_not_named_alone_starts_from_the_fits_figures():
    out = with_not_named(None, GONE, FIGURES)
    assert {k: out[k] for k in FIGURES} == FIGURES
    assert out["effects_not_named"] == GONE
    assert out["summary"].startswith("cable_length_offset is not named")


def test_an_existing_object_keeps_its_own_figures_and_nothing_gone_changes_nothing():
    left = {"reduced_chi2": 3.0, "rms_over_noise": 1.73, "noise_source": "assumed",
            "findings": ["a drift"], "summary": "a drift"}
    out = with_not_named(left, GONE, FIGURES)
    assert out["reduced_chi2"] == 3.0 and out["findings"][0] == "a drift"
    assert with_not_named(None, [], FIGURES) is None
    assert with_not_named(left, [], FIGURES) is left
