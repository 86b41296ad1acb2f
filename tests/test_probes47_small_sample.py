"""Time probes' small-sample reading (probes.cluster_dof, probes.slow_scale): a probe in time
on few error clusters is read with the slow-error scale pooled over the cables' drift
columns, on Student's t of their effective degrees of freedom."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.diagnosis import probes

N_CABLES = 8
SIGMA_M = 1e-4  #: the whitening's length unit [m]


class _Clusters:
    """Stands for a ResidualModel where _probe_results asks it: each entry's error cluster."""

    def __init__(self, cluster: np.ndarray):
        self.cluster = cluster

    def entry_blocks(self, idx=None) -> np.ndarray:
        return self.cluster


def _campaign(rng: np.random.Generator, n_clusters: int, rows: int, slow_sd: float,
              strain: float = 0.0):
    """A recording's linearised probe test: ``n_clusters`` stretches of time of ``rows``
    samples, 8 cables, whitened entries (unit: SIGMA_M) of independent unit errors plus a
    slow error per stretch and cable of ``slow_sd`` the noise model lacks, and a thermal
    expansion of ``strain`` over the recording. The effects: a length offset per cable.
    Returns (stand-in model, linearised fit, probe columns)."""
    n_t = n_clusters * rows
    tau = np.linspace(0.0, 1.0, n_t)
    lengths = rng.uniform(1.0, 3.0, (n_t, N_CABLES))  # [m]
    cluster = np.repeat(np.arange(n_clusters), rows)
    slow = rng.normal(0.0, slow_sd, (n_clusters, N_CABLES))[cluster]
    e = rng.normal(size=(n_t, N_CABLES)) + slow + strain * tau[:, None] * lengths / SIGMA_M
    cols = [("thermal", None, tau[:, None] * lengths)]
    for k in range(N_CABLES):
        x = np.zeros((n_t, N_CABLES))
        x[:, k] = tau
        cols.append(("drift", str(k), x))
    Jp = np.column_stack([x.ravel() / SIGMA_M for _, _, x in cols])
    Jc = np.kron(np.ones((n_t, 1)), np.eye(N_CABLES))  # offsets (whitened per metre / 1e4)
    m = Jc.shape[0]
    lin = probes._Linear(e.ravel(), np.arange(N_CABLES), np.zeros(N_CABLES),
                         np.full(N_CABLES, -np.inf), np.full(N_CABLES, np.inf), Jc, Jp,
                         [np.zeros((m, 0))] * len(cols),
                         np.array([np.max(np.abs(x)) for _, _, x in cols]), math.log(m))
    lin.chi0 = lin.solve(lin.every, None)[0]
    lin.inflation = max(lin.chi0 / (m - N_CABLES), 1.0)
    return _Clusters(np.repeat(cluster, N_CABLES)), lin, cols


def _findings(rm, lin, cols) -> list[str]:
    ok = np.ones(len(cols), dtype=bool)
    out, _ = probes._probe_results(rm, None, lin, cols, ok, SIGMA_M / 100)  # size no bar
    return [f"{r.name}{r.cable or ''}" for r in out if r.finding]


def test_cluster_dof_is_the_satterthwaite_of_the_explicit_matrices():
    """The traces without a G x G matrix equal those of C'C built entry by entry, and a
    coefficient's own sandwich has at most G - 1 degrees of freedom."""
    rng = np.random.default_rng(47)
    m, n_groups = 60, 5
    X = rng.normal(size=(m, 3))
    x = rng.normal(size=m) + np.linspace(0.0, 3.0, m)
    cluster = np.repeat(np.arange(n_groups), m // n_groups)
    U = np.linalg.svd(X, full_matrices=False)[0]
    p = x - U @ (U.T @ x)
    V = np.column_stack([U, p / np.linalg.norm(p)])
    M = np.eye(m) - V @ V.T
    for a in (p / (p @ p), rng.normal(size=m)):
        C = np.column_stack([M @ np.where(cluster == g, a, 0.0) for g in range(n_groups)])
        CC = C.T @ C
        trace, nu = probes.cluster_dof(a, V, cluster, n_groups)
        assert trace == pytest.approx(np.trace(CC), rel=1e-10)
        assert nu == pytest.approx(np.trace(CC) ** 2 / np.trace(CC @ CC), rel=1e-10)
    assert probes.cluster_dof(p / (p @ p), V, cluster, n_groups)[1] <= n_groups - 1 + 1e-9


def test_slow_errors_on_four_clusters_read_no_drift():
    """Four stretches of time whose slow error (0.45 of the unit per stretch and cable, ten
    times the independent errors' share of a 50-sample mean) the noise model lacks: read as
    normal, a drift or thermal probe is a finding on many of 30 such recordings; with the
    slow-error scale pooled over the cables, on none."""
    rng = np.random.default_rng(4701)
    old = new = 0
    for _ in range(30):
        rm, lin, cols = _campaign(rng, 4, 50, 0.45)
        new += bool(_findings(rm, lin, cols))
        z2 = []
        for j in range(len(cols)):  # the normal reading of the cluster-robust z
            _, value, r = lin.solve(lin.every, j)
            z2.append(value ** 2 * float(lin.Jp[:, j] @ lin.Jp[:, j]) / lin.inflation)
        old += max(z2) > probes.PROBE_BIC + lin.log_n
    assert old >= 10, old
    assert new == 0, new


STRAIN = 8e-5  #: over the recording


@pytest.mark.parametrize("n_clusters", [4, 30])
def test_a_real_thermal_expansion_is_found_on_few_clusters_and_many(n_clusters):
    """A thermal expansion whose z^2 is about 1100 on the classical variance (4 stretches),
    beside slow errors of 0.14 of the unit per stretch and cable (twice the independent
    errors' share of a 50-sample mean), is declared on 4 stretches of time (read on
    Student's t of the stretches less one, 3 degrees of freedom, it would need a t of ~1e4:
    never) and on 30."""
    rng = np.random.default_rng(4702)
    found = 0
    for _ in range(10):
        rm, lin, cols = _campaign(rng, n_clusters, 50, 0.14, strain=STRAIN)
        found += "thermal" in _findings(rm, lin, cols)
    assert found >= 9, found
