"""95 % intervals of the diagnosis (``bench.diagnosis.fit``: linearised, widened by profile
refits) and their coverage over generated cases (``bench.evaluate.coverage``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.diagnosis.fit import (
    Z95,
    FitResult,
    Interval,
    _memo_key,
    _profile_end,
    held_at,
    linearised_interval,
    value_interval,
)
from bench.diagnosis.space import ParamSpace
from bench.evaluate import coverage, covers
from controller.robot import resolve_robot


def _fit(phi: float, se: float, curv_sd: float, chi2: float = 100.0,
         effect: str = "pulley_kinematics") -> FitResult:
    """A fit of one effect whose first parameter sits at ``phi`` with reported error ``se``
    and curvature error ``curv_sd`` (the others held)."""
    space = ParamSpace(resolve_robot("ipanema"), (effect,))
    n = len(space)
    p = space.neutral.copy()
    p[0] = phi
    stderr = np.full(n, np.inf)
    stderr[0] = se
    cov = np.zeros((n, n))
    cov[0, 0] = se ** 2
    curv = np.zeros((n, n))
    curv[0, 0] = curv_sd ** 2
    return FitResult(space, p, chi2, 200, chi2, stderr, cov, True, "", n_free=1,
                     curvature_cov=curv)


def _refit(fit: FitResult, rise: float, success: bool = True) -> FitResult:
    r = _fit(0.0, 1.0, 1.0, fit.chi2 + rise)
    r.success = success
    return r


def test_linearised_interval_is_the_value_plus_minus_1_96_errors_within_bounds():
    fit = _fit(0.06, 0.002, 0.001)
    iv = linearised_interval(fit, 0)
    assert iv.method == "linearised"
    assert iv.lo == pytest.approx(0.06 - Z95 * 0.002)
    assert iv.hi == pytest.approx(0.06 + Z95 * 0.002)
    # an uncertainty the fit cannot see widens it
    wide = linearised_interval(fit, 0, extra_var=0.002 ** 2)
    assert wide.hi - 0.06 == pytest.approx(Z95 * 0.002 * math.sqrt(2.0))
    # a radius cannot be negative: the interval stops at the bound
    low = linearised_interval(_fit(0.001, 0.002, 0.001), 0)
    assert low.lo == fit.space.lo[0] == 0.0


def test_profile_end_moves_out_only_where_the_refit_rises_less_than_the_curvature_says():
    fit = _fit(0.06, 0.002, 0.001)  # the reported error twice the curvature's: f = 4
    end = 0.06 + Z95 * 0.002
    target = (end - 0.06) ** 2 / 0.001 ** 2  # = 3.84 * 4
    assert target == pytest.approx(Z95 ** 2 * 4)
    # a quadratic valley: the refit rises as predicted, the end stays
    assert _profile_end(fit, 0, end, _refit(fit, target)) == end
    assert _profile_end(fit, 0, end, _refit(fit, 3 * target)) == end  # never narrowed
    # a flat valley: a rise of a quarter of the prediction puts the end twice as far
    assert _profile_end(fit, 0, end, _refit(fit, target / 4)) == pytest.approx(
        0.06 + 2 * (end - 0.06))
    # no rise at all: out to the bound; a refit that did not converge says nothing
    assert _profile_end(fit, 0, end, _refit(fit, 0.0)) == fit.space.hi[0]
    assert _profile_end(fit, 0, end, _refit(fit, 0.0, success=False)) == end
    # the lower end likewise, down to the bound at zero
    lo_end = 0.06 - Z95 * 0.002
    assert _profile_end(fit, 0, lo_end, _refit(fit, target / 4)) == pytest.approx(
        0.06 - 2 * (0.06 - lo_end))
    assert _profile_end(fit, 0, lo_end, _refit(fit, target / 1000)) == 0.0


def test_a_profile_refit_holds_its_parameter_at_the_end_not_at_the_models_value():
    """A fit's ``hold`` keeps a parameter at its space's ``neutral``: the profile's space
    (:func:`held_at`) moves that to the end, and the fits' memo tells the two apart (a
    profile refit once held the radius at the model's value at every end: its chi-square
    rose by 2170 wherever the end was)."""
    space = ParamSpace(resolve_robot("ipanema"), ("pulley_kinematics",))
    values = space.neutral.copy()
    values[0] = 0.07
    held = held_at(space, values)
    assert held.neutral[0] == 0.07 and space.neutral[0] == 0.05
    assert held.robot(values).pulley_radius[0] == pytest.approx(0.07)

    class _RM:  # what the memo key reads of a residual model
        s = slip_times = sqrt_w = len_rank = reference = None
        sd: dict = {}
        visit_sd = slack_threshold = cells_at = None
        visit_rows = False

    idx, hold = np.arange(3), np.ones(len(space), dtype=bool)
    assert _memo_key(space, _RM(), idx, values, 10, hold, False) != _memo_key(
        held, _RM(), idx, values, 10, hold, False)


def test_a_stiffness_interval_is_the_inverse_of_its_compliance_interval():
    space = ParamSpace(resolve_robot("ipanema"), ("mast_compliance",))
    p = space.params[0]
    assert p.kind == "inverse"
    assert value_interval(p, Interval(1e-6, 4e-6, "linearised")) == pytest.approx(
        (2.5e5, 1e6))
    lo, hi = value_interval(p, Interval(0.0, 4e-6, "profile"))
    assert lo == pytest.approx(2.5e5) and hi == math.inf


def _rec(effect: str, truth: float, value: float, se: float, iv=None, method=None) -> dict:
    return {"effect": effect, "key": "k", "truth": truth, "value": value, "stderr": se,
            "interval": iv, "method": method}


def test_coverage_counts_the_intervals_and_the_linearised_errors_per_effect():
    scores = [{"seed": 1, "intervals": [
        _rec("pulley_kinematics", 0.10, 0.105, 0.0016, [0.09, 0.12], "profile"),
        _rec("pulley_kinematics", 0.10, 0.1001, 0.001, [0.098, 0.102], "linearised")]},
        {"seed": 2, "intervals": [
            _rec("drum_scale", 1.0, 1.01, 0.001, [1.008, 1.012], "linearised")]}]
    cov = coverage(scores)
    assert cov["pulley_kinematics"]["params"] == 2
    assert cov["pulley_kinematics"]["covered"] == 1.0
    assert cov["pulley_kinematics"]["covered_linearised"] == 0.5  # z 3.1 not covered
    assert cov["pulley_kinematics"]["profiled"] == 1
    assert cov["drum_scale"]["covered"] == 0.0
    assert cov["all"]["params"] == 3 and cov["all"]["cases"] == 2
    # the z-scores 3.125, 0.1 (pulleys) and 10 (drum): their rms, and the misses by seed
    assert cov["pulley_kinematics"]["z_rms"] == pytest.approx(math.sqrt((3.125 ** 2 + 0.01) / 2))
    assert cov["pulley_kinematics"]["missed"] == []
    assert cov["drum_scale"]["missed"] == [[2, "k", 10.0]]
    # a report without intervals: the linearised one
    assert covers(_rec("mass", 10.0, 10.1, 0.1))
    assert not covers(_rec("mass", 10.0, 10.3, 0.1))


# ----- coverage over generated cases --------------------------------------------------------

#: every case's poses: a 3 x 2 grid, two visits (a continuous recording: its points as targets)
POSES = {"n": [3, 2, 1], "visits": 2}
#: recording classes (kind, sensors)
DWELL, NO_TRACKER, NO_TENSIONS = ("dwell", "all"), ("dwell", "no_tracker"), ("dwell", "no_tensions")
CONTINUOUS = ("continuous", "all")
#: the seeds of every kind's cases are the first ones from here (a rule, never picked by outcome)
SEED0 = 4300
#: the fewest parameters a kind's coverage is judged on (70 % intervals fail the floor)
MIN_PARAMS = 32


def binomial_floor(n: int, p: float = 0.95, alpha: float = 0.005) -> int:
    """The fewest of ``n`` intervals that must hold the truth: intervals of coverage ``p``
    hold fewer with probability below ``alpha``."""
    from scipy.stats import binom

    return int(binom.ppf(alpha, n, p))


@pytest.fixture
def predicted_rests(monkeypatch):
    """Cases recorded as ``cdpr evaluate`` records them but with the rest searches along a
    move started from the extrapolated rest (as ``conftest.record_scenario``: the same rows
    within about 1e-8 m; a continuous recording in a fraction of the CPU)."""
    import shutil

    import bench.evaluate as ev
    from bench.campaign import campaign_plant, run_campaign

    plain = ev.record

    def record(case: dict, rec) -> None:
        if "logger" in case.get("case", {}) or "change" in case.get("case", {}):
            return plain(case, rec)
        if rec.exists():
            shutil.rmtree(rec)
        sc = ev.scenario_of(case)
        run_campaign(sc, rec, plant=campaign_plant(sc, predict=True))

    monkeypatch.setattr(ev, "record", record)


def _case(effect: str, robot: str, seed: int, kind: str, sensors: str) -> dict:
    """One small generated case concealing ``effect`` alone, nothing outside the vocabulary,
    recorded and diagnosed (:func:`bench.evaluate.run_case`)."""
    from bench.evaluate import CASE_HOOKS, run_case

    if effect in CASE_HOOKS:  # the tracker's own errors: every sensor
        return run_case(seed, robot=robot, tracker=effect, kind=kind, poses=POSES)
    return run_case(seed, robot=robot, effects=(effect,), kind=kind, sensors=sensors,
                    oov="none", poses=POSES)


def _coverage(effect: str, robot: str, classes: tuple, n_cases: int) -> tuple[dict, str]:
    """The coverage (:func:`bench.evaluate.coverage`) of ``effect``'s intervals over cases
    ``SEED0 ..`` (``n_cases``, the recording classes in turn) named right, and what a
    failure should say: the z-scores' rms and the misses by seed."""
    from bench.evaluate import one_blas_thread

    one_blas_thread()
    scores = [_case(effect, robot, SEED0 + i, *classes[i % len(classes)])
              for i in range(n_cases)]
    right = [s for s in scores if s["exact"] and not s["unexplained"]]
    wrong = [(s["seed"], s["named"], s["unexplained"]) for s in scores if s not in right]
    assert len(right) >= 0.8 * len(scores), wrong  # the coverage of few cases says little
    none = {"params": 0, "cases": 0, "covered": math.nan, "covered_ci95": None, "z_rms": None,
            "missed": []}
    cov = coverage(right).get(effect, none)
    per_class = {}
    for c in classes:
        of_c = [s for i, s in enumerate(scores) if classes[i % len(classes)] == c]
        got = coverage([s for s in of_c if s in right]).get(effect, none)
        k = round(got["covered"] * got["params"]) if got["params"] else 0
        per_class["_".join(c)] = f"{k}/{got['params']}"
    return cov, (f"{effect}: {cov['params']} params in {cov['cases']} cases, covered "
                 f"{cov['covered']:.3f} {cov['covered_ci95']} (by class {per_class}), z rms "
                 f"{cov['z_rms']}, missed (seed, key, z) {cov['missed']}, not right {wrong}")


