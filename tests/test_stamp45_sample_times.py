"""The dry run's recording stamps each sensor's sample with the time it was taken.

A short lock-step dry run against the simulated robot (in process): the plant keeps the
states it served (``SimRig.history``: the drums' lengths at a settle, the pose the platform
rests at for them, the load cells' tensions), on the drives' SYNC clock, which is the loop's
clock here. Each tracker fix and each load-cell sample in the recording must sit on the row
of the plant state it measured, and each only once. The old recorder wrote the last fix and
the last tensions on every row at the row's time: 23 ms on average after the plant state
they held (the plant settles at 20 Hz), which `cdpr diagnose` read as a tracker latency.

The recorder itself (:class:`bench.dryrun.record.DryRunRecorder`): rows in time order, a
sample before its cycle row on a row of its own holding the controller's columns, samples
at one time on one row, a sample older than the rows written counted.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.dryrun.loop import ControlLoop, LoopOptions
from bench.dryrun.record import DryRunRecorder
from bench.dryrun.scenarios import max_rate_hz, resolve_scenario, sync_period_us
from bench.dryrun.world import start_world, with_rate
from bench.recording import read_recording
from controller.paths import build_trajectory, load_path
from controller.winch import load_winches
from firmware_sim.scenario import load_scenario

SC = load_scenario(resolve_scenario("paper-centre"))
WINCHES = with_rate(load_winches(), sync_period_us(max_rate_hz(load_winches())) * 1e-6)


def _dry_run(tmp_path: Path, seconds: float):
    """The recording of ``seconds`` of the paper's centre path and the plant's states
    (times on the loop's clock [s], poses (k, 6), measured tensions (k, n) [N])."""
    spec = load_path("paper-centre")
    with start_world(SC, WINCHES) as world:
        read, syncs = world.hw.read, []

        def reading():  # the hardware's reads: their time and that of the lengths' SYNC
            r = read()
            syncs.append((r.t_s, r.lengths_t_s))
            return r

        world.hw.read = reading
        loop = ControlLoop(world.hw, world.tracker, SC.truth,
                           lambda p0: build_trajectory(spec, p0),
                           LoopOptions(max_duration_s=seconds, decimate=5),
                           lambda p0: DryRunRecorder(tmp_path / "rec", SC.truth, p0, {}),
                           tick=world.tick)
        res = loop.run()
        hist = list(world.rig.history)
    assert res.ended == "completed", res.message
    # lock-step: the drives answer each SYNC before the loop reads; its time is the read's
    syncs = np.array(syncs)
    answered = np.isfinite(syncs[:, 1])
    assert answered.mean() > 0.9
    same = syncs[answered, 1] == syncs[answered, 0]  # (not after the drives are stopped)
    assert same.mean() > 0.99 and np.all(syncs[answered, 1] <= syncs[answered, 0])
    t = np.array([h.t_s for h in hist]) - loop._t0  # the rig's time is the drives' clock
    return (read_recording(tmp_path / "rec"), WINCHES.bus.sync_period_s, t,
            np.array([h.pose for h in hist]), np.array([h.measured_N for h in hist]))


def _stamp_errors(t_rows: np.ndarray, samples: np.ndarray, t_plant: np.ndarray,
                  plant: np.ndarray, noise: float) -> tuple[np.ndarray, np.ndarray]:
    """For each sample (rows (m, k) at ``t_rows``) the plant state nearest it in value, where
    no other state is within 10 ``noise`` (the sample's noise per component) of it: the
    time from that state to the row [s] and its index."""
    d = np.linalg.norm(samples[:, None, :] - plant[None, :, :], axis=2)
    k = np.argmin(d, axis=1)
    second = np.partition(d, 1, axis=1)[:, 1]
    clear = second > 10 * noise * np.sqrt(samples.shape[1])
    return (t_rows - t_plant[k])[clear], k[clear]


def test_each_fix_and_tension_sample_is_on_the_row_of_the_plant_state_it_measured(tmp_path):
    rec, period, t_plant, poses, cells = _dry_run(tmp_path, 8.0)
    moving = np.asarray(rec.state) == "move"
    fix = moving & np.isfinite(rec.pose_meas).all(axis=1)
    dt, k = _stamp_errors(rec.t[fix], rec.pose_meas[fix, :3], t_plant, poses[:, :3],
                          SC.noise.tracker_m)
    assert dt.size > 20
    assert np.mean(np.abs(dt) < period / 2) > 0.9, np.round(1e3 * dt, 1)
    assert np.unique(k).size > 0.9 * k.size  # a fix once, not repeated on later rows
    # the load cells are swept as the plant settles (lock-step), their tensions change by
    # about their noise between settles: each sample at a settle's time, of its tensions
    tau = moving & np.isfinite(rec.tau).all(axis=1)
    k = np.searchsorted(t_plant, rec.t[tau] + period / 2) - 1
    assert tau.sum() > 20
    at = np.abs(rec.t[tau] - t_plant[k]) < period / 2
    assert np.mean(at) > 0.9, np.round(1e3 * (rec.t[tau] - t_plant[k]), 1)
    off = np.abs(rec.tau[tau][at] - cells[k[at]]) / SC.noise.load_cell_n
    assert np.mean(off < 4) > 0.99 and np.unique(k).size == k.size
    # the encoders are on every cycle row (their SYNC's time, lock-step)
    assert np.isfinite(rec.l_meas).all(axis=1).sum() >= rec.n_samples - fix.sum() - tau.sum()


def _recorder(tmp_path: Path) -> tuple[DryRunRecorder, int]:
    model = SC.truth
    return DryRunRecorder(tmp_path / "r", model, np.zeros(6), {}), model.n_cables


def _cycle(rec: DryRunRecorder, n: int, t: float, k: int, state: str, **times) -> None:
    """A cycle row at ``t`` [s] whose setpoints, lengths and tensions are ``k`` and whose
    fix is ``k`` (``times``: the samples' own times)."""
    rec.row(t, np.full(6, k), np.full(n, k), np.full(n, 10.0 + k), np.full(n, 100.0 + k),
            np.full(6, k), np.zeros(n), 0, k, 0, state, float(k), **times)


def test_the_recorder_writes_samples_at_their_times_in_time_order(tmp_path):
    rec, n = _recorder(tmp_path)
    _cycle(rec, n, 0.10, 1, "init")
    _cycle(rec, n, 0.20, 2, "move", pose_t=0.15, tensions_t=0.20)
    _cycle(rec, n, 0.30, 3, "move", pose_t=0.20, tensions_t=0.25)  # joins the row at 0.2
    _cycle(rec, n, 1.00, 4, "move")  # writes the rows up to 0.5 s
    _cycle(rec, n, 1.10, 5, "move", pose_t=0.05)  # older than the rows written
    rec.close()
    r = read_recording(tmp_path / "r")
    nan = np.nan
    assert r.t.tolist() == [0.1, 0.15, 0.2, 0.25, 0.3, 0.3, 1.0, 1.1]
    assert list(r.state) == ["init", "init"] + ["move"] * 6
    # a sample's own row holds the controller's columns of the row before it
    np.testing.assert_array_equal(r.pose_meas[:, 0], [1, 2, 3, nan, nan, 5, 4, nan])
    np.testing.assert_array_equal(r.extra["pose_err"], [1, 2, 3, nan, nan, 5, 4, nan])
    np.testing.assert_array_equal(r.l_cmd[:, 0], [1, 1, 2, 2, 3, 3, 4, 5])
    np.testing.assert_array_equal(r.l_meas[:, 0], [11, nan, 12, nan, 13, nan, 14, 15])
    np.testing.assert_array_equal(r.tau[:, 0], [101, nan, 102, 103, nan, nan, 104, 105])
    assert "late_samples = 1" in (tmp_path / "r" / "meta.toml").read_text()
