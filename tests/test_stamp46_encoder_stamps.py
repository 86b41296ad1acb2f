"""The dry run's encoder samples are stamped at the SYNC the drives latched them at.

The simulated drives tell the truth (``SimulatedDrive.on_latch``; ``cdpr sim --latch-log
FILE`` writes it as it comes): per synchronous TPDO, the drive's time
of the SYNC it answers and the position it latched then. Each recorded encoder sample is
matched, per cable, with the latch of the same position (only where no other latch within
0.1 s has that position: a drive standing still latches one value many times), and its
stamp compared with the latch's time on the recording's clock (``t`` + ``clock_origin_s``
of meta.toml: the hardware's clock at t = 0).

- In process, in real time (drives and master on the wall clock, frames handed over by
  threads): the master sends a SYNC before a drive can latch at it, and a TPDO arrives
  after its latch; so a stamp at the SYNC is never after its latch, a stamp at the TPDO's
  arrival (or at the cycle that read it) always is. The median of stamp - latch must be
  <= 0 (the sign, no tolerance: a late TPDO answering an older SYNC may be stamped at the
  SYNC after it, rarely).
- Across processes (``cdpr sim --write-site`` and the dry run on that site, lock-step on the
  SYNC clock, where the drives' clock is the master's SYNC count): every stamp equals its
  latch's time (tests/test_dryrun_site.py, on its first dry run).
- The master's rule (``hal.drives_rx.ReceiveMixin._sync_answered``): a TPDO answers no SYNC
  sent after its frame's time stamp, not after the master's receive thread handled it (in
  process, in real time under load: stamps after their latch 1.3-1.7 % -> 0.7-0.8 %, p99
  of stamp - latch +0.6..+0.8 ms -> -0.6 ms); and, within that bound, the SYNC its drive's
  count of TPDOs gives (:mod:`hal.sync_count`, tests/test_stamp47_sync_count.py).
"""

from __future__ import annotations

import time
import tomllib
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from bench.dryrun.loop import ControlLoop, LoopOptions
from bench.dryrun.record import DryRunRecorder
from bench.dryrun.scenarios import max_rate_hz, resolve_scenario, sync_period_us
from bench.dryrun.world import start_world, with_rate
from bench.recording import read_recording
from controller.paths import build_trajectory, load_path
from controller.winch import WinchSet, counts_to_m, load_winches
from firmware_sim.scenario import load_scenario
from hal.drives_rx import ReceiveMixin
from hal.sync_count import CountAlignment, SyncHistory

SC = load_scenario(resolve_scenario("paper-centre"))
WINCHES = with_rate(load_winches(), sync_period_us(max_rate_hz(load_winches())) * 1e-6)
#: [s] the latches a recorded sample is looked for among (either side of its stamp)
WINDOW_S = 0.1


def stamp_errors(rec_dir: Path, latches: dict[int, np.ndarray], winches: WinchSet
                 ) -> tuple[np.ndarray, int]:
    """Per recorded encoder sample that one latch explains: its stamp less the latch's time
    [s] (on the drives' clock); and the number of samples no latch or several explain.
    ``latches``: node id -> (k, 3) rows (drive time [s], wall time [s], counts)."""
    rec = read_recording(rec_dir)
    origin = tomllib.loads((rec_dir / "meta.toml").read_text())["clock_origin_s"]
    n = len(winches.node_id)
    per_count = np.abs(counts_to_m(np.ones(n), winches) - counts_to_m(np.zeros(n), winches))
    errors, unclear = [], 0
    for j, node in enumerate(winches.node_id):
        lat = latches[int(node)]
        t_l = lat[:, 0]
        l_l = counts_to_m(np.outer(lat[:, 2], np.ones(n)), winches)[:, j]
        ok = np.isfinite(rec.l_meas[:, j])
        t, length = rec.t[ok] + origin, rec.l_meas[ok, j]
        # the encoders' reference (a constant per cable): the most frequent difference
        near = np.clip(np.searchsorted(t_l, t), 0, len(t_l) - 1)
        steps = np.round((length - l_l[near]) / per_count[j])
        vals, counts = np.unique(steps, return_counts=True)
        ref = vals[np.argmax(counts)] * per_count[j]
        for ti, li in zip(t, length, strict=True):
            k = np.flatnonzero(np.abs(t_l - ti) < WINDOW_S)
            k = k[np.abs(l_l[k] + ref - li) < per_count[j] / 2]
            if k.size == 1:
                errors.append(ti - t_l[k[0]])
            else:
                unclear += 1
    return np.array(errors), unclear


def read_latch_log(path: Path) -> dict[int, np.ndarray]:
    """``cdpr sim --latch-log``'s file as :func:`stamp_errors` takes it."""
    a = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return {int(node): a[a[:, 0] == node, 1:] for node in np.unique(a[:, 0])}


def test_in_real_time_each_encoder_sample_is_stamped_at_its_sync_not_its_arrival(tmp_path):
    spec = load_path("paper-centre")
    with start_world(SC, WINCHES, realtime=True) as world:
        drives = world.rig.bank.drives
        kept: dict[int, list] = {d.node_id: [] for d in drives}
        for d in drives:
            d.on_latch = lambda *row, rows=kept[d.node_id]: rows.append(row)
        loop = ControlLoop(world.hw, world.tracker, SC.truth,
                           lambda p0: build_trajectory(spec, p0),
                           LoopOptions(max_duration_s=3.0, decimate=1, realtime=True),
                           lambda p0: DryRunRecorder(tmp_path / "rec", SC.truth, p0, {}))
        res = loop.run()
        latches = {}
        for d in drives:
            with d.lock:
                latches[d.node_id] = np.array(kept[d.node_id], float)
    assert res.cycles > 100, res.message
    err, unclear = stamp_errors(tmp_path / "rec", latches, WINCHES)
    # the drives move on the path: samples are told apart by their position
    assert err.size > 100, (err.size, unclear)
    # the SYNC goes out before a drive latches at it (and the TPDO comes after): at the
    # SYNC, stamp <= latch; at the arrival, stamp > latch for every sample
    assert np.median(err) <= 0.0, np.percentile(err, [1, 50, 99])
    assert np.mean(err <= 1e-6) > 0.5, np.percentile(err, [1, 50, 99])  # 1 us: the file's


def test_a_tpdo_handled_after_the_next_sync_answers_the_sync_before_its_time_stamp():
    """The master takes a TPDO for an answer to no SYNC sent after the frame came (its time
    stamp, on ``time.time()``'s clock), not after the master's receive thread handled it; a
    time stamp outside the SYNCs kept and now (another clock) is not used. (The count that
    also keeps a burst of late answers on their SYNCs: tests/test_stamp47_sync_count.py.)"""
    now = time.time()

    def drives():
        history = SyncHistory(8)
        history.note(now - 0.008, 1.0)
        history.note(now - 0.004, 1.004)
        return SimpleNamespace(_sync_sent=history, _sync_t=1.004, _align=[CountAlignment(8)])

    answered = ReceiveMixin._sync_answered
    assert answered(drives(), 0, now - 0.005) == 1.0  # came before the second SYNC went out
    assert answered(drives(), 0, now - 0.003) == 1.004
    for other_clock in (12.5, now + 60.0, now - 0.009):  # a bus's own clock; too old
        assert answered(drives(), 0, other_clock) == 1.004
    assert answered(SimpleNamespace(_sync_sent=SyncHistory(8), _sync_t=0.5,
                                    _align=[CountAlignment(8)]), 0, now) == 0.5
