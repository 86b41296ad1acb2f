"""``cdpr commission monitor --format mcap|both`` and ``--live``: the recording opens in the
``mcap`` reader with CRC validation and holds the channels (tensions, lengths, drive
feedback and states, events, raw CAN on ``/can``), reads as its CSV twin, and the live view
serves the same row channels."""

from __future__ import annotations

import json
import threading
import time
import uuid

import can
import numpy as np
import pytest

from bench.cli import main
from bench.mcap import MCAP_NAME, read_can_frames, read_mcap
from bench.recording import read_recording
from controller.winch import load_winches
from firmware_sim.drive_bank import SimulatedWinchBank
from hal.drives_cia402 import DriveState
from tests.test_mcap_recording import open_with_mcap_reader

W = load_winches()
L0 = np.linspace(9.0, 12.5, 8)


@pytest.fixture
def rig():
    """Eight simulated drives on a virtual channel (``rig.can`` its spec)."""
    ch = f"monitor-mcap-{uuid.uuid4().hex}"
    bank = SimulatedWinchBank(can.Bus(interface="virtual", channel=ch), W)
    bank.set_positions_m(L0)
    bank.start()
    bank.can = f"virtual:{ch}"
    yield bank
    bank.close()


def monitor(capsys, *argv: str) -> tuple[int, dict]:
    capsys.readouterr()
    code = main(["commission", "monitor", *argv, "--json", "--no-report"])
    out = capsys.readouterr().out.strip().splitlines()
    return code, json.loads(out[-1]) if out else {}


def test_monitor_format_both_mcap_has_every_channel_and_equals_csv(rig, capsys, tmp_path):
    rec = tmp_path / "rec"
    rig.drive(5).inject_over_current()  # a drive in FAULT (the state channel)
    rig.drive(2).set_silent(True)  # a drive that does not answer: an event
    code, out = monitor(capsys, "--can", rig.can, "--duration", "1.0", "--rate", "10",
                        "--record", str(rec), "--format", "both", "--init-pose", "10,8.56,1")
    assert code == 0 and out["format"] == "both" and out["rows"] == out["refreshes"] >= 3
    counts = open_with_mcap_reader(rec / MCAP_NAME)
    n = out["rows"]
    for topic in ("/cables/lengths", "/cables/tensions", "/drives/feedback", "/drives/state"):
        assert counts[topic] == n, topic
    assert counts["/supervisor/events"] >= 1
    # every SDO request and answer of every refresh, the sent ones too (none lost before
    # the recording opened with the first sample)
    frames = list(read_can_frames(rec / MCAP_NAME))
    ids = [f.arbitration_id for f in frames]
    assert ids.count(0x605) >= 4 * n and ids.count(0x585) >= 4 * n
    assert len(frames) == counts["/can"]
    c = read_mcap(rec / MCAP_NAME)
    r_csv = read_recording(rec)
    assert c.header == (rec / "recording.csv").read_text().splitlines()[0].split(",")
    np.testing.assert_array_equal(c.data[:, c.header.index("drive_state_31")],
                                  r_csv.extra["drive_state_31"])
    assert c.data[0, c.header.index("drive_state_31")] == DriveState.FAULT
    np.testing.assert_allclose(c.data[0, [c.header.index(f"l_meas_{k}") for k in W.cables
                                          if k != "12"]], np.delete(L0, 1), atol=1e-6)
    assert np.isnan(c.data[0, c.header.index("l_meas_12")])  # node 2: not answering
    ev = [e for e in c.events if e["address"] == 2]
    assert ev and ev[0]["kind"] == "sdo_lost" and ev[0]["cable"] == "12"
    assert ev[0]["device"] == "drive" and ev[0]["reaction"] == "event" and ev[0]["active"]
    assert not [e for e in c.events if e["address"] != 2]
    csv_events = (rec / "events.csv").read_text().splitlines()
    assert len(csv_events) == 1 + len(c.events) and ",sdo_lost," in csv_events[1]
    # /can log times on the rows' clock (the first frames near t = 0, not the epoch)
    from mcap.reader import make_reader

    with (rec / MCAP_NAME).open("rb") as f:
        times = [m.log_time * 1e-9 for _, ch, m in make_reader(f).iter_messages(
            topics=["/can"])]
    assert -1.0 <= min(times) and max(times) <= c.data[-1, 0] + 1.0


def test_monitor_format_mcap_alone_and_csv_has_no_can_channel(rig, capsys, tmp_path):
    code, out = monitor(capsys, "--can", rig.can, "--duration", "0.2", "--rate", "10",
                        "--record", str(tmp_path / "m"), "--format", "mcap")
    assert code == 0 and sorted(p.name for p in (tmp_path / "m").iterdir()) == [MCAP_NAME]
    assert read_recording(tmp_path / "m").n_samples == out["rows"]
    code, out = monitor(capsys, "--can", rig.can, "--duration", "0.2", "--rate", "10",
                        "--record", str(tmp_path / "c"))
    assert code == 0 and not (tmp_path / "c" / MCAP_NAME).exists()
    assert read_recording(tmp_path / "c").n_samples == out["rows"]


def test_monitor_live_serves_the_row_channels(rig, capsys, monkeypatch):
    """A client subscribes while the monitor runs (in this thread) and receives the
    monitor's channels: lengths, tensions, drive feedback and states, its raw CAN frames."""
    pytest.importorskip("tornado")
    from bench.mcap import live
    from tests.test_foxglove_live import _client

    servers: list = []
    init = live.LiveWriter.__init__

    def spy(self, *a, **kw):
        init(self, *a, **kw)
        servers.append(self)

    monkeypatch.setattr(live.LiveWriter, "__init__", spy)
    want = {"/cables/lengths", "/cables/tensions", "/drives/feedback", "/drives/state", "/can"}
    result: dict = {}

    def client():
        deadline = time.monotonic() + 10
        while not servers and time.monotonic() < deadline:
            time.sleep(0.01)
        if servers:
            result["advertised"], result["got"] = _client(servers[0].port, want, 5.0)

    t = threading.Thread(target=client, daemon=True)
    t.start()
    code, out = monitor(capsys, "--can", rig.can, "--duration", "1.5", "--rate", "20",
                        "--live", "127.0.0.1:0")
    t.join(10)
    assert code == 0 and out["live"] == "127.0.0.1:0" and out["rows"] == 0
    assert result["advertised"]["/drives/state"] == "cdpr.DriveStates"
    assert result["advertised"]["/can"] == "cdpr.CanFrame"
    assert want <= result["got"], result["got"]
