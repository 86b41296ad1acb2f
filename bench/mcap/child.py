"""The writers of a real-time run in a child process: the MCAP encoding, its zstd
compression and the Foxglove live server run beside the control loop, not in its process.

In one process the loop's thread shares the interpreter (the GIL) with every thread that
encodes: the MCAP writer (about 80 us of JSON and protobuf per row, a JSON message per CAN
frame), the live view's publisher and a second connection to the drives' bus whose
python-can notifier parses every frame (about 6,000 a second at 256 Hz). In real time
each of them now and then holds the interpreter when the loop's cycle is due.
:class:`RecordingProcess` keeps only the queueing in the loop's process: the rows (numpy
arrays), events and meta are handed, in batches every :data:`BATCH_S`, through a socket
pair to ONE child process that builds the writers (the same classes as in lock-step:
:class:`bench.mcap.writer.McapRecordingWriter`, :class:`bench.mcap.live.LiveWriter`) and
calls them; the child opens its own connection to the bus for ``/can`` (a ``virtual`` bus,
which lives in one process, is tapped in the loop's process and its frames handed over
with the rows).

The child ends with its parent: it ignores Ctrl-C (the terminal sends it to the whole
process group: the parent ends the run and closes the recording, which the child then
finishes), finishes the file and exits on SIGTERM or SIGHUP, on the end of the pipe (the
parent exited), and when the parent dies whatever killed it (the kernel's parent-death
signal, SIGTERM, then :func:`bench.parallel.end_with_parent`'s watch). The MCAP file then
has its footer; a child killed outright leaves a file that reads up to its last chunk.
"""

from __future__ import annotations

import os
import pickle
import signal
import socket
import subprocess
import sys
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from bench.mcap.channels import can_fields
from bench.recording import BackgroundWriter

#: the longest a row waits in the loop's process before it is handed to the child [s]
BATCH_S = 0.02
#: how long the child may take to start (imports, the writers opened) [s]
STARTUP_S = 60.0
#: how long the child may take to finish the file when closed [s]
CLOSE_S = 30.0
#: after the parent died, the child's time to finish its file before it exits [s]
GRACE_S = 10.0


class Frame(NamedTuple):
    """A CAN frame handed to the child (the attributes of a ``can.Message`` that
    :func:`bench.mcap.channels.can_fields` reads)."""

    timestamp: float
    arbitration_id: int
    is_extended_id: bool
    dlc: int
    data: bytes


class Factory(NamedTuple):
    """A writer the child builds: ``cls(*args, **kwargs)`` (module-level, picklable)."""

    cls: type
    args: tuple
    kwargs: dict


class Spawned:
    """A child process started ahead (``python -m bench.mcap.child``: a fresh interpreter
    that imports the writers' modules, about a second of CPU: started before the robot, it
    does not compete with the hardware's start-up), waiting for its writers
    (:class:`RecordingProcess`) on :attr:`conn` (a socket pair). :meth:`close` ends it
    (idempotent; a :class:`RecordingProcess` closes the one it took)."""

    def __init__(self) -> None:
        ours, theirs = socket.socketpair()
        env = dict(os.environ)
        root = str(Path(__file__).resolve().parents[2])  # (this source tree first)
        env["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [env.get("PYTHONPATH")])])
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "bench.mcap.child", str(theirs.fileno()),
                 str(os.getpid())], pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL, env=env)  # (the run's --json is its own)
        finally:
            theirs.close()
        self.conn = Connection(ours.detach())

    @property
    def pid(self) -> int:
        return self.proc.pid

    def close(self, timeout_s: float = CLOSE_S) -> None:
        """End the child: told (the end of the pipe), then SIGTERM (it finishes its file),
        then SIGKILL, ``timeout_s`` each."""
        self.conn.close()
        for end in (None, self.proc.terminate, self.proc.kill):
            if self.proc.poll() is not None:
                return
            if end is not None:
                end()
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                pass


