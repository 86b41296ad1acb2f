"""Slips during moves (``locate.row_jumps``): a step in one cable's length residual between two
rows is found; what a model error or noise does along a move is not."""

from types import SimpleNamespace

import numpy as np

from bench.diagnosis.locate import row_jumps

IDS = tuple("12345678")


def _stream(R: int = 400, rate: float = 10.0):
    t = np.arange(R) / rate
    return SimpleNamespace(t=t, block=np.ones(R, dtype=int), row=np.arange(R) + 2)


def _noise(R: int, rng, sd: float = 2e-5) -> np.ndarray:
    return rng.normal(0.0, sd, (R, len(IDS)))


def test_a_slip_during_a_ramp_is_found_at_its_row():
    rng = np.random.default_rng(1)
    st = _stream()
    L = _noise(400, rng)
    L[:, 2] += 1e-4 * np.arange(400)  # the model's error grows along the move
    L[250:, 2] += 3e-3  # the slip
    found = row_jumps(st, L, IDS)
    assert [f["cable"] for f in found] == ["3"]
    assert found[0]["row"] == 252 and abs(found[0]["step_m"] - 3e-3) < 3e-4


def test_a_steep_curved_ramp_is_no_slip():
    """A residual that grows by millimetres per row as the platform leaves where the model
    holds (a sagging cable under a straight model) ramps; it does not step."""
    rng = np.random.default_rng(2)
    st = _stream()
    L = _noise(400, rng)
    x = np.arange(400) / 10.0  # [s]
    L[:, 3] += 2e-2 * np.clip(x - 20, 0, None) ** 2  # up to 4 mm more per row
    L[:, 5] -= 3e-2 * np.clip(x - 15, 0, 5)  # 3 mm per row for 5 s, then flat
    assert row_jumps(st, L, IDS) == []


def test_a_noisy_reading_and_a_wild_row_are_no_slip():
    """A slack, sagging cable's reading swings by millimetres with its tension's noise; one
    wild row comes back at the next."""
    rng = np.random.default_rng(3)
    st = _stream()
    L = _noise(400, rng)
    L[200:300, 4] += rng.normal(0.0, 5e-3, 100)
    L[120, 6] += 8e-3
    assert row_jumps(st, L, IDS) == []


def test_a_jump_of_most_cables_at_once_is_the_pose_not_a_slip():
    rng = np.random.default_rng(4)
    st = _stream()
    L = _noise(400, rng)
    L[180:, :6] += 2e-3
    assert row_jumps(st, L, IDS) == []


def test_nothing_before_the_initialisation_ends():
    rng = np.random.default_rng(5)
    st = _stream()
    L = _noise(400, rng)
    L[30:, 1] += 4e-3
    assert row_jumps(st, L, IDS, t_after=5.0) == []
    assert [f["cable"] for f in row_jumps(st, L, IDS)] == ["2"]


def test_one_cable_dominating_a_jump_spread_over_all_is_its_slip():
    """Without tensions the internal forces refitted at each row spread one cable's slip over
    the others: the cable whose jump dominates is the one that slipped."""
    rng = np.random.default_rng(6)
    st = _stream()
    L = _noise(400, rng)
    L[220:] += np.array([0.8, 0.25, 0.35, 0.55, -3.0, 0.6, -0.5, 0.7]) * 1e-3
    found = row_jumps(st, L, IDS)
    assert [f["cable"] for f in found] == ["5"] and found[0]["row"] == 222


