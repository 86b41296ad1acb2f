"""Campaigns: recordings in the ``cdpr-recording/1`` format made on the simulated robot.

The controller (:class:`controller.cycle.LengthController`, with the scenario's
model) is initialised at the scenario's init pose, then visits the pose set
several times in shuffled order. At each visit the winches take the commanded
lengths (encoder quantisation), the plant (the truth, with the concealed
effects and nuisances, and a per-visit change of the cable lengths) comes to
rest, and each sample of the dwell adds tracker, load-cell and encoder noise.
The recording holds the model, never the truth.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from bench.recording import POSE_AXES, write_recording
from controller.cycle import LengthController
from firmware_sim.plant import Nuisances, Plant
from firmware_sim.scenario import Scenario


def run_campaign(sc: Scenario, out: str | Path,
                 progress: Callable[[int, int], None] | None = None,
                 poses: np.ndarray | None = None) -> Path:
    """Simulate the scenario's campaign and write the recording directory ``out``."""
    rng = np.random.default_rng(sc.seed)
    model, n = sc.model, sc.model.n_cables
    nz = sc.noise
    ps = sc.poses
    # a length offset is a slip after initialisation: never before the init dwell ends
    slips = np.maximum(sc.slip_times, ps.init_s)
    plant = Plant(model, sc.truth, sc.init_pose,
                  Nuisances(sc.hysteresis_m, sc.drift_m_per_s, nz.process_m),
                  slip_times=slips, rng=np.random.default_rng(sc.seed + 1))
    tau0_meas = plant.measured_tensions(plant.init_tensions)
    ctl = LengthController(model, sc.init_pose, init_tensions=None)
    targets = ps.generate(rng) if poses is None else np.asarray(poses, float)
    exit_idx = [model.cable_ids.index(c) for c in ps.exit_points]
    rows: dict[str, list[float]] = {"t": []}
    cols = ["t"] + [f"{a}_des" for a in POSE_AXES] + [f"l_cmd_{c}" for c in model.cable_ids] \
        + [f"l_meas_{c}" for c in model.cable_ids] + [f"tau_{c}" for c in model.cable_ids] \
        + [f"{a}_meas" for a in POSE_AXES] \
        + [f"a{ax}_meas_{model.cable_ids[k]}" for k in exit_idx for ax in "xyz"]
    rows = {c: [] for c in cols}
    states: list[str] = []
    dt = 1.0 / ps.rate_hz if ps.rate_hz > 0 else 1.0

    def quantise(lengths: np.ndarray) -> np.ndarray:
        q = nz.encoder_m
        return np.round(lengths / q) * q if q > 0 else lengths

    def dwell(t0: float, duration: float, p_des: np.ndarray, l_cmd: np.ndarray,
              state, label: str) -> float:
        count = max(1, int(round(duration * ps.rate_hz)))
        l_meas = quantise(l_cmd)
        for k in range(count):
            t = t0 + k * dt
            rows["t"].append(t)
            for a, ax in enumerate(POSE_AXES):
                rows[f"{ax}_des"].append(p_des[a])
            meas_pose = state.pose + np.concatenate([rng.normal(0, nz.tracker_m, 3),
                                                     rng.normal(0, nz.tracker_rad, 3)])
            tau = plant.measured_tensions(state.tensions) + rng.normal(0, nz.load_cell_n, n)
            for j, c in enumerate(model.cable_ids):
                rows[f"l_cmd_{c}"].append(l_cmd[j])
                rows[f"l_meas_{c}"].append(l_meas[j])
                rows[f"tau_{c}"].append(tau[j])
            for a, ax in enumerate(POSE_AXES):
                rows[f"{ax}_meas"].append(meas_pose[a])
            for k_ in exit_idx:
                a_meas = state.exits[k_] + rng.normal(0, nz.exit_m, 3)
                for c_, ax in enumerate("xyz"):
                    rows[f"a{ax}_meas_{model.cable_ids[k_]}"].append(a_meas[c_])
            states.append(label)
        return t0 + count * dt

    # initialisation: the platform stands at p0, the encoders read the model's lengths
    p0 = sc.init_pose
    l_ref = ctl.step(p0, None).lengths
    state = plant.settle(quantise(l_ref), t=0.0, guess=p0)
    t = dwell(0.0, ps.init_s, p0, l_ref, state, "init")
    total = ps.visits * len(targets)
    done = 0
    prev = p0
    measured = tau0_meas
    for _ in range(ps.visits):
        order = rng.permutation(len(targets))
        for i in order:
            p_des = targets[i]
            cyc = ctl.step(p_des, measured if model.compliant else None)
            if not cyc.feasible:
                raise ValueError(f"campaign pose {np.round(p_des, 3).tolist()} is not feasible "
                                 f"for the model: {cyc.reason}")
            t += float(np.linalg.norm(p_des[:3] - prev[:3])) / max(ps.speed_m_s, 1e-6)
            state = plant.settle(quantise(cyc.lengths), t=t, visit_noise=plant.visit_noise(),
                                 guess=p_des)
            measured = plant.measured_tensions(state.tensions)
            t = dwell(t, ps.dwell_s, p_des, cyc.lengths, state, "dwell")
            prev = p_des
            done += 1
            if progress:
                progress(done, total)
    arrays = {c: np.array(v) for c, v in rows.items()}
    meta = {"notes": f"simulated campaign ({total} visits of {len(targets)} poses)",
            "pose_source": "simulated laser tracker", "tension_source": "simulated load cells"}
    return write_recording(out, model, sc.init_pose, arrays, meta, states=states,
                           robot_header=f"model the controller ran with ({model.name})")
