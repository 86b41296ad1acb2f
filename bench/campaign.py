"""Campaigns: recordings in the ``cdpr-recording/1`` format made on the simulated robot.

The controller (:class:`controller.cycle.LengthController`, with the scenario's
model) is initialised at the scenario's init pose, then visits the pose set
several times in shuffled order. The plant (the truth, with the concealed
effects and nuisances, and a per-visit change of the cable lengths) comes to
rest for every commanded set of lengths (quasi-static), and each recorded row
adds tracker, load-cell and encoder noise. The recording holds the model, never
the truth.

Two kinds (the scenario's ``[recording] kind``):

- ``dwell``: the platform is taken to each target and dwells there; rows are
  recorded only while it stands (a campaign of replicate dwells).
- ``continuous``: rows at ``rate_hz`` all the time, along straight lines between
  the targets (position and angles interpolated at ``speed_m_s``), with or without
  dwells at the targets, as a dry run or a real robot's log records them. The
  per-visit change of the cable lengths is drawn at each target and blends in
  along the move towards it.

Column groups can be left out (``tracker``, ``load_cells``, ``state_column``).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from bench.recording import POSE_AXES, write_recording
from controller.cycle import LengthController
from firmware_sim.plant import Plant
from firmware_sim.scenario import Scenario
from firmware_sim.tracker_sim import TrackerView

#: angular speed of continuous moves [rad/s] (orientation changes take at least this long)
ANGULAR_SPEED = 0.1


def campaign_targets(sc: Scenario, poses: np.ndarray | None = None) -> tuple[np.ndarray,
                                                                           np.random.Generator]:
    """The target poses (P, 6) of one round of visits and the campaign's random generator."""
    rng = np.random.default_rng(sc.seed)
    targets = sc.poses.generate(rng) if poses is None else np.asarray(poses, float)
    return targets, rng


def campaign_plant(sc: Scenario, referenced: np.ndarray | None = None,
                   predict: bool = False) -> Plant:
    """The plant of the scenario's campaign. ``referenced`` (n,) [m]: the truth's unstretched
    lengths when the encoders were referenced, where that was before this campaign (one that
    continues another after a change on the robot: the encoders keep their reference);
    default: at this campaign's initialisation (:attr:`Plant.referenced`). ``predict``: the rest
    searches along a move start from the extrapolated rest (:attr:`Plant.predict`)."""
    return Plant(sc.model, sc.truth, sc.init_pose, sc.nuisances(process=True),
                 slip_times=plant_slips(sc), rng=np.random.default_rng(sc.seed + 1),
                 check_every=10 if sc.recording.kind == "continuous" else 1, predict=predict,
                 referenced=referenced)


def plant_slips(sc: Scenario, times: np.ndarray | None = None) -> np.ndarray:
    """The slip times (n,) [s] as the scenario's plant takes them: ``times`` (default the
    scenario's ``slip_times``), none before the initialisation's dwell ends (``init_s``): a
    length offset is a slip after the encoders were referenced."""
    return np.maximum(sc.slip_times if times is None else times, sc.poses.init_s)


