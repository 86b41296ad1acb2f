"""``cdpr commission jog --platform``: the platform moved through the controller's model.

A CDPR is jogged in Cartesian space: every winch moves at once so that the platform
moves and every cable stays in tension. The jog

1. needs the winches referenced (``cdpr commission reference``; a homing since then
   refuses it): the pose now is the forward kinematics of the referenced readings;
2. plans a jerk-limited straight line to the target (``--step`` from the pose now, or
   ``--to``) with the trajectory generator of the dry run
   (:class:`controller.trajectory.Trajectory`, :class:`~controller.trajectory.Move`) and
   checks it as the dry run checks its path (:func:`controller.paths.check_trajectory`:
   frame, feasible tensions, winch ranges): an infeasible target is refused before
   anything moves;
3. runs the dry run's controller (:class:`controller.cycle.LengthController`: inverse
   kinematics, tension distribution, cable elasticity) every bus cycle, the drives in
   cyclic synchronous position through the HAL (:func:`hal.interface.hardware_from_args`);
4. watches every cable (:class:`bench.commission.watch.CableGuard` on the HAL's load-cell
   readings): a tension that leaves the window, or is about to, quick-stops every drive
   (they hold in Quick Stop Active), then they are disabled.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bench.commission.common import CommissionError, Ui, confirm, winches_of
from bench.commission.reference import parse_pose, require_reference, state_path
from bench.commission.report import Section
from bench.commission.watch import CableGuard, horizon_s

#: the platform's default jog speed [m/s]
DEFAULT_SPEED_M_S = 0.02
#: cycles after the end of the line to let the drives settle
SETTLE_CYCLES = 25


def current_pose(robot, lengths_m: np.ndarray, guess: np.ndarray) -> np.ndarray:
    """The pose (6,) of referenced cable lengths [m] (forward kinematics of the model)."""
    from controller.forward import forward_rigid

    res = forward_rigid(robot, lengths_m, guess)
    if not res.success or not np.all(np.isfinite(res.pose)):
        raise CommissionError(f"forward kinematics of the referenced lengths failed "
                              f"(residual {res.residual:.3g} m): reference again", 1)
    return res.pose


def target_pose(args: argparse.Namespace, p_now: np.ndarray) -> np.ndarray:
    """``--step`` added to the pose now, or ``--to`` [m, deg] -> (6,) [m, rad]."""
    if (args.step is None) == (args.to is None):
        raise CommissionError("--platform needs exactly one of --step DX,DY,DZ[,DR,DP,DY] "
                              "and --to X,Y,Z[,R,P,Y] (m, deg)", 2)
    if args.step is not None:
        return p_now + parse_pose(args.step, "--step")
    return parse_pose(args.to, "--to")


def plan(robot, w, p_now: np.ndarray, target: np.ndarray, speed: float):
    """The jerk-limited line and its check; CommissionError when infeasible."""
    from controller.paths import check_trajectory
    from controller.trajectory import MotionLimits, Move, Trajectory

    traj = Trajectory([Move(tuple(float(x) for x in target), "jog")], p_now,
                      MotionLimits(max_speed_m_s=speed))
    chk = check_trajectory(robot, traj, w, step_m=0.005)
    if not chk.ok:
        raise CommissionError(f"jog --platform refused before any motion: {chk.reason}", 1)
    return traj, chk


def _cycle(hw, ctrl, pose: np.ndarray, r):
    """One cycle: setpoints for ``pose``, out with the SYNC; the new readings."""
    out = ctrl.step(pose, r.tensions_N, r.tensions_ok)
    if not out.feasible:
        return None, out.reason
    hw.write_lengths(out.lengths)
    return out, ""


def run_platform_jog(args: argparse.Namespace, ui: Ui, section: Section) -> int:
    from controller.cycle import LengthController
    from controller.robot import resolve_robot
    from hal.interface import hardware_from_args

    if args.winch is not None:
        raise CommissionError("--platform moves every winch: give no WINCH", 2)
    if args.modbus is None:
        raise CommissionError("--platform needs the load cells (--modbus): every cable is "
                              "watched while the platform moves", 2)
    w = winches_of(args)
    robot = resolve_robot(args.robot)
    speed = DEFAULT_SPEED_M_S if args.speed is None else args.speed
    if not 0 < speed <= 0.25:
        raise CommissionError(f"--speed {speed:g} m/s: must be in (0, 0.25] for a jog", 2)
    path = state_path(args)
    offsets = require_reference(path, w)  # refused before anything is opened
    section.fact("reference", f"{path}")
    hw = hardware_from_args(args)
    guard = None
    try:
        hw.start()
        r = hw.read()
        from bench.commission.reference import check_readings, read_state

        check_readings(w, r.lengths_m)
        st = read_state(path)
        p_now = current_pose(robot, r.lengths_m + offsets, np.asarray(st["pose"], float))
        target = target_pose(args, p_now)
        step = float(np.linalg.norm(target[:3] - p_now[:3]))
        if step > args.max_step:
            raise CommissionError(f"step {step * 1e3:.1f} mm longer than --max-step "
                                  f"{args.max_step * 1e3:g} mm", 2)
        traj, chk = plan(robot, w, p_now, target, speed)
        section.fact("platform jog", f"{np.round(p_now, 4).tolist()} -> "
                     f"{np.round(target, 4).tolist()} (m, rad), {traj.duration_s:.2f} s at up "
                     f"to {speed:g} m/s; planned tensions {chk.tension_min_n:.1f}.."
                     f"{chk.tension_max_n:.1f} N")
        confirm(args, f"Move the platform from {np.round(p_now[:3], 4).tolist()} to "
                f"{np.round(target[:3], 4).tolist()} m (every winch moves)?", ui)

        def reader():
            rr = hw.read()
            return rr.tensions_N, rr.tensions_ok, time.monotonic() - float(
                np.min(rr.tension_age_s)) if np.isfinite(rr.tension_age_s).any() \
                else time.monotonic()

        decel = float(np.min(w.quick_stop_decel_m_s2))
        guard = CableGuard(args, w.cables, horizon_s(speed * 2.0, decel), reader=reader)
        section.fact("cable watch", f"every cable, window {guard.window}")
        res = _run(hw, robot, r, p_now, traj, guard, ui, LengthController)
    finally:
        try:
            hw.shutdown()
        finally:
            hw.close()
    end_pose = res["end_pose"]
    if res["guard_stop"]:
        ui.say(f"STOPPED by the cable watch: {res['guard_stop']}")
        section.fact("cable watch stop", res["guard_stop"])
    ui.say(f"platform: {np.round(p_now[:3], 4).tolist()} -> {np.round(end_pose[:3], 4).tolist()}"
           f" m (target {np.round(target[:3], 4).tolist()}), ended by {res['ended_by']}")
    section.fact("result", f"end pose {np.round(end_pose, 4).tolist()}, ended by "
                 f"{res['ended_by']}")
    ui.emit({"start_pose": [float(x) for x in p_now], "target_pose": [float(x) for x in target],
             "end_pose": [float(x) for x in end_pose], "duration_s": traj.duration_s,
             "ended_by": res["ended_by"], "guard_stop": res["guard_stop"],
             "cable_watch": guard.summary() if guard else None, "state": "disabled"})
    return 1 if res["guard_stop"] or res["ended_by"] != "target reached" else 0


def _run(hw, robot, r, p_now, traj, guard: CableGuard, ui: Ui, controller_cls) -> dict:
    """The paced loop: one setpoint per bus cycle along ``traj``; quick stop on the guard."""
    tau0 = r.tensions_N if bool(np.all(r.tensions_ok)) else None
    ctrl = controller_cls(robot, p_now, tau0)
    hw.reference(ctrl.reference)  # the readings are d_model(p_now) from here on
    hw.enable()
    period = float(hw.drives.winches.bus.sync_period_s)
    t_next = time.monotonic()
    n_cycles = int(np.ceil(traj.duration_s / period)) + SETTLE_CYCLES
    ended, why, guard_stop = "target reached", "", ""
    tty_line = 0.0
    try:
        for i in range(n_cycles + 1):
            r = hw.read()
            if r.faults:
                ended = why = f"fault: {r.faults[0]}"
                hw.quick_stop()
                break
            stop = guard(r)
            if stop:
                ended, why, guard_stop = f"stopped: {stop}", stop, stop
                hw.quick_stop()
                break
            pose = traj.sample(min(i * period, traj.duration_s)).pose
            out, reason = _cycle(hw, ctrl, pose, r)
            if out is None:
                ended = why = f"infeasible setpoint: {reason}"
                hw.quick_stop()
                break
            if time.monotonic() - tty_line > 0.5:
                ui.progress(f"platform {np.round(pose[:3], 4).tolist()} m  | {guard.line()}")
                tty_line = time.monotonic()
            t_next += period
            delay = t_next - time.monotonic()
            if delay > 0:
                time.sleep(delay)
    except KeyboardInterrupt:  # Ctrl-C: stop on the ramp and hold, then disable
        hw.quick_stop()
        for _ in range(SETTLE_CYCLES):
            hw.write_lengths(None)
            time.sleep(period)
        raise
    for _ in range(SETTLE_CYCLES if why else 0):  # the quick stop's ramp, then holding
        hw.write_lengths(None)
        time.sleep(period)
    r = hw.read()
    return {"ended_by": ended, "guard_stop": guard_stop,
            "end_pose": current_pose(robot, r.lengths_m, p_now)}


__all__ = ["DEFAULT_SPEED_M_S", "current_pose", "plan", "run_platform_jog", "target_pose"]
