"""The printed report of ``cdpr diagnose`` (without ``--json``) gives a parameter's 95 %
interval beside its standard error where the interval is not the value ± q standard errors
(issue 32, item 5: a profile refit widened a pulley radius's interval; only the JSON report
said so, the printed one showed the narrower standard error alone)."""

from __future__ import annotations

from bench.commands.diagnose import _human


def _report() -> dict:
    """A report (cdpr-diagnosis/1) with one pulley effect: ``r_11``'s interval linearised,
    ``r_42``'s widened by a profile refit; and a mast stiffness whose upper end is open."""
    pulleys = {"name": "pulley_kinematics", "explains": "swivel pulleys",
               "params": {"r_11": 0.008, "r_42": 0.0073},
               "stderr": {"r_11": 1e-4, "r_42": 3.4e-4},
               "interval95": {"r_11": [0.0078, 0.0082], "r_42": [0.0061, 0.0091]},
               "interval_method": {"r_11": "linearised", "r_42": "profile"},
               "evidence": {"heldout_pose_rms_before_m": 7e-3,
                            "heldout_pose_rms_after_m": 2e-4, "delta_bic": -1e5},
               "undetermined": [], "alternatives": []}
    masts = {"name": "mast_compliance", "explains": "masts bend",
             "params": {"kx_1": 2e5}, "stderr": {"kx_1": 3e4},
             "interval95": {"kx_1": [1.5e5, None]},
             "interval_method": {"kx_1": "profile+selective"},
             "evidence": {"heldout_pose_rms_before_m": None, "heldout_pose_rms_after_m": None,
                          "delta_bic": -50.0},
             "undetermined": [], "alternatives": []}
    none4 = {"pose_rms_m": None, "pose_max_m": None, "exit_point_rms_m": None,
             "tension_rms_n": None, "wrench_rms": None, "heldout_pose_rms_m": None}
    return {"recording": "rec", "samples": 10, "baseline": none4, "fitted": none4,
            "mismatch": {"summary": "pose error"}, "unexplained": None,
            "effects": [pulleys, masts], "model": None}


def _line(text: str, key: str) -> str:
    return next(line for line in text.splitlines() if line.strip().startswith(key + " "))


def test_a_profile_interval_is_printed_beside_the_standard_error():
    text = _human(_report())
    assert "95 % [0.0061, 0.0091] (profile)" in _line(text, "r_42")
    assert "95 %" not in _line(text, "r_11")  # the value ± q errors: nothing to add


def test_an_open_end_of_an_interval_reads_inf():
    assert "95 % [150000, inf] (profile+selective)" in _line(_human(_report()), "kx_1")


def test_a_report_without_intervals_prints_as_before():
    rep = _report()
    for e in rep["effects"]:
        del e["interval95"], e["interval_method"]
    assert "95 %" not in _human(rep)