def test_binomial_floor_fails_intervals_of_70_percent():
    """The bound the coverage tests use: 95 % intervals pass it (but for 1 in 200), intervals
    that cover 70 % of the time fail it with the parameter counts these tests have."""
    from scipy.stats import binom

    for n in (MIN_PARAMS, 40, 48, 64):
        k = binomial_floor(n)
        assert binom.cdf(k - 1, n, 0.95) < 0.005
        assert binom.sf(k - 1, n, 0.70) < 0.1, n


class BelowFloor(AssertionError):
    """Fewer intervals held the truth than 95 % intervals would (the binomial floor): the
    only failure a strictly xfailed kind expects (too few cases named right, too few
    parameters or a crash still fail)."""


def _kind(effect: str, robot: str, classes: tuple, n_cases: int, *marks):
    return pytest.param(effect, robot, classes, n_cases, marks=marks,
                        id=f"{effect}-{'+'.join('_'.join(c) for c in classes)}")


#: per effect kind of the vocabulary: the robot, the recording classes taken in turn, the
#: cases (about 40 parameters expected: one to three per case for the lengths, drums, EA,
#: sag, mass, latency; more for the rest). The suite runs the weak kinds on dwells with every
#: sensor (the cheapest class, ~0.6 CPU-s a case); ``make coverage`` (marker ``coverage``)
#: every kind on its other recording classes.
KINDS = [
    _kind("cable_length_offset", "rocaspect", (DWELL,), 26),
    _kind("drum_scale", "rocaspect", (DWELL,), 22),
    _kind("cable_elasticity", "rocaspect", (DWELL,), 32),
    _kind("pulley_kinematics", "ipanema", (DWELL,), 4),
    _kind("cable_length_offset", "rocaspect", (NO_TRACKER, NO_TENSIONS, CONTINUOUS), 27,
          pytest.mark.coverage),
    _kind("drum_scale", "rocaspect", (NO_TRACKER, NO_TENSIONS, CONTINUOUS), 24,
          pytest.mark.coverage),
    _kind("cable_elasticity", "rocaspect", (NO_TRACKER, NO_TENSIONS, CONTINUOUS), 26,
          pytest.mark.coverage),
    _kind("cable_sag", "rocaspect", (DWELL,), 40, pytest.mark.coverage),
    _kind("exit_point_offset", "rocaspect", (DWELL, NO_TENSIONS), 12, pytest.mark.coverage),
    _kind("mast_compliance", "rocaspect", (DWELL, NO_TENSIONS), 8, pytest.mark.coverage),
    _kind("load_cell_calibration", "rocaspect", (DWELL, NO_TRACKER), 14, pytest.mark.coverage),
    _kind("platform_mass", "rocaspect", (DWELL, NO_TRACKER), 28, pytest.mark.coverage),
    # 42 of 48 (the floor 41): every sensor 24/24, without load cells 18/24 (4301, a low
    # draw whose fit takes the initial tensions: z up to 4.6; 4303, 4305 7/8)
    _kind("pulley_kinematics", "ipanema", (DWELL, NO_TENSIONS), 6, pytest.mark.coverage),
    _kind("tracker_frame", "rocaspect", (DWELL,), 7, pytest.mark.coverage),
    _kind("tracker_latency", "rocaspect", (CONTINUOUS,), 40, pytest.mark.coverage),
]


