"""The form of a step (bench.diagnosis.noise._forms): one rule for a column alone and for
the columns together."""
import numpy as np

from bench.diagnosis import noise


def _pos(m: int, constant: bool = False) -> np.ndarray:
    rng = np.random.default_rng(3)
    pos = rng.normal(size=(m, 3)) * 0.4
    if constant:
        pos[:] = [0.1, 0.2, 0.5]
    return pos


def test_uniform_only_where_few_degrees_of_freedom() -> None:
    feats = noise._pose_features(_pos(30))
    assert feats.shape[1] == 4
    forms = noise._forms(feats, dof0=11.0)  # 11 - 4 < 8
    assert len(forms) == 1 and forms[0].shape == (30, 1)
    assert np.all(forms[0] == 1.0)


def test_pose_form_beside_uniform_where_enough_degrees_of_freedom() -> None:
    feats = noise._pose_features(_pos(30))
    forms = noise._forms(feats, dof0=12.0)  # 12 - 4 >= 8
    assert [f.shape[1] for f in forms] == [1, 4]


def test_one_form_where_no_axis_varies() -> None:
    feats = noise._pose_features(_pos(30, constant=True))
    assert [f.shape[1] for f in noise._forms(feats, dof0=100.0)] == [1]


def test_regressors_zero_before_the_step_and_centred_in_groups() -> None:
    form = noise._forms(noise._pose_features(_pos(8)), dof0=100.0)[-1]
    inv = np.array([0, 0, 0, 0, 1, 1, 1, 1])
    after = np.array([False, False, True, True, False, True, True, True])
    U = noise._step_regressors(form, inv, after)
    assert U.shape == (8, 4)
    for g in (0, 1):
        assert np.allclose(U[inv == g].sum(axis=0), 0.0)
    assert np.allclose(U[0], -0.5 * form[2:4].sum(axis=0) / 2)
