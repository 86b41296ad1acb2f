"""The MCAP recording and the live view of a real-time run in a child process
(bench/mcap/child.py): the file opens in the ``mcap`` reader with every channel and
schema and holds what the in-process writer writes of the same rows; a client receives
the live channels; the child taps a socketcand bus itself; it ends when its parent is
killed (and finishes the file); Ctrl-C to the process group leaves a whole file."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from bench.dryrun.record import open_recorder
from bench.mcap import read_can_frames, read_mcap
from bench.mcap.child import Spawned
from controller.robot import resolve_robot
from tests.test_foxglove_live import _check_can, _client, _fed, _frames
from tests.test_mcap_recording import open_with_mcap_reader

ROOT = Path(__file__).resolve().parents[1]
ROBOT = resolve_robot("rocaspect")
P0 = np.array([10.0, 8.5, 1.0, 0, 0, 0])
STATES = np.array([4, 4, 7, 5, 5, 5, 5, 5])
ROW_TOPICS = {"/pose/desired", "/pose/measured", "/cables/lengths", "/cables/tensions",
              "/drives/state", "/loop", "/tf", "/scene"}


def _row(rec, k: int) -> None:
    n = ROBOT.n_cables
    rec.row(0.01 * k, np.full(6, 0.1 * k), np.full(n, 1.0 + k), np.ones(n), np.full(n, 50.0),
            np.zeros(6), np.ones(n), 0, 0, 0, "move", drive_states=STATES)


def _rows(rec, n: int) -> None:
    for k in range(n):
        _row(rec, k)
        if k % 5 == 0:
            rec.event(0.01 * k, "drive", 3, "21", "emcy", 0x2310, "event", True, f"row {k}")


def test_the_child_writes_what_the_in_process_writer_writes(tmp_path):
    """The same rows and events through the child process and in this process: the two
    files read the same (one encoding), every channel and schema is in the child's file
    (mcap reader, CRCs), the rows counted back from the child."""
    files = {}
    for name, child in (("here", None), ("child", Spawned())):
        rec = open_recorder(tmp_path / name, ROBOT, P0, {"notes": "x"}, fmt="mcap",
                            child=child)
        _rows(rec, 40)
        rec.close()
        assert rec.rows == 40
        files[name] = tmp_path / name / "recording.mcap"
        if child is not None:
            assert child.proc.wait(10) == 0
    counts = open_with_mcap_reader(files["child"])
    assert ROW_TOPICS | {"/supervisor/events", "/supervisor/log", "/can"} <= set(counts)
    assert counts == open_with_mcap_reader(files["here"])
    here, there = read_mcap(files["here"]), read_mcap(files["child"])
    assert not there.truncated and there.states == here.states
    np.testing.assert_array_equal(there.data, here.data)
    assert there.events == here.events
    assert (there.meta_text, there.robot_text) == (here.meta_text, here.robot_text)
    assert _messages(files["child"]) == _messages(files["here"])


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    """(topic, log time, data) of every message, in the file's order."""
    from mcap.reader import make_reader

    with path.open("rb") as f:
        return [(ch.topic, m.log_time, m.data)
                for _, ch, m in make_reader(f).iter_messages(log_time_order=False)]


def test_the_child_serves_the_view_and_records_the_tapped_virtual_bus(tmp_path):
    """``--live`` and ``--format mcap`` in the child, the drives' bus a ``virtual`` one
    (tapped in this process, its frames handed over): a client receives the row channels
    and ``/can``; the file holds at least the frames the client saw."""
    import can

    spec = f"virtual:child-can-{uuid.uuid4().hex}"
    path = tmp_path / "rec"
    rec = open_recorder(path, ROBOT, P0, {}, fmt="mcap", live="127.0.0.1:0", can=spec,
                        child=Spawned())
    bus = can.Bus(interface="virtual", channel=spec.split(":", 1)[1])
    stop = threading.Event()

    def once(k):
        for m in _frames(k):
            bus.send(m)
        _row(rec, k)

    t = threading.Thread(target=_fed, args=(once, stop), daemon=True)
    t.start()
    payloads: dict[str, list[bytes]] = {}
    try:
        advertised, got = _client(rec.port, ROW_TOPICS | {"/can"}, payloads=payloads,
                                  count=3)
    finally:
        stop.set()
        t.join()
        rec.close()
        bus.shutdown()
    assert ROW_TOPICS | {"/can"} <= got, got
    assert advertised["/can"] == "cdpr.CanFrame"
    _check_can(payloads)
    last = json.loads(payloads["/drives/state"][-1])["state"]
    assert [last[c] for c in ROBOT.cable_ids] == STATES.tolist()
    assert len(list(read_can_frames(path / "recording.mcap"))) >= len(payloads["/can"])