@pytest.mark.parametrize("effect,robot,classes,n_cases", KINDS)
def test_95_percent_intervals_cover_the_truth(effect, robot, classes, n_cases,
                                              predicted_rests):
    """Per effect kind, over small generated cases named right, the report's 95 % intervals
    hold the truth of their parameters as often as 95 % intervals do (a binomial bound that
    intervals covering 70 % of the time fail: at least 32 parameters)."""
    cov, say = _coverage(effect, robot, classes, n_cases)
    n = cov["params"]
    assert n >= MIN_PARAMS, say
    if round(cov["covered"] * n) < binomial_floor(n):
        raise BelowFloor(say)



@pytest.mark.parametrize("theta", [0.0, 1.5, 3.0, 6.0])
def test_selective_intervals_cover_the_truth_of_parameters_reported_past_a_threshold(theta):
    """Estimates x ~ N(theta, 1) reported only when |x| > 3 (the report's rule): the
    selective 95 % interval holds theta 95 % of the time among the reported ones (drawn
    from the normal truncated to |x| > 3), where x +- 1.96 holds a theta of 0 never."""
    from scipy.stats import truncnorm

    from bench.diagnosis.fit import selective_interval

    rng = np.random.default_rng(7)
    c, n = 3.0, 300
    # P(x > c) against P(x < -c): each side drawn in its share
    p_hi = 1.0 - truncnorm.cdf(c, -np.inf, np.inf, loc=theta)  # (plain normal tail)
    p_lo = truncnorm.cdf(-c, -np.inf, np.inf, loc=theta)
    hi_side = rng.random(n) < p_hi / (p_hi + p_lo)
    x = np.where(hi_side,
                 truncnorm.rvs(c - theta, np.inf, loc=theta, size=n, random_state=rng),
                 truncnorm.rvs(-np.inf, -c - theta, loc=theta, size=n, random_state=rng))
    ivs = [selective_interval(float(v), 0.0, 1.0, c) for v in x]
    hit = np.mean([lo <= theta <= hi for lo, hi in ivs])
    assert 0.92 <= hit <= 0.98, hit
    if theta == 0.0:
        assert not np.any(np.abs(x) <= Z95)  # the plain interval never holds it


