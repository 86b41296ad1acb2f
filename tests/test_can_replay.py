"""``cdpr replay``: the CAN log of a dry run with a fault, played into the HAL again, gives
the live run's drive events, supervisor reactions and final drive states; the same from
the MCAP ``/can`` channel, a candump ``.log`` and an ``.asc``; a log before the fault gives
none; bad logs are refused naming the file."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import can
import pytest

from bench.can_replay import (
    drive_events_of_recording,
    read_log,
    replay,
    replay_keys,
    supervisor_keys,
)
from bench.cli import main
from bench.mcap import read_mcap
from controller.winch import load_winches

FAULTS = {
    "over_current": '[[fault]]\nat_s = 1.2\ndrive = 3\nkind = "over_current"\n',
    "heartbeat_stop": '[[fault]]\nat_s = 0.8\ndrive = 5\nkind = "heartbeat_stop"\n',
}


@pytest.fixture(scope="module", params=sorted(FAULTS))
def live_run(request, tmp_path_factory):
    """A dry run with a fault, recorded as MCAP with its CAN frames: (dir, JSON result)."""
    d = tmp_path_factory.mktemp(request.param)
    (d / "faults.toml").write_text(FAULTS[request.param], encoding="utf-8")
    rec = d / "rec"
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(["dry-run", "paper-centre", "--duration", "2.5", "--quiet", "--json",
                     "--faults", str(d / "faults.toml"), "--record", str(rec),
                     "--format", "mcap"])
    res = json.loads(out.getvalue())
    assert code == 1 and res["ended"] == "quick_stop", res
    return rec / "recording.mcap", res


def _period(mcap: Path) -> float:
    return 1.0 / tomllib.loads(read_mcap(mcap).meta_text)["rate_hz"]


def _live_events(mcap: Path) -> list[dict]:
    return read_mcap(mcap).events


def _same_final_states(got: list[str], live: list[str]) -> None:
    """The replay's final states equal the live run's (a heartbeat-lost drive: UNKNOWN in
    both, whatever TPDOs it still sends)."""
    assert got == live


def test_replay_of_the_mcap_can_channel_gives_the_live_events(live_run):
    mcap, res = live_run
    live = _live_events(mcap)
    want = drive_events_of_recording(live)
    assert want, live  # the fault made the HAL say something
    period = _period(mcap)
    got = replay(read_log(mcap), load_winches(), period_s=period)
    assert replay_keys(got) == want
    assert supervisor_keys(got.supervisor) == supervisor_keys(live)
    assert any(e[3] == "quick_stop" for e in supervisor_keys(got.supervisor))
    _same_final_states(got.final_states, res["drive_states"])
    if "heartbeat_stop" in str(mcap):  # its TPDOs go on: still UNKNOWN while it is lost
        assert res["drive_states"][4] == "UNKNOWN" and "UNKNOWN" not in (
            res["drive_states"][:4] + res["drive_states"][5:])
    # the same times: the log starts within a cycle of the recording's t = 0
    live_t = [e["t"] for e in live if e["device"] == "drive" and e["reaction"] == "event"]
    for a, b in zip(live_t, [e["t"] for e in got.events], strict=True):
        assert abs(a - b) <= 1.5 * period


@pytest.mark.parametrize("suffix", [".log", ".asc"])
def test_replay_of_a_candump_log_and_an_asc(live_run, tmp_path, capsys, suffix):
    mcap, res = live_run
    path = tmp_path / f"bus{suffix}"
    with can.Logger(str(path)) as log:
        for m in read_log(mcap):
            log.on_message_received(m)
    rate = 1.0 / _period(mcap)
    assert main(["replay", str(path), "--fast", "--json", "--rate", repr(rate)]) == 0
    out = json.loads(capsys.readouterr().out)
    got_keys = [(e["node"], e["kind"], e["code"]) for e in out["events"]]
    assert got_keys == drive_events_of_recording(_live_events(mcap))
    assert supervisor_keys(out["supervisor"]) == supervisor_keys(_live_events(mcap))
    assert out["syncs"] > 100 and out["frames"] > 8 * out["syncs"]
    _same_final_states(out["final_states"], res["drive_states"])


def test_a_log_cut_before_the_fault_gives_no_event(live_run):
    mcap, _ = live_run
    frames = list(read_log(mcap))
    period = _period(mcap)
    t_first = min(e["t"] for e in _live_events(mcap) if e["device"] == "drive")
    syncs = [i for i, m in enumerate(frames) if m.arbitration_id == 0x80 and not m.data]
    cut = frames[:syncs[int(t_first / period) - 20]]  # 20 cycles before the live event
    got = replay(cut, load_winches(), period_s=period)
    assert got.events == [] and got.supervisor == []
    assert got.final_states == ["OPERATION_ENABLED"] * 8


def test_original_timing_takes_the_log_s_time(live_run):
    mcap, _ = live_run
    frames = list(read_log(mcap))
    t0 = frames[0].timestamp
    span = frames[-1].timestamp - t0
    assert span > 0.1, (span, len(frames))
    # the frames up to the first one a window after the start (a loaded host may leave a
    # gap in the log, so a fixed window's last frame could be anywhere in it; on a loaded
    # host the logged frames of the run's ~1 s once spanned less than 0.25 s)
    window = min(0.25, 0.5 * span)
    end = next(i for i, m in enumerate(frames) if m.timestamp - t0 >= window)
    short = frames[: end + 1]
    got = replay(short, load_winches(), fast=False, period_s=_period(mcap))
    assert got.log_s > 0.8 * window and got.wall_s >= 0.95 * got.log_s


def test_bad_logs_are_refused_naming_the_file(tmp_path, capsys):
    bad = tmp_path / "bus.txt"
    bad.write_text("nothing\n")
    assert main(["replay", str(bad), "--json"]) == 2
    assert str(bad) in json.loads(capsys.readouterr().out)["error"]
    assert main(["replay", str(tmp_path / "none.log"), "--json"]) == 2
    assert "no such file" in json.loads(capsys.readouterr().out)["error"]
    assert main(["replay", str(bad), "--rate", "-1", "--json"]) == 2
    assert "--rate" in json.loads(capsys.readouterr().out)["error"]
    empty = tmp_path / "empty.log"
    empty.write_text("")
    assert main(["replay", str(empty), "--json"]) == 2
    assert "no CAN frames" in json.loads(capsys.readouterr().out)["error"]


def test_the_replay_uses_only_public_attributes():
    """bench/can_replay.py reaches nothing private of the HAL (nor of anything else): the
    replay HAL's public entry (hal.drives_replay.ReplayDrives.feed_frame) is enough."""
    import ast

    import bench.can_replay as mod

    tree = ast.parse(Path(mod.__file__).read_text(encoding="utf-8"))
    private = sorted({(n.lineno, n.attr) for n in ast.walk(tree) if isinstance(n, ast.Attribute)
                      and n.attr.startswith("_") and not n.attr.startswith("__")})
    assert private == []
