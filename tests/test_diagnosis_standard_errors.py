"""Standard errors of the diagnosis fits (``bench.diagnosis.fit.standard_errors``): checked
against the spread of the estimates over many simulated data sets (a linear model, fitted
by weighted least squares the way the diagnosis whitens its residuals)."""

from __future__ import annotations

import numpy as np

from bench.diagnosis.fit import ErrorStructure, standard_errors


def _wls(X: np.ndarray, y: np.ndarray, w: np.ndarray):
    """Whitened Jacobian, estimate and whitened residuals of a weighted linear fit."""
    J = X * np.sqrt(w)[:, None]
    beta = np.linalg.lstsq(J, y * np.sqrt(w), rcond=None)[0]
    return J, beta, (y - X @ beta) * np.sqrt(w)


def _spread_and_se(make, reps: int = 400, seed: int = 3):
    rng = np.random.default_rng(seed)
    est, ses = [], []
    for _ in range(reps):
        X, y, errors = make(rng)
        J, beta, r = _wls(X, y, errors.weights)
        _, se = standard_errors(J, float(r @ r), errors.n_eff, r=r, errors=errors)
        est.append(beta)
        ses.append(se)
    return np.std(est, axis=0), np.sqrt(np.mean(np.square(ses), axis=0))


def test_weighted_rows_with_independent_errors_are_not_inflated():
    """Rows of moves weighed down to a quarter (and a few dwells at full weight), their
    errors independent after all: the errors are those of the weighted estimator, half
    the ones that trust the weights."""
    n = 240
    w = np.where(np.arange(n) % 20 == 0, 1.0, 0.25)

    def make(rng):
        X = np.column_stack([np.ones(n), rng.uniform(-1, 1, n)])
        y = X @ np.array([0.5, -2.0]) + rng.normal(0.0, 1.0, n)
        e = ErrorStructure(w, np.zeros(n, int), np.zeros(n, int), np.arange(n),
                           np.zeros(n, int), float(w.sum()))
        return X, y, e

    spread, se = _spread_and_se(make)
    assert np.all(np.abs(se / spread - 1.0) < 0.15), (se, spread)
    # the covariance that believes the weights (rows of variance 3) is too large by far
    X, _, e = make(np.random.default_rng(0))
    J = X * np.sqrt(w)[:, None]
    naive = np.sqrt(np.diag(np.linalg.inv(J.T @ J)))
    assert np.all(naive / spread > 1.6)


def test_shared_errors_inflate_what_they_share_and_nothing_else():
    """An error shared by the samples of a move (a random intercept per move): the offset,
    which the move's samples see together, gets its inflated error; a slope that averages
    to zero within each move is as sure as the independent noise makes it."""
    moves, per = 30, 10
    n = moves * per
    move = np.repeat(np.arange(moves), per)
    x = np.tile(np.linspace(-1.0, 1.0, per), moves)

    def make(rng):
        X = np.column_stack([np.ones(n), x])
        y = X @ np.array([1.0, 0.3]) + rng.normal(0.0, 1.0, moves)[move] \
            + rng.normal(0.0, 1.0, n)
        e = ErrorStructure(np.ones(n), np.zeros(n, int), np.zeros(n, int), move,
                           np.zeros(n, int), float(n))
        return X, y, e

    spread, se = _spread_and_se(make)
    assert np.all(np.abs(se / spread - 1.0) < 0.15), (se, spread)
    # the offset's error is several times the independent one, the slope's is not
    assert spread[0] > 2.0 * np.sqrt(2.0 / n)
    assert spread[1] < 1.3 * np.sqrt(2.0 / np.sum(x ** 2))