def test_a_selective_interval_far_past_the_threshold_is_the_plain_one():
    from bench.diagnosis.fit import selective_interval

    lo, hi = selective_interval(2.0 + 12.0 * 0.1, 2.0, 0.1, 3.0)
    assert lo == pytest.approx(3.2 - Z95 * 0.1, abs=1e-4)
    assert hi == pytest.approx(3.2 + Z95 * 0.1, abs=1e-4)
    assert selective_interval(2.25, 2.0, 0.1, 3.0) is None  # not past the threshold
    lo, hi = selective_interval(-0.31, 0.0, 0.1, 3.0)  # just past: reaches over 0, and
    assert hi > 0.0 and -0.31 - Z95 * 0.1 < lo < -0.31  # its far end comes in


def test_a_parameter_reported_just_past_its_threshold_gets_the_selective_interval():
    """The report's rule (:func:`report_threshold`) and the interval (:func:`selective`):
    a parameter 3.1 errors from the model's value reaches back over it; 30 errors out it
    keeps its linearised interval."""
    from bench.diagnosis.report import report_threshold, selective

    p = _fit(0.0, 1e-3, 1e-3).space.params[0]
    near = _fit(p.neutral + 3.1e-3, 1e-3, 1e-3)
    s, c = report_threshold(p, 1e-3)
    assert s == pytest.approx(1e-3) and c == pytest.approx(3.0)
    iv = selective(near, 0, linearised_interval(near, 0))
    assert iv.method == "selective" and iv.lo < p.neutral < iv.hi, (iv, p.neutral)
    far = _fit(p.neutral + 30e-3, 1e-3, 1e-3)
    lin = linearised_interval(far, 0)
    assert selective(far, 0, lin) == lin
    # an interval a refit had widened keeps saying so, and the evaluation still counts it
    prof = Interval(lin.lo - 1e-4, lin.hi, "profile")
    got = selective(near, 0, Interval(near.phi[0] - 1e-3, near.phi[0] + 1e-3, "profile"))
    assert got.method == "profile+selective"
    assert selective(far, 0, prof).method == "profile"
    cov = coverage([{"seed": 1, "intervals": [
        _rec("mast_compliance", 0.0, 3.1e-3, 1e-3, [got.lo, got.hi], got.method),
        _rec("mast_compliance", 0.0, 3.1e-3, 1e-3, [-1e-3, 7e-3], "selective")]}])
    assert cov["mast_compliance"]["profiled"] == 1
    assert cov["mast_compliance"]["selective"] == 2
