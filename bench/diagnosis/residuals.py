"""Residuals of a hypothesis about the real robot against dwell-averaged samples.

Inverse residuals, evaluated at the measured poses (cheap, vectorised over
samples, no equilibrium solve), are what the fits minimise:

- ``length`` (n per sample) [m]: unstretched length the hypothesis needs to hold
  the platform at the measured pose with the measured tensions, minus the
  unstretched length it reads behind the encoders by the initialisation
  convention. Attributes the error to cables.
- ``wrench`` (6) [N, N m]: ``W tau + w_g`` at the measured pose, tensions
  through the hypothesis' load-cell calibration. Independent of lengths:
  isolates load cells, mass and exit-point directions.
- ``exit`` (3 per measured exit point) [m]: predicted minus measured exit point.

Forward figures (:meth:`ResidualModel.forward`) solve the equilibrium of each
sample under the hypothesis and compare poses and tensions: the headline.
Without measured tensions, tensions come from the tension distribution at the
measured pose (as the paper did).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.diagnosis.samples import Samples, pooled_std
from controller import cables
from controller.cycle import reference_lengths
from controller.forward import forward_pose
from controller.kinematics import gravity_wrench
from controller.pose import cross
from controller.robot import Robot
from controller.statics import (
    batch_statics,
    init_unstretched,
    true_tensions,
    unstretched_from_readings,
)

#: noise floors [m, N, N m, m] when replicates are missing or suspiciously quiet
FLOORS = {"length": 2e-5, "force": 0.05, "moment": 0.05, "exit": 2e-5}
#: defaults when the recording has no replicate visits
DEFAULTS = {"length": 3e-4, "force": 2.0, "moment": 2.0, "exit": 1e-3}


@dataclass
class Blocks:
    """Raw inverse residuals of all samples: ``length`` (N,n), ``wrench`` (N,6), ``exit``
    (N,n,3); NaN where the data do not allow them. ``ok`` (N,) samples evaluated."""

    length: np.ndarray
    wrench: np.ndarray
    exit: np.ndarray
    ok: np.ndarray
    length_extra_sd: np.ndarray | None = None  # (N,n) load-cell noise carried into lengths


@dataclass
class Forward:
    """Forward figures per sample: ``pose_err`` (N,6) measured minus predicted; ``tension_err``
    (N,n) measured minus predicted load-cell readings; ``exit_err`` (N,n,3); ``ok`` (N,)."""

    pose_err: np.ndarray
    tension_err: np.ndarray
    exit_err: np.ndarray
    ok: np.ndarray


class ResidualModel:
    """Residuals of hypotheses against the samples of one recording.

    ``model`` is the robot the controller ran with (defines the encoder reference
    ``d_model(p0)``); ``tau0`` the load-cell readings at initialisation (None if
    the recording has no tensions); ``slip_times`` (n,) the times from which a
    cable length offset applies (0 = throughout).
    """

    def __init__(self, samples: Samples, model: Robot, init_pose: np.ndarray,
                 tau0: np.ndarray | None, slip_times: np.ndarray | None = None) -> None:
        self.s = samples
        self.model = model
        self.init_pose = np.asarray(init_pose, dtype=float)
        self.tau0 = tau0
        self.reference = reference_lengths(model, self.init_pose)
        n = model.n_cables
        self.slip_times = np.zeros(n) if slip_times is None else np.asarray(slip_times, float)
        s = samples
        self.has_pose = np.isfinite(s.pose_meas).all(axis=1)
        self.has_tau = np.isfinite(s.tau).all(axis=1)
        self.has_len = np.isfinite(s.l_meas).all(axis=1) & self.has_pose
        self.has_exit = np.isfinite(s.exit_meas).all(axis=2) & self.has_pose[:, None]
        self.any_tau = bool(self.has_tau.any())
        self.sigma = dict(DEFAULTS)
        self.sigma_source = "defaults (no replicate visits)"
        self._warm_exits: np.ndarray | None = None  # last deflected exits (warm start)
        # slack cables: measured tension within the load-cell noise of zero (the noise of
        # one row, from the spread within dwells; 0.5 N if the recording cannot tell)
        tau_noise = s.tau_row_sd if s.tau_row_sd else 0.5
        self.slack_threshold = max(1.0, 4.0 * tau_noise)
        self.tau_noise = tau_noise / np.sqrt(np.maximum(s.count, 1))  # per dwell sample [N]

    # ----- inverse residuals --------------------------------------------------------
    def blocks(self, H: Robot) -> Blocks:
        """Inverse residuals of hypothesis ``H`` on every sample."""
        s, n, N = self.s, self.model.n_cables, self.s.n
        length = np.full((N, n), np.nan)
        wrench = np.full((N, 6), np.nan)
        exits_err = np.full((N, n, 3), np.nan)
        ok = np.zeros(N, dtype=bool)
        sel = np.flatnonzero(self.has_pose)
        if not len(sel):
            return Blocks(length, wrench, exits_err, ok)
        poses = s.pose_meas[sel]
        if self.any_tau:
            tau = true_tensions(H, s.tau[sel])
            measured = self.has_tau[sel]
            if not measured.all():
                tau[~measured] = batch_statics(H, poses[~measured]).tensions
            warm = self._warm_exits if self._warm_exits is not None and \
                len(self._warm_exits) == len(sel) else None
            bs = batch_statics(H, poses, tau, exits0=warm)
            if H.compliant:
                self._warm_exits = bs.exits
        else:
            bs = batch_statics(H, poses)
        tau, exits, st, good = bs.tensions, bs.exits, bs.state, bs.feasible
        ok[sel] = good
        # length residual
        try:
            tau0 = true_tensions(H, self.tau0) if self.tau0 is not None else None
            u0, _ = init_unstretched(H, self.init_pose, tau0)
        except ValueError:
            return Blocks(length, wrench, exits_err, ok)
        dl = np.where(s.t[sel, None] >= self.slip_times, H.length_offset, 0.0)
        read = unstretched_from_readings(H, s.l_meas[sel], self.reference, u0, dl)
        lres = bs.unstretched - read
        extra = None
        if H.rho > 0 and self.any_tau:
            # a sagging cable's length hangs on its tension (more so the slacker it is): the
            # load cells' noise carries into its length residual
            dT = 0.5
            l_up = cables.from_tensions(H, st, tau + dT)[1]
            sens = np.abs(l_up - bs.unstretched) / dT  # m/N
            extra = np.full((N, n), 0.0)
            extra[sel] = sens * self.tau_noise[sel][:, None]
        # a slack cable only says it is at least as long as the straight line
        slack = (tau < self.slack_threshold) & self.has_tau[sel][:, None]
        lres = np.where(slack, np.maximum(lres, 0.0), lres)
        lres[~self.has_len[sel]] = np.nan
        length[sel] = lres
        # wrench residual (measured tensions only)
        if self.any_tau:
            f = bs.platform_forces
            wg = gravity_wrench(H.mass, H.com, H.gravity, st.R)
            wr = np.concatenate([f.sum(axis=-2), cross(st.Rb, f).sum(axis=-2)], axis=-1) + wg
            # in load-cell units: a hypothesis must not shrink the sensor noise by its gains
            wr *= float(np.exp(np.mean(np.log(H.load_cell_gain))))
            wr[~self.has_tau[sel]] = np.nan
            wrench[sel] = wr
        # exit points
        if self.has_exit.any():
            e = exits - s.exit_meas[sel]
            e[~self.has_exit[sel]] = np.nan
            exits_err[sel] = e
        return Blocks(length, wrench, exits_err, ok, extra)

    # ----- noise ----------------------------------------------------------------------
    def estimate_noise(self, H: Robot) -> dict[str, float]:
        """Noise of each residual block from the spread over replicate visits (model errors
        repeat at a target pose, noise does not); defaults without replicates."""
        b = self.blocks(H)
        est = {}
        tg = self.s.target
        for name, vals in (("length", b.length), ("force", b.wrench[:, :3]),
                           ("moment", b.wrench[:, 3:]), ("exit", b.exit.reshape(self.s.n, -1))):
            if not np.isfinite(vals).any():
                continue
            sd = pooled_std(vals, tg)
            if sd is None or not np.isfinite(sd).any():
                continue
            est[name] = max(float(np.sqrt(np.nanmean(sd ** 2))), FLOORS[name])
        if self.has_pose.any():
            sd = pooled_std(self.s.pose_meas[:, :3], tg)
            if sd is not None and np.isfinite(sd).all():
                est["pose_m"] = float(np.sqrt(np.sum(sd ** 2)))  # 3-D repeatability
        if est:
            self.sigma.update(est)
            self.sigma_source = "replicate visits"
        return dict(self.sigma)

    # ----- whitened vector --------------------------------------------------------------
    def whitened(self, H: Robot, idx: np.ndarray | None = None) -> np.ndarray:
        """Residuals of ``idx`` samples (all by default), divided by their noise, as one vector
        (NaN entries dropped; their positions depend only on the data)."""
        b = self.blocks(H)
        return self.whiten(b, idx)

    def whiten(self, b: Blocks, idx: np.ndarray | None = None) -> np.ndarray:
        sl = slice(None) if idx is None else idx
        sg = self.sigma
        present = self.has_len[sl][:, None]
        if b.length_extra_sd is None:
            parts = [self._mask(b.length[sl], present) / sg["length"]]
        else:
            sd = np.sqrt(sg["length"] ** 2 + b.length_extra_sd[sl] ** 2)
            parts = [self._mask(b.length[sl] / sd, present)]
        if self.any_tau:
            m = self.has_tau[sl] & self.has_pose[sl]
            parts.append(self._mask(b.wrench[sl][:, :3], m[:, None]) / sg["force"])
            parts.append(self._mask(b.wrench[sl][:, 3:], m[:, None]) / sg["moment"])
        if self.has_exit.any():
            parts.append(self._mask(b.exit[sl], self.has_exit[sl][..., None]) / sg["exit"])
        return np.concatenate([p for p in parts if p.size])

    @staticmethod
    def _mask(values: np.ndarray, present: np.ndarray) -> np.ndarray:
        """Entries where data exist (fixed layout); a failed evaluation counts as a huge
        residual rather than a missing one, so a fit cannot gain by breaking samples."""
        present = np.broadcast_to(present, values.shape)
        v = values[present]
        return np.where(np.isfinite(v), v, 1e6)

    # ----- forward figures -------------------------------------------------------------
    def forward(self, H: Robot, idx: np.ndarray | None = None) -> Forward:
        """Equilibrium of each sample under ``H`` from its encoder readings, vs measurements."""
        s, n = self.s, self.model.n_cables
        N = s.n
        pose_err = np.full((N, 6), np.nan)
        tension_err = np.full((N, n), np.nan)
        exit_err = np.full((N, n, 3), np.nan)
        ok = np.zeros(N, dtype=bool)
        have_l = np.isfinite(s.l_meas).all(axis=1)
        if not have_l.any():
            return Forward(pose_err, tension_err, exit_err, ok)
        try:
            tau0 = true_tensions(H, self.tau0) if self.tau0 is not None else None
            u0, _ = init_unstretched(H, self.init_pose, tau0)
        except ValueError:
            return Forward(pose_err, tension_err, exit_err, ok)
        todo = np.flatnonzero(have_l) if idx is None else np.intersect1d(idx,
                                                                         np.flatnonzero(have_l))
        for i in todo:
            dl = np.where(s.t[i] >= self.slip_times, H.length_offset, 0.0)
            l0 = unstretched_from_readings(H, s.l_meas[i], self.reference, u0, dl)
            guess = s.pose_meas[i] if self.has_pose[i] else s.pose_des[i]
            if not np.isfinite(guess).all():
                guess = self.init_pose
            tau_meas = true_tensions(H, s.tau[i]) if self.has_tau[i] else None
            res = forward_pose(H, l0, guess, tensions=tau_meas)
            if not res.success:
                continue
            ok[i] = True
            if self.has_pose[i]:
                pose_err[i] = s.pose_meas[i] - res.pose
            if self.has_tau[i] and np.all(np.isfinite(res.tensions)) and H.elastic:
                tension_err[i] = s.tau[i] - (H.load_cell_gain * res.tensions
                                             + H.load_cell_offset)
            if self.has_exit[i].any():
                e = s.exit_meas[i] - res.exits
                e[~self.has_exit[i]] = np.nan
                exit_err[i] = e
        return Forward(pose_err, tension_err, exit_err, ok)