def test_each_kind_of_quantity_keeps_its_own_level():
    """Two kinds of quantity whose residuals differ tenfold in size relative to their assumed
    noise (a length noise underestimated, a force noise right): each parameter gets the
    error of the kind that fixes it."""
    n = 200
    kinds = np.repeat([0, 1], n // 2)

    def make(rng):
        X = np.zeros((n, 2))
        X[kinds == 0, 0] = 1.0
        X[kinds == 1, 1] = 1.0
        y = X @ np.array([0.2, -0.1]) + np.where(kinds == 0, 10.0, 1.0) * rng.normal(0, 1, n)
        e = ErrorStructure(np.ones(n), kinds, kinds, np.arange(n), np.zeros(n, int),
                           float(n))
        return X, y, e

    spread, se = _spread_and_se(make)
    assert np.all(np.abs(se / spread - 1.0) < 0.15), (se, spread)


def test_an_error_shared_by_few_visits_is_not_understated_by_the_fit_absorbing_it(monkeypatch):
    """A dozen visits, each with its own error shared by its rows, against six parameters
    that differ from visit to visit: the fit absorbs half of the visits' error, so the
    plain moments of its residuals under-state it (errors too small by about 1.4). The
    components estimated against the fit's projection give the spread of the estimates."""
    import bench.diagnosis.fit as fit

    moves, per, p = 12, 10, 6
    n = moves * per
    move = np.repeat(np.arange(moves), per)
    design = np.random.default_rng(11).normal(0.0, 1.0, (moves, p - 1))
    X = np.column_stack([np.ones(n), design[move]])

    def make(rng):
        y = X @ np.linspace(-1.0, 1.0, p) + rng.normal(0.0, 1.0, moves)[move] \
            + rng.normal(0.0, 0.3, n)
        e = ErrorStructure(np.ones(n), np.zeros(n, int), np.zeros(n, int), move,
                           np.zeros(n, int), float(n))
        return X, y, e

    spread, se = _spread_and_se(make)
    assert np.all(np.abs(se / spread - 1.0) < 0.15), (se, spread)
    # the plain moments of the fitted residuals: too small
    monkeypatch.setattr(fit, "_unbiased_components",
                        lambda Js, sw, kinds, stats, *_: stats / np.where(
                            np.concatenate([k.pairs for k in kinds]) > 0,
                            np.concatenate([k.pairs for k in kinds]), 1.0))
    spread0, se0 = _spread_and_se(make)
    assert np.all(se0 / spread0 < 0.85), (se0, spread0)


def _pruned_z(b2: float, reps: int = 2000, seed: int = 5):
    """z-scores of a kept slope after a correlated one was pruned (within two of its standard
    errors of zero) and held there: with the pruned fit's errors and with the reported ones
    (:func:`pruning_bias_var` added)."""
    from bench.diagnosis.fit import FitResult, pruning_bias_var

    rng = np.random.default_rng(seed)
    n = 50
    x1 = rng.normal(size=n)
    X = np.column_stack([x1, 0.95 * x1 + np.sqrt(1 - 0.95 ** 2) * rng.normal(size=n)])
    cov = np.linalg.inv(X.T @ X)
    plain, reported = [], []
    for _ in range(reps):
        y = X @ np.array([1.0, b2 * np.sqrt(cov[1, 1])]) + rng.normal(size=n)
        beta = cov @ X.T @ y
        if abs(beta[1]) >= 2.0 * np.sqrt(cov[1, 1]):
            continue
        full = FitResult(None, beta, 0.0, n, 0.0, np.sqrt(np.diag(cov)), cov, True, "")
        b1 = float(x1 @ y / (x1 @ x1))
        se1 = 1.0 / np.sqrt(x1 @ x1)
        bias = pruning_bias_var(full, np.array([False, True]), np.zeros(2))[0]
        plain.append((b1 - 1.0) / se1)
        reported.append((b1 - 1.0) / np.sqrt(se1 ** 2 + bias))
    return float(np.sqrt(np.mean(np.square(plain)))), float(np.sqrt(np.mean(np.square(reported))))


def test_pruning_a_parameter_that_is_not_zero_widens_what_it_moved_into():
    """A slope correlated (0.95) with a kept one, not zero but within two standard errors of
    it: the pruned fit moves it into the kept slope, whose own error does not show it (RMS
    z-score 5); the reported error holds part of it (an unbiased estimate of the squared
    shift from a departure the pruning already found small cannot hold it all). A slope
    truly zero widens the kept one's error a little."""
    plain, reported = _pruned_z(1.5)
    assert plain > 4.0 and reported < 0.8 * plain, (plain, reported)
    plain0, reported0 = _pruned_z(0.0)
    assert 0.8 < reported0 < plain0 < 1.1, (plain0, reported0)


def test_an_error_by_the_direction_of_approach_widens_an_offset_where_directions_differ():
    """Hysteresis: each cable reads +-h by the direction of its last move, on top of
    independent noise. A per-cable offset takes up the mean of the two directions; what the
    imbalance of directions moves into it is an error the plain levels do not see (each row
    looks independent) and the direction component does. A slope along a balanced design
    is not widened."""
    cols, per = 4, 60
    n = cols * per
    col = np.repeat(np.arange(cols), per)
    rng0 = np.random.default_rng(2)
    # two thirds of one direction: the offset takes up a third of the hysteresis
    s = np.where(rng0.random(n) < 2 / 3, 1.0, -1.0)
    x = rng0.uniform(-1, 1, n)
    X = np.column_stack([(col[:, None] == np.arange(cols)).astype(float), x])

    def make(rng):
        y = X @ np.r_[np.zeros(cols), 0.5] + rng.normal(0.0, 1.0, cols)[col] * s \
            + rng.normal(0.0, 0.3, n)
        e = ErrorStructure(np.ones(n), np.zeros(n, int), col, np.arange(n),
                           np.zeros(n, int), float(n), s)
        return X, y, e

    spread, se = _spread_and_se(make)
    assert np.all(np.abs(se / spread - 1.0) < 0.2), (se, spread)

    def make_plain(rng):
        X_, y, e = make(rng)
        return X_, y, ErrorStructure(e.weights, e.kinds, e.columns, e.moves, e.stretches,
                                     e.n_eff)

    spread0, se0 = _spread_and_se(make_plain)
    assert np.all(se0[:cols] / spread0[:cols] < 0.75), (se0, spread0)


def _blended_visits(knots: bool):
    """A continuous recording with dwells: ten stops (the first the initialisation, where the
    encoders are referenced: no error), twelve rows on each move between two stops (weighed
    down to four independent samples). Each stop has its own length error, and the rows of a
    move carry a blend of those of its two ends (linear in time), plus white noise."""
    stops, per = 10, 12
    t_stop = np.arange(stops) * (per + 1.0)
    f = np.arange(1, per + 1) / (per + 1.0)
    t = np.concatenate([t_stop, (t_stop[:-1, None] + f * (per + 1.0)).ravel()])
    kind = np.r_[np.zeros(stops, int), np.full((stops - 1) * per, 4)]
    w = np.where(kind == 0, 1.0, 4.0 / per)
    H = np.zeros((len(t), stops))
    H[np.arange(stops), np.arange(stops)] = 1.0
    a = np.repeat(np.arange(stops - 1), per)
    H[stops + np.arange(len(a)), a] = 1.0 - np.tile(f, stops - 1)
    H[stops + np.arange(len(a)), a + 1] = np.tile(f, stops - 1)
    H[:, 0] = 0.0  # the initialisation's stop
    move = np.r_[np.arange(stops), stops + a]
    x_stop = np.random.default_rng(7).uniform(-1.0, 1.0, stops)
    x = np.r_[x_stop, (1.0 - np.tile(f, stops - 1)) * x_stop[a]
              + np.tile(f, stops - 1) * x_stop[a + 1]]
    X = np.column_stack([(t > 0).astype(float), x])
    sig_k, sig_w = 1.0, 0.3

    def make(rng):
        y = X @ np.array([0.5, -1.0]) + H @ rng.normal(0.0, sig_k, stops) \
            + rng.normal(0.0, sig_w, len(t))
        e = ErrorStructure(w, kind, np.zeros(len(t), int), move, np.zeros(len(t), int),
                           float(w.sum()), knots=sig_k * H if knots else None)
        return X, y, e

    return make


def test_an_error_that_moves_blend_between_stops_is_counted_whole():
    """The error of each stop reaches the rows of the moves on both sides of it and the
    dwell there: an error no grouping by move or target holds (the rows of one move share
    two stops' errors, in proportions that change along it). Known from the replicate dwells
    (``knots``), it gives the spread of the estimates; the components alone, estimated from
    the residuals grouped by move, under-state it."""
    spread, se = _spread_and_se(_blended_visits(True))
    assert np.all(np.abs(se / spread - 1.0) < 0.15), (se, spread)
    spread0, se0 = _spread_and_se(_blended_visits(False))
    assert np.any(se0 / spread0 < 0.8), (se0, spread0)


def _independent(n: int) -> ErrorStructure:
    return ErrorStructure(np.ones(n), np.zeros(n, int), np.zeros(n, int), np.arange(n),
                          np.zeros(n, int), float(n))


def test_a_parameter_the_residuals_do_not_see_is_undetermined_not_exact():
    """A parameter whose column is only the rounding of a finite difference (a mast
    stiffness that no sample's residual moves with) has no information: its error is
    infinite, not the zero that the covariance's truncated inverse gave it (reported to
    1e-15 of itself, 40 times off). The others keep the errors they have without it."""
    rng = np.random.default_rng(5)
    n = 200
    X = np.column_stack([np.ones(n), rng.uniform(-1, 1, n)])
    y = X @ np.array([0.3, 1.5]) + rng.normal(0.0, 1.0, n)
    J, beta, r = _wls(X, y, np.ones(n))
    _, se_two = standard_errors(J, float(r @ r), float(n), r=r, errors=_independent(n))
    noise = rng.normal(0.0, 1e-9, n)  # a column of rounding noise
    J3 = np.column_stack([J, noise])
    _, se = standard_errors(J3, float(r @ r), float(n), r=r, errors=_independent(n))
    assert np.isinf(se[2])
    assert np.allclose(se[:2], se_two, rtol=1e-6)
    # two parameters with one column (exact look-alikes): neither is fixed by the data
    J4 = np.column_stack([J, J[:, 1]])
    _, se4 = standard_errors(J4, float(r @ r), float(n), r=r, errors=_independent(n))
    assert np.isinf(se4[1]) and np.isinf(se4[2]) and np.isclose(se4[0], se_two[0], rtol=1e-6)


def test_a_smooth_well_determined_fit_keeps_its_errors():
    """Nothing without information: every error finite, the classical ones (independent
    errors of unit variance: sqrt of the diagonal of (J^T J)^-1, to the spread of the
    residuals), however different the parameters' scales."""
    rng = np.random.default_rng(6)
    n = 300
    X = np.column_stack([np.ones(n), rng.uniform(-1, 1, n), 1e-4 * rng.uniform(-1, 1, n)])
    y = X @ np.array([0.3, 1.5, 2e4]) + rng.normal(0.0, 1.0, n)
    J, beta, r = _wls(X, y, np.ones(n))
    _, se = standard_errors(J, float(r @ r), float(n), r=r, errors=_independent(n))
    classical = np.sqrt(np.diag(np.linalg.inv(J.T @ J)) * float(r @ r) / (n - 3))
    assert np.all(np.isfinite(se))
    assert np.allclose(se, classical, rtol=0.05)


def _space(kinds, scale):
    from types import SimpleNamespace

    return SimpleNamespace(params=[SimpleNamespace(kind=k) for k in kinds],
                           scale=np.asarray(scale, dtype=float))


def test_a_column_of_rounding_noise_is_held_before_the_fit():
    """The compliance of a mast no residual moves with: its finite-difference column is
    noise a billionth of the others' (in the parameters' scales), which the scale-blind
    Gram-Schmidt test took for a new direction (the fit then wandered along it to a
    stiffness 40 times off). It is held; real columns of any units are not."""
    from bench.diagnosis.fit import null_parameters

    rng = np.random.default_rng(7)
    n = 120
    a, b = rng.normal(size=n), rng.normal(size=n)
    sp = _space(["offset", "inverse", "inverse"], [1e-3, 1e-6, 1e-6])
    # per unit of each parameter: an offset in metres, compliances in m/N (huge columns)
    J = np.column_stack([a / 1e-3, b / 1e-6, rng.normal(0.0, 1e-3, n)])
    assert list(null_parameters(J, sp)) == [False, False, True]
    # nothing to find: two real compliance columns, one a hundred times weaker than the other
    J2 = np.column_stack([a / 1e-3, b / 1e-6, 0.01 * rng.normal(size=n) / 1e-6])
    assert not null_parameters(J2, sp).any()


def test_a_held_parameter_the_data_cannot_fix_widens_what_it_moves_into():
    """A common gain of the load cells and the platform's mass (no tracker): the statics see
    only their ratio, the cables' stretch tells the mass to 12 %. The mass, 8 % off, is
    pruned (within two of its errors of the model's value) and moved whole into the gain,
    whose pruned error (0.05 %) cannot show it; the estimate of that shift from the mass's
    departure is zero whatever it is (the data do not see it). A held parameter wider than
    its effect's meaningful range (``unfixed``) gives the kept one at least the error the
    full fit gave it beside it: z-scores near 1. Nothing changes where it is not marked."""
    from bench.diagnosis.fit import FitResult, pruning_bias_var

    rng = np.random.default_rng(11)
    n = 400
    x = rng.uniform(0.5, 1.5, n)
    # y = g * x (statics: gain over mass, known to 5e-4) and z = m * x (stretch: the mass's
    # own scale, known to 12 %): parameters g and m, truth g = 1, m = 1.08
    sy, sz = 5e-4 * np.sqrt(n) * np.mean(x), 0.12 * np.sqrt(n) * np.mean(x)
    X = np.zeros((2 * n, 2))
    X[:n, 0], X[:n, 1] = x / sy, -x / sy  # y - (g - m) x: the statics see g - m
    X[n:, 1] = x / sz
    cov = np.linalg.inv(X.T @ X)
    z_old, z_new = [], []
    for _ in range(300):
        yy = np.concatenate([(0.0 - 0.08) * x / sy, 0.08 * x / sz]) + rng.normal(size=2 * n)
        beta = cov @ X.T @ yy  # departures of (g - 1, m - 1)
        if abs(beta[1]) >= 2.0 * np.sqrt(cov[1, 1]):
            continue
        full = FitResult(None, beta, 0.0, 2 * n, 0.0, np.sqrt(np.diag(cov)), cov, True, "")
        Xk = X[:, :1]
        g = float(np.linalg.lstsq(Xk, yy, rcond=None)[0][0])  # m held at the model's value
        se_g = float(np.sqrt(np.linalg.inv(Xk.T @ Xk)[0, 0]))
        weak = np.array([False, True])
        old = pruning_bias_var(full, weak, np.zeros(2))[0]
        new = pruning_bias_var(full, weak, np.zeros(2), weak)[0]
        assert new >= old
        assert pruning_bias_var(full, weak, np.zeros(2), np.zeros(2, bool))[0] == old
        z_old.append(g / np.sqrt(se_g ** 2 + old))
        z_new.append(g / np.sqrt(se_g ** 2 + new))
    rms_old = float(np.sqrt(np.mean(np.square(z_old))))
    rms_new = float(np.sqrt(np.mean(np.square(z_new))))
    assert len(z_old) > 100
    assert rms_old > 20.0 and 0.4 < rms_new < 1.25, (rms_old, rms_new)


def test_held_parameters_the_data_cannot_fix_are_those_the_report_calls_undetermined():
    """The mass known to 12 % (no tracker) cannot be fixed; known to 0.5 kg it can; a load
    cell's offset known to 1 N is fixed (holding it widens nothing: its gain keeps the
    pruned fit's error where the offset is zero, as on most recordings)."""
    from bench.diagnosis.fit import unfixed_parameters as unfixed
    from bench.diagnosis.space import ParamSpace
    from controller.robot import resolve_robot

    sp = ParamSpace(resolve_robot("cogiro"), ["platform_mass", "load_cell_calibration"])
    keys = [p.key for p in sp.params]
    se = np.full(len(keys), 1e-4)
    se[keys.index("mass")] = 0.12 * sp.neutral[keys.index("mass")]
    se[keys.index("offset_11")] = 1.0
    u = unfixed(sp, se)
    assert u[keys.index("mass")] and not u[keys.index("offset_11")]
    se[keys.index("mass")] = 0.5
    assert not unfixed(sp, se).any()


def _full_fit(cov: np.ndarray, phi: np.ndarray, effects: list[str]):
    """A full fit (no data behind it) with covariance ``cov`` at ``phi``, the model at 0."""
    from types import SimpleNamespace

    from bench.diagnosis.fit import FitResult

    space = SimpleNamespace(params=[SimpleNamespace(effect=e) for e in effects],
                            neutral=np.zeros(len(phi)))
    return FitResult(space, np.asarray(phi, float), 0.0, 100, 0.0, np.sqrt(np.diag(cov)), cov,
                     True, "", curvature_cov=cov)


def test_a_parameter_another_effect_stands_in_for_is_not_held():
    """A pulley's radius within two standard errors of the model's and its cable's exit
    point, correlated -0.98: holding either costs about the same, so the radius is not
    held (its part would go to the exit point at the error of a fit that knows the radius).
    Not so within one effect, for loosely correlated parameters, or where holding the
    other would cost far more (the data say which moved)."""
    from bench.diagnosis.fit import traded_parameters

    sd = np.array([0.011, 0.0062])

    def cov(rho: float) -> np.ndarray:
        return np.outer(sd, sd) * np.array([[1.0, rho], [rho, 1.0]])

    weak = np.array([True, False])
    assert traded_parameters(_full_fit(cov(-0.98), [-0.014, -0.0145], ["pulley", "exit"]),
                             weak).tolist() == [True, False]
    assert not traded_parameters(_full_fit(cov(-0.98), [-0.014, -0.0145], ["exit", "exit"]),
                                 weak).any()
    assert not traded_parameters(_full_fit(cov(-0.3), [-0.014, -0.0145], ["pulley", "exit"]),
                                 weak).any()
    assert not traded_parameters(_full_fit(cov(-0.98), [-0.014, -0.06], ["pulley", "exit"]),
                                 weak).any()


def test_gains_sharing_a_common_mode_with_the_mass_are_not_stand_ins_for_it():
    """Eight load-cell gains and the platform's mass: the mass is the gains' common mode up to
    the cables' stretch (each gain correlated -1.0 with the mass marginally), yet no single
    gain can stand in for it: the gains are held, the mass kept."""
    from bench.diagnosis.fit import traded_parameters

    rng = np.random.default_rng(3)
    poses, cells = 20, 8
    tau = rng.uniform(500.0, 1500.0, size=(poses, cells))
    rows = []
    for p in range(poses):
        for c in range(cells):  # a tension reading: its cell's gain, and the mass
            r = np.zeros(cells + 1)
            r[c] = tau[p, c]
            r[-1] = tau[p, c]
            rows.append(r)
            s = np.zeros(cells + 1)  # the cable's stretch: the mass alone, weakly
            s[-1] = 1e-3 * tau[p, c]
            rows.append(s)
    J = np.array(rows)
    C = np.linalg.inv(J.T @ J)
    phi = np.zeros(cells + 1)
    phi[-1] = 4.0 * np.sqrt(C[-1, -1])
    full = _full_fit(C, phi, ["load_cell_calibration"] * cells + ["platform_mass"])
    weak = np.array([True] * cells + [False])
    assert not traded_parameters(full, weak).any()


def test_a_held_gain_sharing_a_poorly_known_mode_with_kept_ones_widens_them():
    """Three load cells' gains whose common mode the data fix to 2 % (a light platform, noisy
    cells) and each gain to 0.1 % beside the others: the first, within its marginal error of
    one, is held, and the kept ones keep the common mode's error (it is marked as unfixed
    for :func:`pruning_bias_var`); not so for gains known on their own, nor across effects
    (:func:`traded_parameters` decides those)."""
    from bench.diagnosis.fit import pruning_bias_var, shared_mode

    common, own = 0.02, 0.001
    cov = common ** 2 * np.ones((3, 3)) + own ** 2 * np.eye(3)
    weak = np.array([True, False, False])
    full = _full_fit(cov, [0.001, 0.035, 0.036], ["gain", "gain", "gain"])
    got = shared_mode(full, weak)
    assert got.tolist() == [True, False, False]
    widened = pruning_bias_var(full, weak, np.zeros(3), weak & got)
    assert np.all(np.sqrt(widened[1:]) > 0.9 * common)  # the common mode's error, kept
    assert np.all(pruning_bias_var(full, weak, np.zeros(3))[1:] < own ** 2)  # without: none
    # gains each known on their own (no common mode): nothing shared
    alone = _full_fit(own ** 2 * np.eye(3), [0.001, 0.035, 0.036], ["gain", "gain", "gain"])
    assert not shared_mode(alone, weak).any()
    # the same covariance across two effects: not this rule's
    assert not shared_mode(_full_fit(cov, [0.001, 0.035, 0.036], ["mass", "gain", "gain"]),
                           weak).any()