def test_the_child_taps_a_socketcand_bus_on_its_own_connection(tmp_path):
    """A socketcand bus (the process rig's hub, a real bus's server) is tapped by the child
    itself: the frames another client sends reach the file's ``/can``."""
    import can

    from firmware_sim.can_hub import CanHub

    with CanHub() as hub:
        host, port = hub.address
        path = tmp_path / "rec"
        rec = open_recorder(path, ROBOT, P0, {}, fmt="mcap", can=f"socketcand:{host}:{port}",
                            child=Spawned())
        assert rec.tap is None  # (the child's)
        deadline = time.monotonic() + 10
        while hub.n_clients < 1 and time.monotonic() < deadline:
            time.sleep(0.01)
        sender = can.Bus(interface="socketcand", host=host, port=port, channel="can0")
        try:
            for k in range(20):
                for m in _frames(k):
                    sender.send(m)
                _row(rec, k)
                time.sleep(0.01)
            time.sleep(0.3)
        finally:
            sender.shutdown()
            rec.close()
    ids = [f.arbitration_id for f in read_can_frames(path / "recording.mcap")]
    assert ids.count(0x183) == 20 and ids.count(0x80) == 20


def test_a_child_that_cannot_open_its_recording_says_why(tmp_path):
    """The recording's directory is a file: the child's OSError comes out here, and the
    child has ended."""
    (tmp_path / "rec").write_text("a file")
    child = Spawned()
    with pytest.raises(OSError):
        open_recorder(tmp_path / "rec", ROBOT, P0, {}, fmt="mcap", child=child)
    assert child.proc.wait(10) is not None


PARENT = textwrap.dedent("""
    import faulthandler, signal, sys, time
    import numpy as np
    from bench.dryrun.record import open_recorder
    from bench.mcap.child import Spawned
    from controller.robot import resolve_robot
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # (where it waits: _where)
    # as a shell's foreground job starts: Ctrl-C raises KeyboardInterrupt. A process
    # inherits an ignored SIGINT and Python then leaves it ignored; a test runner's worker
    # may have it so (a full run's parent once ignored it: no end after Ctrl-C)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    robot = resolve_robot("rocaspect")
    child = Spawned()
    rec = open_recorder(sys.argv[1], robot, np.array([10.0, 8.5, 1.0, 0, 0, 0]), {},
                        fmt="mcap", child=child)
    print(child.pid, flush=True)
    n = robot.n_cables
    k = 0
    try:
        while True:
            rec.row(0.01 * k, np.zeros(6), np.ones(n), np.ones(n), np.ones(n), np.zeros(6),
                    np.ones(n), 0, 0, 0, "move")
            k += 1
            time.sleep(0.002)
    except KeyboardInterrupt:
        rec.close()
        print(rec.rows, flush=True)
""")