class RecordingProcess(BackgroundWriter):
    """The writers ``factories`` (in order; the first one's rows are :attr:`rows`) in a
    child process (``spawned``, or one started now), behind the writer interface
    (:meth:`append`, :meth:`event`, :meth:`can_frame`, :meth:`update_meta`, :meth:`close`,
    :attr:`rows`, :attr:`columns`) of ``columns``. ``can``: a ``--can`` spec the child taps
    for ``/can`` on a connection of its own (None: none; frames given to :meth:`can_frame`
    are handed over). ``name`` names it in errors. Raises what opening a writer raised
    (e.g. the recording's :class:`OSError`). :attr:`host`, :attr:`port`: a live view's
    address (None without)."""

    def __init__(self, factories: list[Factory], columns: list[str], can: str | None = None,
                 name: str = "recording", spawned: Spawned | None = None,
                 startup_s: float = STARTUP_S) -> None:
        self.child = spawned if spawned is not None else Spawned()
        self._f = self.child.conn
        self.path = name  # type: ignore[assignment]  (BackgroundWriter's errors name it)
        self.columns = list(columns)
        self.rows = 0  #: rows appended (the child's count after :meth:`close`)
        try:
            self._f.send((list(factories), can))
            info = self._reply(startup_s, "start")
        except BaseException:
            self.child.close()
            raise
        self.host = next((i["host"] for i in info if i.get("port") is not None), None)
        self.port = next((i["port"] for i in info if i.get("port") is not None), None)
        self._start(BATCH_S, f"to-{name}")

    def _reply(self, timeout_s: float, what: str) -> Any:
        """The child's answer ``("ok", value)``; raises its ``("error", exception)``."""
        if not self._f.poll(timeout_s):
            raise TimeoutError(f"{self.path}: the recording process did not {what} in "
                               f"{timeout_s:g} s")
        try:
            kind, value = self._f.recv()
        except EOFError:
            raise OSError(f"{self.path}: the recording process ended (exit "
                          f"{self.child.proc.poll()}) before it could {what}") from None
        if kind == "error":
            raise value
        return value

    def append(self, values: np.ndarray | list[float], state: str | None = None) -> None:
        """One row (copied): ``values`` in column order, ``state``."""
        row = np.array(values, dtype=float)
        if len(row) != len(self.columns):
            raise ValueError(f"{len(row)} values for {len(self.columns)} columns")
        self._queue_item(("append", (row, state or "")))
        self.rows += 1

    def event(self, t: float, device: str, address: int, cable: str, kind: str, code: int,
              reaction: str, active: bool, text: str) -> None:
        self._queue_item(("event", (float(t), str(device), int(address), str(cable),
                                    str(kind), int(code), str(reaction), bool(active),
                                    str(text))))

    def can_frame(self, msg) -> None:
        """One CAN frame (a ``can.Message``); cheap, any thread (a bus's callback)."""
        self._queue_item(("can", can_fields(msg)), check=False)

    def update_meta(self, **fields: Any) -> None:
        self._queue_item(("meta", fields))

    def _write(self, items: list[tuple]) -> None:
        if items:
            self._f.send(items)

    def _finish(self) -> None:
        self._f.send(None)  # the end: the child closes its writers
        self.rows = self._reply(CLOSE_S, "finish the recording")

    def close(self) -> None:
        """Hand over the rest, let the child finish its writers, end it (idempotent)."""
        try:
            super().close()
        finally:
            self.child.close()


