"""``cdpr commission`` against ``cdpr sim`` in ANOTHER PROCESS (socketcand hub, Modbus/TCP),
and a jog in a third process stopped by its dead-man input, then by SIGINT.

The endpoints come from the simulator's ``--json`` line. Waits are generous deadlines on
lines the commands print; nothing asserts on elapsed time.
"""

from __future__ import annotations

import json
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import canopen
import numpy as np
import pytest
from test_cli_sim import Sim

from bench.cli import main
from bench.recording import read_recording
from controller.winch import load_winches
from firmware_sim.cia402_drive import EDS_PATH
from hal.can_bus import open_bus
from hal.drives_cia402 import DriveState, decode_states
from hal.drives_config import Setting, sdo_write

ROOT = Path(__file__).resolve().parents[1]
W = load_winches()


@pytest.fixture
def sim():
    s = Sim()
    yield s
    s.stop()
    s.close()


def cli(capsys, *argv: str) -> tuple[int, dict]:
    capsys.readouterr()
    code = main(["commission", *argv, "--json"])
    out = capsys.readouterr().out.strip().splitlines()
    return code, json.loads(out[-1])


def _sigint_ignored() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class Jog:
    """``cdpr commission jog`` in its own process; keys fed on stdin by a thread."""

    def __init__(self, *args: str) -> None:
        cmd = [sys.executable, "-m", "bench.cli", "commission", "jog", *args, "--json"]
        # started as a shell's background job would be, SIGINT ignored: the jog must stop
        # on it all the same
        self.proc = subprocess.Popen(cmd, cwd=ROOT, stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     preexec_fn=_sigint_ignored)
        self.lines: queue.Queue[str | None] = queue.Queue()
        self.seen: list[str] = []
        self.pressing = threading.Event()
        self._stop = threading.Event()
        threading.Thread(target=self._read, daemon=True).start()
        threading.Thread(target=self._keys, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stderr:
            self.lines.put(line)
        self.lines.put(None)

    def _keys(self) -> None:
        while not self._stop.is_set():
            if self.pressing.is_set():
                try:
                    self.proc.stdin.write("+")
                    self.proc.stdin.flush()
                except (BrokenPipeError, ValueError, OSError):
                    return
            time.sleep(0.02)  # a terminal's key repeat is ~30 Hz

    def wait_for(self, text: str, deadline_s: float = 30.0) -> str:
        end = time.monotonic() + deadline_s
        while True:
            try:
                line = self.lines.get(timeout=max(0.0, end - time.monotonic()))
            except queue.Empty:
                raise AssertionError(f"no {text!r} from the jog in {deadline_s} s: "
                                     f"{''.join(self.seen)}") from None
            if line is None:
                raise AssertionError(f"jog exited ({self.proc.wait(5)}) before {text!r}: "
                                     f"{''.join(self.seen)}")
            self.seen.append(line)
            if text in line:
                return line

    def close(self) -> None:
        self._stop.set()
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5)
        for f in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            try:
                f.close()
            except OSError:
                pass