def run_campaign(sc: Scenario, out: str | Path | None,
                 progress: Callable[[int, int], None] | None = None,
                 poses: np.ndarray | None = None, sink: Callable[..., None] | None = None,
                 plant: Plant | None = None,
                 first_row: Callable[[float, Plant], None] | None = None) -> Path | None:
    """Simulate the scenario's campaign and write the recording directory ``out``.

    With ``sink``, nothing is written and no measurement noise is drawn: every row's truth is
    handed to ``sink(t, pose_des, l_cmd, l_meas, state, tau_read, label)`` instead (``state``
    the plant's :class:`~firmware_sim.plant.PlantState`, ``tau_read`` what noise-free load
    cells read [N]), for a logger that samples it its own way (:mod:`bench.logger_sim`).
    ``plant``: the campaign's plant when the caller made it (:func:`campaign_plant` of ``sc``
    with its own reference or rest searches); default: ``campaign_plant(sc)``.
    ``first_row(t, plant)`` is called once with
    the time [s] of the first row after the initialisation, before the plant settles for it
    (a campaign continuing another sets its later slips by it: :meth:`Plant.slip_at`)."""
    model, ps, spec = sc.model, sc.poses, sc.recording
    targets, rng = campaign_targets(sc, poses)
    plant = campaign_plant(sc) if plant is None else plant
    measured = plant.measured_tensions(plant.init_tensions)  # [N], before the first settle
    ctl = LengthController(model, sc.init_pose, init_tensions=None)
    rows = _Rows(sc, plant, rng, sink)
    # initialisation: the platform stands at p0, the encoders read the model's lengths
    p0 = sc.init_pose
    l_ref = ctl.step(p0, None).lengths
    state = plant.settle(rows.quantise(l_ref), t=0.0, guess=p0)
    t = rows.dwell(0.0, ps.init_s, p0, l_ref, state, "init")
    total = ps.visits * len(targets)
    done = 0
    prev = p0
    noise_prev = np.zeros(model.n_cables)
    continuous = spec.kind == "continuous"
    for _ in range(ps.visits):
        for i in rng.permutation(len(targets)):
            p_des = targets[i]
            noise_next = plant.visit_noise()
            travel = rows.dt if continuous else _travel_s(prev, p_des, ps.speed_m_s)
            if first_row is not None and done == 0:
                first_row(t + travel, plant)
            if continuous:
                t, state, measured = _move(ctl, plant, prev, p_des, t, rows.dt, ps.speed_m_s,
                                           measured, noise_prev, noise_next, rows.quantise,
                                           rows.row, model.compliant)
                cyc = ctl.step(p_des, measured if model.compliant else None)
            else:
                cyc = ctl.step(p_des, measured if model.compliant else None)
                if not cyc.feasible:
                    raise ValueError(f"campaign pose {np.round(p_des, 3).tolist()} is not "
                                     f"feasible for the model: {cyc.reason}")
                t += travel
                state = plant.settle(rows.quantise(cyc.lengths), t=t, visit_noise=noise_next,
                                     guess=p_des)
                measured = plant.measured_tensions(state.tensions)
            if not continuous or spec.dwell_at_targets:
                t = rows.dwell(t, ps.dwell_s, p_des, cyc.lengths, state, "dwell")
            noise_prev = noise_next
            prev = p_des
            done += 1
            if progress:
                progress(done, total)
    if sink is not None or out is None:
        return None
    return rows.write(out, total, len(targets))