def serve(conn, parent: int) -> None:
    """The child: waits for ``(factories, can)`` (or ``None``, the end of the pipe: ends),
    builds the writers, answers ``("ok", [{"host", "port"}, ...])`` (or ``("error",
    exception)``), then calls them with the parent's batches until ``None`` or the pipe's
    end, closes them and answers ``("ok", rows)`` (see the module docstring)."""
    from bench.parallel import end_with_parent

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _finish_on_signal)
    end_with_parent(parent, signal.SIGTERM, GRACE_S)
    import bench.mcap.live  # noqa: F401  (the imports before the run needs them)
    import bench.mcap.recorders  # noqa: F401

    try:
        job = conn.recv()
    except EOFError:  # the parent ended before the run opened its recording
        return
    if job is None:
        return
    try:
        tee, tap = _open(*job)
    except BaseException as exc:  # noqa: BLE001 - handed to the parent
        _answer(conn, "error", exc)
        return
    _answer(conn, "ok", [{"host": getattr(w, "host", None), "port": getattr(w, "port", None)}
                         for w in tee.recorders])
    error = _serve_calls(conn, tee, tap)
    if error is not None:
        _answer(conn, "error", error)
    else:
        _answer(conn, "ok", tee.rows)


def _serve_calls(conn, tee, tap) -> BaseException | None:
    """The parent's calls to the writers until the end, then the writers closed; the error
    that came up (None: the file is whole)."""
    error: BaseException | None = None
    try:
        _calls(conn, tee)
    except BaseException as exc:  # noqa: BLE001 - a signal, a writer's error
        error = exc
    try:
        if tap is not None:
            tap.close()
    finally:
        try:
            tee.close()
        except BaseException as exc:  # noqa: BLE001
            error = error or exc
    return None if isinstance(error, SystemExit) else error  # (told to stop: whole)


def _open(factories: list[Factory], can: str | None):
    """The writers (a :class:`bench.mcap.recorders.TeeRecorder`) and the bus's tap."""
    from bench.mcap.can_tap import CanTap
    from bench.mcap.recorders import TeeRecorder

    writers: list = []
    try:
        for f in factories:
            writers.append(f.cls(*f.args, **f.kwargs))
        tee = TeeRecorder(*writers)
        return tee, (CanTap(can, tee.can_frame) if can else None)
    except BaseException:
        for w in writers:
            w.close()
        raise


#: the child takes the parent's batches (SIGTERM, SIGHUP stop it); once False they are
#: ignored: the writers close undisturbed (e.g. the parent's death signal after the EOF)
_TAKING = [False]


def _calls(conn, tee) -> None:
    """The parent's batches to the writers until ``None`` or the end of the pipe."""
    _TAKING[0] = True
    try:
        _take(conn, tee)
    finally:
        _TAKING[0] = False


def _take(conn, tee) -> None:
    while True:
        try:
            batch = conn.recv()
        except EOFError:  # the parent exited
            return
        if batch is None:
            return
        for kind, a in batch:
            if kind == "append":
                tee.append(*a)
            elif kind == "can":
                tee.can_frame(Frame(*a))
            elif kind == "event":
                tee.event(*a)
            else:
                tee.update_meta(**a)


def _finish_on_signal(signum, frame) -> None:
    """SIGTERM, SIGHUP (or the parent's death): stop taking batches, finish the file (once
    the writers are closing: nothing)."""
    if _TAKING[0]:
        _TAKING[0] = False
        raise SystemExit(128 + signum)


def _answer(conn, kind: str, value: Any) -> None:
    """Send the parent ``(kind, value)`` if it still listens (an exception that does not
    pickle goes as a RuntimeError with its text)."""
    try:
        try:
            conn.send((kind, value))
        except (pickle.PicklingError, TypeError, AttributeError, ValueError):  # unpicklable
            conn.send((kind, RuntimeError(f"{type(value).__name__}: {value}")))
    except OSError:  # the parent is gone
        if kind == "error":
            print(f"cdpr recording process: {value}", file=sys.stderr)


def main(argv: list[str] | None = None) -> None:
    """``python -m bench.mcap.child FD PARENT``: :func:`serve` on the socket ``FD`` for the
    parent process ``PARENT`` (pid)."""
    fd, parent = (int(a) for a in (argv if argv is not None else sys.argv[1:]))
    serve(Connection(fd), parent)


if __name__ == "__main__":
    main()
