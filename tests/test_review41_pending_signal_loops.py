"""A Ctrl-C whose KeyboardInterrupt a gc callback swallowed before ``cdpr dry-run`` or
``cdpr sim`` installed its own signal handler (bench.parallel.hand_over_pending) stops the
run as a Ctrl-C then would: promptly, exit status 130, the recording kept."""

from __future__ import annotations

import json
import os
import signal
import time

import pytest

import bench.dryrun.scenarios
import firmware_sim.rig
from bench.cli import main
from bench.parallel import hand_over_pending, interrupt_on_term
from bench.recording import read_recording


def _lose_a_sigint() -> None:
    """Send SIGINT to this process and swallow what its handler raises, as a gc callback
    does."""
    try:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.5)  # the handler runs here at the latest
    except KeyboardInterrupt:
        pass


@pytest.fixture
def deadline():
    """A test that would hang (the run never stopped) fails after 60 s instead."""
    def expire(signum, frame):
        raise TimeoutError("the run did not stop")

    old = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, 60.0)
    yield
    signal.setitimer(signal.ITIMER_REAL, 0.0)
    signal.signal(signal.SIGALRM, old)


def test_hand_over_gives_the_lost_signal_once():
    got = []
    with interrupt_on_term():
        hand_over_pending(lambda s, f: got.append(s))  # nothing pending: nothing given
        assert got == []
        _lose_a_sigint()
        hand_over_pending(lambda s, f: got.append(s))
        hand_over_pending(lambda s, f: got.append(s))
    assert got == [signal.SIGINT]


def test_dry_run_stops_on_a_sigint_lost_during_its_set_up(tmp_path, capsys, monkeypatch,
                                                          deadline):
    real = bench.dryrun.scenarios.resolve_scenario

    def resolve(name):  # the set-up, under the command line's handler
        _lose_a_sigint()
        return real(name)

    monkeypatch.setattr(bench.dryrun.scenarios, "resolve_scenario", resolve)
    code = main(["dry-run", "paper-centre", "--duration", "30", "--json", "--quiet",
                 "--record", str(tmp_path / "rec")])
    out = json.loads(capsys.readouterr().out)
    assert code == 130 and out["ended"] == "interrupted"
    assert out["simulated_s"] < 5.0  # the quick stop, not the 30 s asked
    rec = read_recording(tmp_path / "rec")
    assert rec.n_samples > 0 and rec.state[-1] == "quick_stop"
    assert "dry run: interrupted" in (tmp_path / "rec" / "meta.toml").read_text()


def test_sim_stops_on_a_sigint_lost_during_its_set_up(capsys, monkeypatch, deadline):
    real = firmware_sim.rig.SimRig

    def rig(*a, **kw):  # the set-up, under the command line's handler
        _lose_a_sigint()
        return real(*a, **kw)

    monkeypatch.setattr(firmware_sim.rig, "SimRig", rig)
    t0 = time.monotonic()
    code = main(["sim", "--json"])
    captured = capsys.readouterr()
    assert code == 130 and time.monotonic() - t0 < 30.0
    assert json.loads(captured.out.splitlines()[0])["cables"]
    assert captured.err.strip().splitlines()[-1] == "cdpr sim: interrupted (SIGINT)"