def test_commissioning_against_cdpr_sim_in_another_process(sim, capsys, tmp_path):
    ep = sim.info
    can_, modbus = ep["can"], ep["modbus"]
    rep = str(tmp_path / "report.md")

    code, out = cli(capsys, "scan", "--can", can_, "--modbus", modbus, "--report", rep)
    assert code == 0 and [d["status"] for d in out["drives"]] == ["ok"] * 8
    assert [c["status"] for c in out["load_cells"]] == ["ok"] * 8
    assert all(c["tension_n"] > 0 for c in out["load_cells"])  # the platform hangs on them

    # the drives come up with their EDS defaults: check finds it, --apply fixes and stores
    code, out = cli(capsys, "check", "--can", can_, "--report", rep)
    assert code == 1 and all(d["differences"] for d in out["drives"])
    code, out = cli(capsys, "check", "--can", can_, "--apply", "--yes", "--report", rep)
    assert code == 0 and out["applied"] == list(range(1, 9))

    # a wrong parameter written behind the tool's back is found and fixed
    net = canopen.Network(open_bus(can_))
    net.connect()
    try:
        node = canopen.RemoteNode(6, canopen.import_od(str(EDS_PATH), 6))
        net.add_node(node)
        sdo_write(node, Setting(0x605A, 0, 0, "quick stop option code"), "n6")
        code, out = cli(capsys, "check", "--can", can_, "--report", rep)
        assert code == 1
        diffs = {d["node_id"]: d["differences"] for d in out["drives"] if d["differences"]}
        q = int(W.quick_stop_option[5])
        assert diffs == {6: [{"index": "0x605A", "subindex": 0, "name": "quick stop option code",
                              "expected": q, "actual": 0, "expected_text": str(q),
                              "actual_text": "0"}]}
        code, out = cli(capsys, "check", "32", "--can", can_, "--apply", "--yes",
                        "--report", rep)
        assert code == 0 and out["drives"][0]["differences"] == []

        # jog in another process: moves while keys come, halts and disables when they stop
        node3 = canopen.RemoteNode(3, canopen.import_od(str(EDS_PATH), 3))
        net.add_node(node3)

        # while the jog runs it is the only master: its TPDOs (statusword, position) are
        # read passively; an SDO request of ours would be another master's (foreign_master)
        tpdos: queue.Queue[tuple[int, int]] = queue.Queue()
        tpdo_cob = int(node3.object_dictionary[0x1800][1].default) & 0x7FF
        net.subscribe(tpdo_cob, lambda _c, data, _t: tpdos.put(
            (int.from_bytes(data[:2], "little"), int.from_bytes(data[2:6], "little",
                                                                 signed=True))))
        jogging = [False]

        def fresh_tpdo() -> tuple[int, int]:
            while not tpdos.empty():
                tpdos.get_nowait()
            return tpdos.get(timeout=5.0)

        def state3() -> str:
            if jogging[0]:
                sw = fresh_tpdo()[0]
            else:
                sw = int.from_bytes(bytes(node3.sdo.upload(0x6041, 0))[:2], "little")
            return DriveState(int(decode_states([sw])[0])).name

        def length3() -> float:
            if jogging[0]:
                pos = fresh_tpdo()[1]
            else:
                pos = int.from_bytes(bytes(node3.sdo.upload(0x6064, 0))[:4], "little",
                                     signed=True)
            return W.axis(2).counts_to_m(pos)

        l_start = length3()
        # no --modbus: the cables are not watched, allowed only with the platform on its
        # stand (--platform-supported), which also allows the long travel
        jog = Jog("21", "--can", can_, "--yes", "--deadman", "0.4", "--speed", "0.2",
                  "--platform-supported", "--travel", "0.5", "--report", rep)
        try:
            jog.wait_for("Hold +")
            jogging[0] = True
            jog.pressing.set()
            jog.wait_for(" moving ")
            time.sleep(0.3)
            jog.pressing.clear()  # the operator lets go of the key
            jog.wait_for(" halting ")
            jog.wait_for(" idle ")
            assert state3() == "READY_TO_SWITCH_ON"  # disabled, the jog still running
            l_stopped = length3()
            assert l_stopped > l_start + 1e-3
            time.sleep(0.3)
            assert length3() == l_stopped
            jog.pressing.set()  # again, then Ctrl-C while it moves
            jog.wait_for(" moving ")
            end = time.monotonic() + 30
            while length3() <= l_stopped + 1e-3 and time.monotonic() < end:
                time.sleep(0.02)
            jog.proc.send_signal(signal.SIGINT)
            jog.pressing.clear()
            assert jog.proc.wait(30) == 130  # (a jog that ignored it fails here, not hangs)
            jogging[0] = False
            out = json.loads(jog.proc.stdout.read().strip().splitlines()[-1])
        finally:
            jog.close()
        assert out == {"error": "interrupted (SIGINT)", "state": "SWITCH_ON_DISABLED"}
        assert state3() == "SWITCH_ON_DISABLED"
        assert length3() > l_stopped + 1e-3
    finally:
        net.disconnect()

    # referencing: the current position of cable 21 reads 14 m from now on
    wfile = tmp_path / "winches.toml"
    wfile.write_text(Path(W.source).read_text())
    code, out = cli(capsys, "home", "21", "--can", can_, "--winches", str(wfile),
                    "--length", "14.0", "--yes", "--report", rep)
    assert code == 0 and out["length_m"] == pytest.approx(14.0)
    assert load_winches(wfile).axis(2).counts_to_m(out["position_after_counts"]) == \
        pytest.approx(14.0)

    # monitor with a recording, through the new winch file
    rec = tmp_path / "rec"
    code, out = cli(capsys, "monitor", "--can", can_, "--modbus", modbus, "--winches",
                    str(wfile), "--duration", "0.5", "--rate", "10", "--record", str(rec),
                    "--report", rep)
    assert code == 0 and out["rows"] >= 2
    r = read_recording(rec)
    assert r.l_meas[-1, 2] == pytest.approx(14.0, abs=1e-6)
    others = [0, 1, 3, 4, 5, 6, 7]
    np.testing.assert_allclose(r.l_meas[-1, others], np.array(ep["reference_m"])[others],
                               atol=1e-5)
    assert np.all(np.isfinite(r.tau[-1]))
    assert r.meta["notes"].startswith("cdpr commission monitor")

    report = Path(rep).read_text()
    for sub in ("scan", "check", "jog", "home", "monitor"):
        assert f" {sub}\n" in report
    assert "interrupted (Ctrl-C)" in report and "drive left: SWITCH_ON_DISABLED" in report