def test_a_jump_where_another_cable_goes_slack_is_the_balance_not_a_slip():
    """Without load cells each row's tensions are fitted to the stretch: where the fit moves
    a cable to zero tension (its residual left out, one-sided), the others' residuals change
    with the new balance. The same jump between rows on one balance is a slip."""
    rng = np.random.default_rng(6)
    st = _stream()
    st.tau = np.full((400, len(IDS)), np.nan)  # no load cells: tensions fitted per row
    L = _noise(400, rng)
    L[:, 4] += 3e-2  # a model centimetres off
    L[250:, 4] += 6e-3
    switched = L.copy()
    switched[250:, 0] = np.nan  # cable 1 at zero tension from row 250 on
    assert row_jumps(st, switched, IDS) == []
    found = row_jumps(st, L, IDS)
    assert [f["cable"] for f in found] == ["5"] and found[0]["row"] == 252
    # measured tensions: the slip itself slackened cable 1 (its load cell reads zero)
    st.tau = np.full((400, len(IDS)), 100.0)
    found = row_jumps(st, switched, IDS)
    assert [f["cable"] for f in found] == ["5"] and found[0]["row"] == 252


def _absorbing(R: int, rng) -> np.ndarray:
    """Directions (R, 8, 2) the fitted tensions take up: a slip of cable 3 stretches cables 1
    and 4 to share it (its pattern is far from the unit change of its own reading)."""
    A = np.zeros((R, len(IDS), 2))
    A[:, [0, 2, 3], 0] = [1.0, 1.0, 0.6]
    A[:, [1, 4, 5, 6, 7], 1] = rng.uniform(0.5, 1.0, 5)
    return A * 1e-5


def test_a_slip_shared_by_the_fitted_tensions_is_found_through_its_pattern():
    """Without load cells the tensions refitted at each row take up part of one cable's slip
    and pass it to others (ROCASPECT without tensions: a 3.0 mm slip of cable 21 read as
    1 mm on it and 1.2 mm on cable 11, no jump of its own). Fitted through each cable's
    pattern (the reading's change less what the tensions take up), the slip is cable 3's,
    at its full size; the raw jumps alone find none."""
    rng = np.random.default_rng(11)
    R = 400
    st = _stream(R)
    st.tau = np.full((R, len(IDS)), np.nan)
    A = _absorbing(R, rng)
    P = np.eye(len(IDS)) - A[0] @ np.linalg.pinv(A[0])
    L = _noise(R, rng) @ P.T
    L[250:] += 3e-3 * P[:, 2]
    assert row_jumps(st, L, IDS) == []
    found = row_jumps(st, L, IDS, absorbed=A)
    assert [f["cable"] for f in found] == ["3"] and found[0]["row"] == 252
    assert abs(found[0]["step_m"] - 3e-3) < 2e-4


def test_a_pattern_jump_no_single_cable_accounts_for_is_no_slip():
    """Must find nothing: noise alone through the absorbing directions, and a jump of all
    the cables at once (the pose, a new visit) that no single cable's pattern accounts for."""
    rng = np.random.default_rng(12)
    R = 400
    st = _stream(R)
    st.tau = np.full((R, len(IDS)), np.nan)
    A = _absorbing(R, rng)
    P = np.eye(len(IDS)) - A[0] @ np.linalg.pinv(A[0])
    L = _noise(R, rng) @ P.T
    assert row_jumps(st, L, IDS, absorbed=A) == []
    L[250:] += P @ np.array([2.0, -1.5, 1.0, 2.5, -2.0, 1.8, -2.2, 1.2]) * 1e-3
    assert row_jumps(st, L, IDS, absorbed=A) == []