class _Rows:
    """A campaign's rows as the recording's columns: the commanded pose and lengths, the
    encoders (quantised), and the noisy load cells and tracker the scenario's recording
    holds (the tracker's own frame and latency errors applied); or, with ``sink``, each
    row's truth handed over without noise."""

    def __init__(self, sc: Scenario, plant: Plant, rng: np.random.Generator,
                 sink: Callable[..., None] | None) -> None:
        model, spec = sc.model, sc.recording
        self.sc, self.plant, self.rng, self.sink = sc, plant, rng, sink
        self.exit_idx = [model.cable_ids.index(c) for c in sc.poses.exit_points] \
            if spec.tracker else []
        cols = ["t"] + [f"{a}_des" for a in POSE_AXES] \
            + [f"l_cmd_{c}" for c in model.cable_ids] + [f"l_meas_{c}" for c in model.cable_ids]
        if spec.load_cells:
            cols += [f"tau_{c}" for c in model.cable_ids]
        if spec.tracker:
            cols += [f"{a}_meas" for a in POSE_AXES] \
                + [f"a{ax}_meas_{model.cable_ids[k]}" for k in self.exit_idx for ax in "xyz"]
        self.rows: dict[str, list[float]] = {c: [] for c in cols}
        self.states: list[str] = []
        self.rate = spec.rate_hz or sc.poses.rate_hz
        self.dt = 1.0 / self.rate if self.rate > 0 else 1.0  # [s]
        self.view = TrackerView(sc.truth)  # the tracker's own errors (frame, latency), if any

    def quantise(self, lengths: np.ndarray) -> np.ndarray:
        """``lengths`` [m] as the encoders read them (to their resolution)."""
        q = self.sc.noise.encoder_m
        return np.round(lengths / q) * q if q > 0 else lengths

    def row(self, t: float, p_des: np.ndarray, l_cmd: np.ndarray, l_meas: np.ndarray, state,
            label: str) -> None:
        """One row at ``t`` [s] of the plant's ``state`` (noise drawn in this order: pose,
        tensions, exit points)."""
        if self.sink is not None:
            self.sink(t, p_des, l_cmd, l_meas, state,
                      self.plant.measured_tensions(state.tensions), label)
            return
        rows, spec, nz, rng, view = self.rows, self.sc.recording, self.sc.noise, self.rng, \
            self.view
        cable_ids = self.sc.model.cable_ids
        rows["t"].append(t)
        for a, ax in enumerate(POSE_AXES):
            rows[f"{ax}_des"].append(p_des[a])
        for j, c in enumerate(cable_ids):
            rows[f"l_cmd_{c}"].append(l_cmd[j])
            rows[f"l_meas_{c}"].append(l_meas[j])
        if spec.tracker:
            seen = state.pose if view.exact else view.read(t, state.pose)
            meas_pose = seen + np.concatenate([rng.normal(0, nz.tracker_m, 3),
                                               rng.normal(0, nz.tracker_rad, 3)])
            for a, ax in enumerate(POSE_AXES):
                rows[f"{ax}_meas"].append(meas_pose[a])
        if spec.load_cells:
            tau = self.plant.measured_tensions(state.tensions) \
                + rng.normal(0, nz.load_cell_n, len(cable_ids))
            for j, c in enumerate(cable_ids):
                rows[f"tau_{c}"].append(tau[j])
        if spec.tracker:
            for k_ in self.exit_idx:
                a_seen = state.exits[k_] if view.exact else view.points(state.exits[k_])
                a_meas = a_seen + rng.normal(0, nz.exit_m, 3)
                for c_, ax in enumerate("xyz"):
                    rows[f"a{ax}_meas_{cable_ids[k_]}"].append(a_meas[c_])
        self.states.append(label)

    def dwell(self, t0: float, duration: float, p_des: np.ndarray, l_cmd: np.ndarray,
              state, label: str) -> float:
        """Rows at the recording's rate for ``duration`` [s] from ``t0`` standing in
        ``state``; the time after them."""
        count = max(1, int(round(duration * self.rate)))
        l_meas = self.quantise(l_cmd)
        for k in range(count):
            self.row(t0 + k * self.dt, p_des, l_cmd, l_meas, state, label)
        return t0 + count * self.dt

    def write(self, out: str | Path, total: int, n_targets: int) -> Path:
        """The recording directory ``out`` of the rows."""
        sc, spec = self.sc, self.sc.recording
        arrays = {c: np.array(v) for c, v in self.rows.items()}
        what = "continuous recording" if spec.kind == "continuous" else "simulated campaign"
        meta = {"notes": f"{what} ({total} visits of {n_targets} poses)",
                "pose_source": "simulated laser tracker" if spec.tracker else "none",
                "tension_source": "simulated load cells" if spec.load_cells else "none"}
        return write_recording(out, sc.model, sc.init_pose, arrays, meta,
                               states=self.states if spec.state_column else None,
                               robot_header=f"model the controller ran with ({sc.model.name})")


def _travel_s(start: np.ndarray, end: np.ndarray, speed: float) -> float:
    """Time [s] a dwell campaign takes from pose ``start`` to ``end`` (6,) at ``speed`` [m/s]."""
    return float(np.linalg.norm(end[:3] - start[:3])) / max(speed, 1e-6)


def _move(ctl: LengthController, plant: Plant, start: np.ndarray, end: np.ndarray, t: float,
          dt: float, speed: float, measured: np.ndarray, noise_a: np.ndarray,
          noise_b: np.ndarray, quantise, row, compliant: bool):
    """Rows along the straight line from ``start`` to ``end`` (6,) at ``speed`` [m/s]; the
    per-visit length change blends from ``noise_a`` to ``noise_b``. Returns the time, the
    plant state and the tensions the load cells read at the end."""
    d = float(np.linalg.norm(end[:3] - start[:3]))
    a = float(np.abs(end[3:] - start[3:]).max())
    duration = max(d / max(speed, 1e-6), a / ANGULAR_SPEED, dt)
    steps = max(1, int(np.ceil(duration / dt)))
    state = plant.state
    for k in range(1, steps + 1):
        f = k / steps
        p = start + f * (end - start)
        cyc = ctl.step(p, measured if compliant else None)
        if not cyc.feasible:
            raise ValueError(f"campaign path pose {np.round(p, 3).tolist()} is not feasible "
                             f"for the model: {cyc.reason}")
        l_meas = quantise(cyc.lengths)
        t = t + dt
        state = plant.settle(l_meas, t=t, visit_noise=noise_a + f * (noise_b - noise_a))
        measured = plant.measured_tensions(state.tensions)
        row(t, p, cyc.lengths, l_meas, state, "move")
    return t + dt, state, measured
