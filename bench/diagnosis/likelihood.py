"""The likelihood of tensions that the length errors move: a Jacobian term for the fits.

Without a tracker, a sample's pose is estimated from its encoder lengths and the length
residual keeps the ``r = n - 6`` directions of the cables' internal forces (the null space
of the wrench matrix). There the measured tensions are no independent regressor of the
cables' stretch: an error of the unstretched lengths from visit to visit (repeatability,
hysteresis, creep) cannot move the platform in those directions and becomes stretch, so
the internal forces the load cells read change with it (``dT = -(EA / L) d eps``: a tenth
of a millimetre is tens of newtons on a stiff cable). The residual
``eps = L(p) / (1 + T / EA) - read`` then holds the very error that moved its regressor
``T L / EA``, and least squares takes that share of the error for a stiffer cable (or a
smaller tension: a load cell's gain too high, a mass too low): EA 50 % too stiff at four
times its standard error on a CoGiRo-class recording with 0.6 mm repeatability.

The data's likelihood accounts for it: the tensions given the readings have the density
of the length errors times the Jacobian of the map from the tensions to the errors, whose
internal-force block ``N^T D N`` (``N`` an orthonormal basis of the taut cables' internal
forces, ``D = diag(|d u / d tau_meas|)``: each cable's stretch per newton its load cell
reads, ``L / (EA g)``) depends on the cables' EA and the cells' gains. ``-2 log L`` is
the chi-square minus ``2 sum_samples log det(N^T D N)``; the fits minimise that (as one
extra residual entry: see :class:`StretchLikelihood`), and the chi-square they report
holds the term relative to the recording's model (zero for the model itself).

Only dwell samples carry the term: their length error is the visit-to-visit error of the
unstretched lengths, which moves the tensions. Rows of moves hold errors that do not (the
channels read at slightly different instants, dynamics, what they blend between stops);
with the term on them, the tensions' scatter, smaller than the rows' length noise would
make it, pulled weakly determined EAs soft (a CoGiRo-class continuous recording: per-cable
EAs halved at 14 standard errors). Samples with a tracker pose keep the plain chi-square:
the pose measured fixes six of the errors' directions and the stretch is seen in all ``n``
of them, which makes the bias a small share of the standard error there.
"""

from __future__ import annotations

import numpy as np

from bench.diagnosis.residuals import ResidualModel, _stretch_sensitivity
from controller.kinematics import wrench_matrix
from controller.robot import Robot
from controller.statics import batch_statics, true_tensions

#: the factor by which a hypothesis may scale a cable's stretch per newton against the
#: model's within the fits' bounds (EA down to 1000 N, gains from 0.5): the extra entry is
#: sqrt(K + delta) with K = 2 sum w r log(BOUND), never below zero
BOUND = 1.0e4


class StretchLikelihood:
    """The fit residuals of ``rm`` on samples ``idx`` with the Jacobian term of the module
    docstring appended as one entry (when some samples have an estimated pose and measured
    tensions; otherwise :attr:`n_extra` is 0 and :meth:`residuals` is ``rm.whitened``)."""

    def __init__(self, rm: ResidualModel, idx: np.ndarray) -> None:
        self.rm = rm
        self.idx = np.asarray(idx)
        s = rm.s
        sel = rm.est_pose[self.idx] & rm.has_tau[self.idx] & rm.has_len[self.idx] \
            & (np.asarray(s.kind)[self.idx] == 0)
        self.own = self.idx[sel]
        n = rm.model.n_cables
        self.n_extra = 1 if len(self.own) and n > 6 else 0
        w = np.asarray(s.weight, dtype=float)[self.own]
        self.K = 2.0 * float(np.sum(w)) * (n - 6) * np.log(BOUND) if self.n_extra else 0.0

    def residuals(self, H: Robot) -> np.ndarray:
        """Whitened residuals of ``H`` (the plain ones, then the extra entry)."""
        b = self.rm.blocks(H, self.idx)
        r = self.rm.whiten(b, self.idx)
        if not self.n_extra:
            return r
        delta = self.delta(H, b.poses[self.own])
        return np.append(r, np.sqrt(max(self.K + delta, 0.0)))

    def delta(self, H: Robot, poses: np.ndarray) -> float:
        """``-2 sum_s w_s (log det(N^T D_H N) - log det(N^T D_model N))`` at ``poses`` (the
        samples' estimated poses under ``H``)."""
        rm, s = self.rm, self.rm.s
        ok = np.isfinite(poses).all(axis=1)
        if not ok.any():
            return 0.0
        own = self.own[ok]
        tau_m = s.tau[own]
        taut = tau_m >= rm.slack_threshold
        keep = taut.sum(axis=1) > 6
        if not keep.any():
            return 0.0
        own, tau_m, taut, poses = own[keep], tau_m[keep], taut[keep], poses[ok][keep]
        w = np.asarray(s.weight, dtype=float)[own]
        with np.errstate(all="ignore"):
            ld_h, ld_m = self._logdet(H, rm.model, poses, tau_m, taut)
        good = np.isfinite(ld_h) & np.isfinite(ld_m)
        return -2.0 * float(np.sum(w[good] * (ld_h[good] - ld_m[good])))

    @staticmethod
    def _logdet(H: Robot, model: Robot, poses: np.ndarray, tau_m: np.ndarray,
                taut: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """log det(N^T D N) per sample (M,) of ``H`` and of ``model`` at ``poses``, but for
        a term the two share: ``N`` the internal forces of the taut cables under ``H`` (a
        slack cable's own direction with a unit entry: a constant factor), ``D`` each
        robot's stretch per newton read. As ``log det D + log det(W D^-1 W^T) - log det(W
        W^T)`` (``W`` the taut cables' wrench matrix), whose last term cancels between the
        two: six-by-six determinants, no null space."""
        tau = true_tensions(H, tau_m)
        bs = batch_statics(H, poses, tau)
        W = wrench_matrix(bs.state) * taut[:, None, :]
        out = []
        for R, t in ((H, tau), (model, true_tensions(model, tau_m))):
            d = np.abs(_stretch_sensitivity(R, bs, t)) / np.abs(R.load_cell_gain)
            d = np.where(taut, d, 1.0)
            M = (W / d[:, None, :]) @ np.swapaxes(W, -1, -2)
            sign, ld = np.linalg.slogdet(M)
            out.append(np.where(sign > 0, ld + np.sum(np.log(d), axis=-1), np.nan))
        return out[0], out[1]