def _posed(R: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Rows whose pose was estimated (no tracker): the pose takes up six directions of the
    eight cables' length residuals, ``A`` (R, 8, 6); ``P`` (8, 8) projects on the two it
    leaves (``N``), where cables 2 and 4 have nearly parallel patterns, as ROCASPECT's even
    cables do."""
    N = np.array([[1.0, 0.0], [0.7, 0.7], [0.0, 1.0], [0.72, 0.69], [-0.7, 0.7],
                  [0.6, -0.8], [-0.9, -0.2], [0.5, 0.2]]) * rng.uniform(0.8, 1.2, (8, 1))
    N = np.linalg.qr(N)[0]
    P = N @ N.T
    A = np.repeat((np.linalg.svd(np.eye(len(IDS)) - P)[0][:, :6] * 1e-3)[None], R, axis=0)
    return A, P


def test_a_slip_under_an_estimated_pose_needs_its_tension_to_jump():
    """No tracker: each row's pose is fitted to the readings and takes up six of the eight
    directions of a jump. A slip of cable 3 is found, at its size, where its load cell's
    tension jumps with it (the platform moved); the same jump of the readings with the
    tensions running on smoothly is a reading's error (hysteresis, a bump), no slip. Must
    find nothing in noise alone either."""
    rng = np.random.default_rng(21)
    R = 400
    st = _stream(R)
    A, P = _posed(R, rng)
    tau = 500.0 + np.linspace(0.0, 50.0, R)[:, None] + rng.normal(0.0, 1.0, (R, len(IDS)))
    st.tau = tau
    L = _noise(R, rng) @ P.T
    assert row_jumps(st, L, IDS, absorbed=A) == []
    slip = L.copy()
    slip[250:] += 4e-3 * P[:, 2]
    assert row_jumps(st, slip, IDS, absorbed=A) == []  # the tensions ran on smoothly
    st.tau = tau.copy()
    st.tau[250:, 2] -= 120.0
    found = row_jumps(st, slip, IDS, absorbed=A)
    assert [f["cable"] for f in found] == ["3"] and found[0]["row"] == 252
    assert abs(found[0]["step_m"] - 4e-3) < 3e-4


def test_a_jump_one_cable_accounts_for_only_roughly_is_no_slip(monkeypatch):
    """In the two directions an estimated pose leaves, some cable's pattern always lies
    nearer a jump than the others': a jump of several cables at once (cable 3's pattern and
    a fifth of cable 1's) that cable 3 accounts for far better than any other still leaves
    far more than the noise, and is no slip. Without that bound it would be cable 3's."""
    import bench.diagnosis.locate as locate

    rng = np.random.default_rng(22)
    R = 400
    st = _stream(R)
    A, P = _posed(R, rng)
    st.tau = 500.0 + rng.normal(0.0, 1.0, (R, len(IDS)))
    st.tau[250:, [0, 2]] -= 120.0
    L = _noise(R, rng) @ P.T
    L[250:] += 4e-3 * (P[:, 2] + 0.2 * P[:, 0])
    assert row_jumps(st, L, IDS, absorbed=A) == []
    monkeypatch.setattr(locate, "FIT_Z", 1e6)
    assert [f["cable"] for f in row_jumps(st, L, IDS, absorbed=A)] == ["3"]


def test_a_jump_two_cables_account_for_alike_names_both_and_their_own_jumps_first():
    """Cables 2 and 4 have nearly parallel patterns in the directions an estimated pose
    leaves: a 6 mm slip of cable 2 is accounted for by either, each a candidate alike (the
    fit tells whose). Where cable 4 also has a smaller jump of its own later, that is its
    step, and cable 2 is left alone at the first."""
    rng = np.random.default_rng(23)
    R = 400
    st = _stream(R)
    A, P = _posed(R, rng)
    st.tau = 500.0 + rng.normal(0.0, 1.0, (R, len(IDS)))
    st.tau[150:, [1, 3]] -= 120.0  # the platform moved: both tensions jump
    L = _noise(R, rng) @ P.T
    L[150:] += 6e-3 * P[:, 1]
    found = {f["cable"]: f for f in row_jumps(st, L, IDS, absorbed=A)}
    assert set(found) == {"2", "4"}
    assert found["2"]["alike"] == ["4"] and found["4"]["alike"] == ["2"]
    assert found["2"]["row"] == found["4"]["row"] == 152
    assert abs(found["2"]["step_m"] - 6e-3) < 5e-4
    st.tau[300:, 3] -= 60.0
    L[300:] += 3e-3 * P[:, 3]
    found = {f["cable"]: f for f in row_jumps(st, L, IDS, absorbed=A)}
    assert found["4"]["row"] == 302 and "alike" not in found["4"]
    assert found["2"]["row"] == 152 and "alike" not in found["2"]