def _parent(path: Path) -> tuple[subprocess.Popen, int]:
    """A process recording through a child (``PARENT``), in a session of its own, its
    stderr to the file ``path.err`` (a pipe would also wait for the child);
    (it, the child's pid) once rows are on their way."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with open(path.with_suffix(".err"), "w") as err:
        proc = subprocess.Popen([sys.executable, "-c", PARENT, str(path)], env=env,
                                stdout=subprocess.PIPE, stderr=err, text=True,
                                start_new_session=True)
    assert proc.stdout is not None
    child = int(proc.stdout.readline())
    time.sleep(0.5)
    return proc, child


def _where(proc: subprocess.Popen, child: int, path: Path) -> str:
    """What the recording's parent ``proc`` and its ``child`` (pid) are doing: for each,
    its signal masks (blocked, ignored, caught) and each thread's kernel wait channel; the
    parent's Python stacks (faulthandler on SIGUSR1, ``PARENT``) (a failure's evidence)."""
    lines = []
    for name, pid in (("parent", proc.pid), ("child", child)):
        try:
            status = Path(f"/proc/{pid}/status").read_text().splitlines()
            lines.append(f"{name} {pid}: " + ", ".join(
                ln for ln in status if ln.startswith(("State", "SigBlk", "SigIgn", "SigCgt"))))
            for task in sorted(Path(f"/proc/{pid}/task").iterdir()):
                lines.append(f"  thread {(task / 'comm').read_text().strip()}: "
                             f"{(task / 'wchan').read_text().strip()}")
        except OSError:
            lines.append(f"{name} {pid}: gone")
    lines.append("its stdout: at its end" if proc.stdout.closed else
                 "its stdout held open by: " + ", ".join(_holders(proc.stdout.fileno())))
    if proc.poll() is None:
        os.kill(proc.pid, signal.SIGUSR1)
        time.sleep(1.0)
    lines.append(path.with_suffix(".err").read_text())
    return "\n".join(lines)


def _holders(fd: int) -> list[str]:
    """The processes (pid and command line) with the other end of the pipe ``fd`` open: a
    process forked while the pipe was made (before its write end was closed here) keeps
    ``communicate`` from seeing its end."""
    want = f"pipe:[{os.fstat(fd).st_ino}]"
    found = []
    for proc_dir in Path("/proc").iterdir():
        if not proc_dir.name.isdigit() or int(proc_dir.name) == os.getpid():
            continue
        try:
            if any(os.readlink(f) == want for f in (proc_dir / "fd").iterdir()):
                cmd = (proc_dir / "cmdline").read_bytes().decode(errors="replace")
                found.append(f"{proc_dir.name} {' '.join(cmd.replace(chr(0), ' ').split())[:80]}")
        except OSError:
            continue
    return found


def _gone(pid: int, timeout_s: float) -> bool:
    """The process ``pid`` has exited (or is a zombie: exited, its parent gone) within
    ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            with open(f"/proc/{pid}/stat") as f:
                if f.read().split(")")[-1].split()[0] == "Z":
                    return True
        except FileNotFoundError:
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.05)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc, PR_SET_PDEATHSIG")
def test_the_child_ends_when_its_parent_is_killed(tmp_path):
    """SIGKILL to the parent: the child finishes the file (its footer: whole) and is gone
    within a few seconds."""
    proc, child = _parent(tmp_path / "rec")
    try:
        proc.kill()
        proc.wait()
        assert _gone(child, 5.0), "the recording process outlived its parent"
    finally:
        if not _gone(child, 0):
            os.kill(child, signal.SIGKILL)
    c = read_mcap(tmp_path / "rec" / "recording.mcap")
    assert len(c.data) > 10 and not c.truncated


def test_ctrl_c_to_the_process_group_leaves_a_whole_file(tmp_path):
    """Ctrl-C reaches the parent and the child (one process group): the child ignores it,
    the parent closes the recording, the child writes the rest and the footer."""
    proc, child = _parent(tmp_path / "rec")
    try:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            out, _ = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            out = None
        if out is None:  # (outside the handler: the evidence without the timeout's trace)
            pytest.fail("no end 30 s after Ctrl-C:\n" + _where(proc, child, tmp_path / "rec"))
    finally:
        if proc.poll() is None:
            proc.kill()
    rows = int(out.split()[-1])
    assert _gone(child, 5.0)
    c = read_mcap(tmp_path / "rec" / "recording.mcap")
    assert not c.truncated and len(c.data) == rows > 10


def test_a_real_time_dry_run_records_in_its_child_process(tmp_path, capsys, monkeypatch):
    """``cdpr dry-run --realtime --record --format both --live``: the MCAP recording and
    the view in the child process started by the command (and ended with it), the CSV
    directory here; the file opens in the mcap reader with every channel, its rows are the
    CSV directory's, ``/can`` holds the in-process rig's frames."""
    from bench.cli import main
    from bench.mcap import child as child_mod
    from bench.recording import read_recording

    started: list[Spawned] = []

    class Spy(Spawned):
        def __init__(self) -> None:
            super().__init__()
            started.append(self)

    monkeypatch.setattr(child_mod, "Spawned", Spy)
    rec = tmp_path / "rec"
    assert main(["dry-run", "paper-centre", "--realtime", "--duration", "0.3", "--json",
                 "--quiet", "--record", str(rec), "--format", "both", "--live",
                 "127.0.0.1:0"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["ended"] == "completed"
    assert len(started) == 1 and started[0].proc.poll() == 0
    counts = open_with_mcap_reader(rec / "recording.mcap")
    assert ROW_TOPICS | {"/supervisor/events", "/supervisor/log"} <= set(counts)
    assert counts["/can"] > 0
    c = read_mcap(rec / "recording.mcap")
    assert not c.truncated
    csv = read_recording(rec)
    assert len(c.data) == csv.n_samples
