"""The master dies: how long until every winch drive holds in Quick Stop Active.

:func:`master_loss_trial` runs the eight simulated drives in this process behind a
socketcand hub (:class:`firmware_sim.drive_rig.DriveRig`), a master in another process
(``python -m bench.benchmarks.master_loss master --can SPEC``: the HAL, started, enabled and
paying every cable out at a constant speed), kills the master with SIGKILL, and watches
the drives: when each enters Quick Stop Active, when it stands still, how far it went on
the quick-stop ramp, and that it then holds. The drives stop on their own (consumer
heartbeat 0x1016, RPDO deadline, abort connection option 0x6007, quick stop option 0x605A
= 6, all from the winch parameter file).

Benchmark keys (medians over trials, wall time from SIGKILL): ``master_loss_qsa_sync_s``
and ``master_loss_qsa_wall_s`` until all eight drives are in Quick Stop Active with the
drives on the SYNC clock and on the wall clock; ``master_loss_stopped_*_s`` until all
eight stand still.
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from bench.benchmarks import register

ROOT = Path(__file__).resolve().parents[2]
#: cable speed of the master's motion when it dies [m/s]
SPEED_M_S = 0.2


def _master(can_spec: str, clock: str, rpdo_timeout_s: float | None = None) -> int:
    """The master process: start, enable, pay out at SPEED_M_S until killed (10 s at most).
    ``rpdo_timeout_s``: the drives' RPDO deadline it configures (default the winch file's)."""
    import dataclasses

    from controller.winch import load_winches
    from firmware_sim.cia402_drive import EDS_PATH
    from hal.drives import WinchDrives

    w = load_winches()
    if rpdo_timeout_s is not None:
        w = dataclasses.replace(w, bus=dataclasses.replace(w.bus, rpdo_timeout_s=rpdo_timeout_s))
    hal = WinchDrives.open(can_spec, w, EDS_PATH, clock=clock)
    hal.start()
    hal.enable_and_wait()
    l0 = hal.lengths_m()
    period = w.bus.sync_period_s
    tick = time.monotonic()
    for i in range(1, int(10.0 / period)):
        t = i * period
        ramp = min(t, 0.1)  # reach the speed at 2 m/s^2
        hal.set_lengths(l0 + SPEED_M_S * (ramp**2 / 0.2 + max(t - 0.1, 0.0)))
        hal.step(timeout=1.0)
        if i == int(0.3 / period):
            print("moving", flush=True)
        if clock == "wall":
            tick += period
            time.sleep(max(0.0, tick - time.monotonic()))
    hal.close()
    return 0


def master_loss_trial(clock: str = "sync", timeout_s: float = 30.0,
                      rpdo_timeout_s: float | None = None) -> dict:
    """One trial (see the module docstring); drives on ``clock`` ("sync" or "wall");
    ``rpdo_timeout_s`` the RPDO deadline the master configures (default the winch file's).

    ``starved`` is True when a drive stopped before the kill: a live wall-clock master on a
    busy host missed the RPDO deadline (the drive did right; the trial measured nothing).

    Returns ``qsa_s`` (SIGKILL to all eight in Quick Stop Active), ``stopped_s`` (to all
    standing still), per drive ``qsa_each_s``, ``stop_m`` (distance after the kill),
    ``reasons`` (what each drive saw), ``held`` (no motion over 0.5 s afterwards and still
    in Quick Stop Active), and ``detect_lag_s`` (per drive: from the last master heartbeat
    it heard to its reaction, on its own clock reference; the consumer time plus at most a
    tick when the heartbeat was the cause)."""
    from controller.winch import counts_to_m_rate, load_winches
    from firmware_sim.cia402_drive import State
    from firmware_sim.drive_rig import DriveRig

    w = load_winches()
    rig = DriveRig(initial_lengths_m=10.0, clock=clock).start()
    proc = subprocess.Popen(
        [sys.executable, "-m", "bench.benchmarks.master_loss", "master", "--can",
         rig.endpoint()["can"], "--clock", clock,
         *(() if rpdo_timeout_s is None else ("--rpdo-timeout", str(rpdo_timeout_s)))],
        cwd=ROOT, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True)
    try:
        line: list[str] = []
        reader = threading.Thread(target=lambda: line.append(proc.stdout.readline()),
                                  daemon=True)
        reader.start()
        reader.join(timeout_s)
        if not line or line[0].strip() != "moving":
            proc.kill()
            _, err = proc.communicate(timeout=10)
            raise RuntimeError(f"master did not start moving: {err[-2000:]}")
        drives = rig.bank.drives
        time.sleep(0.1)
        with rig.bank.lock:
            v = counts_to_m_rate(np.array([d.axis.vel for d in drives]), w)
            starved = not all(d.state == State.OPERATION_ENABLED for d in drives)
            p_kill = rig.bank.positions_m()
        t_kill = time.monotonic()
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
        n = len(drives)
        qsa = np.full(n, np.nan)
        stopped = np.full(n, np.nan)
        deadline = t_kill + timeout_s
        while np.isnan(stopped).any() and time.monotonic() < deadline:
            now = time.monotonic()
            with rig.bank.lock:
                for k, d in enumerate(drives):
                    if np.isnan(qsa[k]) and d.state == State.QUICK_STOP_ACTIVE:
                        qsa[k] = now - t_kill
                    if (not np.isnan(qsa[k]) and np.isnan(stopped[k])
                            and abs(d.axis.vel) < 1.0 and d._ramp is None):
                        stopped[k] = now - t_kill
            time.sleep(0.001)
        p_stop = rig.bank.positions_m()
        time.sleep(0.5)
        p_later = rig.bank.positions_m()
        with rig.bank.lock:
            states = [d.state for d in drives]
            losses = [list(d.connection_losses) for d in drives]
        lags = [ls[0][2] if ls else None for ls in losses]
        return {
            "clock": clock,
            "starved": starved,
            "speed_m_s": v.tolist(),
            "qsa_s": float(np.max(qsa)),
            "stopped_s": float(np.max(stopped)),
            "qsa_each_s": qsa.tolist(),
            "stop_m": (p_stop - p_kill).tolist(),
            "held": bool(np.all(np.abs(p_later - p_stop) < 1e-6)
                         and all(s == State.QUICK_STOP_ACTIVE for s in states)),
            "reasons": [ls[0][1] if ls else "" for ls in losses],
            "detect_lag_s": lags,
        }
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        proc.stdout.close()
        proc.stderr.close()
        rig.close()


@register("master loss")
def bench_master_loss(quick: bool) -> dict[str, float]:
    trials = 2 if quick else 5
    out = {}
    for clock in ("sync", "wall"):
        runs = [master_loss_trial(clock) for _ in range(trials)]
        out[f"master_loss_qsa_{clock}_s"] = statistics.median(r["qsa_s"] for r in runs)
        out[f"master_loss_stopped_{clock}_s"] = statistics.median(r["stopped_s"] for r in runs)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.benchmarks.master_loss")
    sub = p.add_subparsers(dest="what", required=True)
    m = sub.add_parser("master", help="run the master (the process to kill)")
    m.add_argument("--can", required=True)
    m.add_argument("--clock", choices=("sync", "wall"), default="sync")
    m.add_argument("--rpdo-timeout", type=float, default=None, metavar="S")
    t = sub.add_parser("trial", help="run trials and print them")
    t.add_argument("--clock", choices=("sync", "wall"), default="sync")
    t.add_argument("-n", type=int, default=1)
    args = p.parse_args(argv)
    if args.what == "master":
        return _master(args.can, args.clock, args.rpdo_timeout)
    for _ in range(args.n):
        r = master_loss_trial(args.clock)
        print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()})
    return 0


if __name__ == "__main__":
    sys.exit(main())
