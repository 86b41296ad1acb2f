"""Run one plain function over many items, in-process, on a local process pool or on Dask.

:func:`run_each` calls ``fn(item, **kw)`` for every item and yields an :class:`Outcome`
per item **as it completes** (not in submission order). An exception in one call is
caught and reported in its outcome (type and message); it never stops or hides the
other items. A local worker process that dies is reported for the item that killed it
(the items running beside it are run again). ``fn`` must be a module-level function (it
is pickled by reference), and on a Dask cluster every worker must be able to import it
(cdpr-bench installed there).

Backends: ``scheduler`` (a Dask distributed address such as ``tcp://127.0.0.1:8786``)
takes precedence; otherwise ``jobs`` > 1 is a :class:`~concurrent.futures.ProcessPoolExecutor`
of ``jobs`` processes and ``jobs`` == 1 runs in this process, one item after the other.

Local worker processes end with their parent, whatever ends it: :func:`worker_pool`
makes pools whose workers ask the kernel for SIGKILL when their parent dies (Linux
``PR_SET_PDEATHSIG``) and also watch their parent's pid (elsewhere, or if the parent
went before they asked); :func:`ending_workers` terminates them when the parent leaves
a ``with`` block by an exception (Ctrl-C), and :func:`interrupt_on_term` turns SIGTERM
(and SIGHUP) into that exception, so that ``timeout``, CI and schedulers end the
workers too. Workers take SIGTERM and SIGHUP with the default action (a worker told to
stop ends at once, without a traceback) and ignore SIGINT (Ctrl-C reaches the whole
process group: the parent decides); :func:`interruption` gives the exit status and the
one line the parent reports.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from functools import partial
from typing import Any

#: how often a worker checks that its parent is alive [s]
WATCH_S = 0.5


def single_blas_thread() -> bool:
    """Limit the loaded OpenBLAS to one thread in this process (True if it could).

    The physics works on small matrices (6 x 8, 18 x 18): several BLAS threads only add
    overhead there, and beside worker processes (``--jobs``) they fight over the cores
    (the diagnosis ran twice as long on two cores). Only the jobs that want it call
    this (the diagnosis, the evaluation): a real-time rig keeps its own setting. SciPy's own
    OpenBLAS (loaded with ``scipy.linalg``) is loaded first, so that it is limited too."""
    import ctypes
    import ctypes.util

    try:
        import scipy.linalg  # noqa: F401  (loads scipy's OpenBLAS before the limit)
    except ImportError:
        pass

    try:
        with open("/proc/self/maps", encoding="ascii", errors="replace") as f:
            libs = {line.split()[-1] for line in f
                    if "openblas" in line.lower() and ".so" in line}
    except OSError:
        return False
    done = False
    for lib in libs:
        try:
            handle = ctypes.CDLL(lib)
        except OSError:
            continue
        for name in ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
                     "openblas_set_num_threads64_", "openblas_set_num_threads"):
            fn = getattr(handle, name, None)
            if fn is not None:
                fn(1)
                done = True
    return done


def end_with_parent(parent: int, signum: int = signal.SIGKILL, grace_s: float = 0.0) -> None:
    """End this (child) process when its parent ``parent`` (pid) ends, whatever ends it: the
    kernel sends ``signum`` when the parent goes (Linux ``PR_SET_PDEATHSIG``; the parent is
    the thread that started this process), and a thread watches the parent's pid every
    :data:`WATCH_S` (elsewhere, or if the parent went before the request) and exits
    (status 1) ``grace_s`` seconds after the parent is gone (time for a handler of
    ``signum`` to finish its work)."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signum, 0, 0, 0)  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):  # pragma: no cover - platform dependent
            pass
    if os.getppid() != parent:  # the parent is already gone
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(WATCH_S)
            if os.getppid() != parent:
                time.sleep(grace_s)
                os._exit(1)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def _die_with_parent(parent: int) -> None:
    """Worker initializer: end this process when the parent ``parent`` (pid) ends."""
    end_with_parent(parent)
    # Ctrl-C goes to the whole process group: the parent decides, the workers carry on
    # until it ends them (no traceback per worker). SIGTERM (terminate_workers, or sent to
    # the group) ends a worker at once and quietly: a fork inherits the parent's handlers,
    # and interrupt_on_term's would raise Terminated here, a traceback per worker
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for sig in (signal.SIGTERM, getattr(signal, "SIGHUP", None)):
        if sig is not None:
            signal.signal(sig, signal.SIG_DFL)
    single_blas_thread()


def worker_pool(jobs: int, share_cores: bool = False) -> ProcessPoolExecutor:
    """A process pool whose workers end with this process (see the module docstring).

    ``share_cores``: the pool's workers, and this process inside :func:`sharing_cores`,
    count on one shared counter which of them compute (:func:`job_running`), so that
    one of them may hand half of its work to a forked helper on a core the others leave
    idle (:func:`claim_core`; e.g. the one fit still running while the pool's other
    worker waits). The counter is the pool's attribute ``busy``."""
    if not share_cores:
        return ProcessPoolExecutor(max_workers=jobs, initializer=_die_with_parent,
                                   initargs=(os.getpid(),))
    import multiprocessing

    busy = multiprocessing.Value("i", 0)
    pool = ProcessPoolExecutor(max_workers=jobs, initializer=_sharing_worker,
                               initargs=(os.getpid(), busy))
    pool.busy = busy  # type: ignore[attr-defined]
    return pool


#: processes computing now, shared by a core-sharing pool's creator and its workers (a
#: ``multiprocessing.Value``), or a counter of this process alone; None: no sharing here
_BUSY: Any = None
#: this process is a worker of a core-sharing pool (counted while it runs a job)
_WORKER = False


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - platform dependent
        return os.cpu_count() or 1


def _sharing_worker(parent: int, busy: Any) -> None:
    """Worker initializer of a core-sharing pool (:func:`worker_pool`)."""
    global _BUSY, _WORKER
    _die_with_parent(parent)
    _BUSY, _WORKER = busy, True


class _Private:
    """The counter of a process that shares its cores with no pool (``get_lock`` as a
    ``multiprocessing.Value`` has it)."""

    def __init__(self) -> None:
        self.value = 0
        self._lock = threading.Lock()

    def get_lock(self) -> threading.Lock:
        return self._lock


@contextlib.contextmanager
def sharing_cores(pool: Any = None) -> Iterator[None]:
    """Inside, this process (the creator of ``pool``, a core-sharing :func:`worker_pool`;
    without one, alone) may claim idle cores for forked helpers (:func:`claim_core`),
    counting itself as computing: it computes while the pool's workers wait, and waits
    while they compute."""
    global _BUSY
    before = _BUSY
    _BUSY = getattr(pool, "busy", None) or _Private()
    try:
        yield
    finally:
        _BUSY = before


@contextlib.contextmanager
def job_running() -> Iterator[None]:
    """Around a job in a core-sharing pool's worker: counted as computing (nothing
    elsewhere)."""
    if _BUSY is None or not _WORKER:
        yield
        return
    with _BUSY.get_lock():
        _BUSY.value += 1
    try:
        yield
    finally:
        with _BUSY.get_lock():
            _BUSY.value -= 1


def claim_core() -> bool:
    """A core for a forked helper of this process, where the processes computing (the
    pool's running jobs, the helpers, and this process itself) leave one idle: True and
    counted until :func:`release_core`. False outside :func:`sharing_cores` and a
    core-sharing pool's worker, and in a helper forked from either."""
    if _BUSY is None:
        return False
    me = 0 if _WORKER else 1
    with _BUSY.get_lock():
        if _BUSY.value + me < _cores():
            _BUSY.value += 1
            return True
    return False


def release_core() -> None:
    """Give back a core :func:`claim_core` claimed."""
    if _BUSY is not None:
        with _BUSY.get_lock():
            _BUSY.value -= 1


def terminate_workers(pool: ProcessPoolExecutor) -> None:
    """Stop a pool now: cancel what has not started and terminate its worker processes."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)  # shutdown forgets it
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        with contextlib.suppress(Exception):
            p.terminate()
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(timeout=5)
    _join_manager(manager)


def _join_manager(thread: threading.Thread | None, timeout_s: float = 5.0) -> None:
    """Wait (up to ``timeout_s``, s) for a pool's manager thread to end after its workers
    were terminated: it closes the pool's wake-up pipe as it ends, and Python's exit hook
    (``concurrent.futures.process._python_exit``, 3.11) writes to that pipe unlocked, so an
    interpreter leaving while the thread still closes it prints ``OSError: Bad file
    descriptor``. A thread that has ended leaves the pipe marked closed and the hook quiet."""
    if thread is not None and thread.is_alive():
        with contextlib.suppress(Exception):
            thread.join(timeout=timeout_s)


@contextlib.contextmanager
def ending_workers(pool: ProcessPoolExecutor | None):
    """``with ending_workers(pool):`` shuts the pool down normally at the end of the block, and
    terminates its workers at once when the block ends by an exception (Ctrl-C, SIGTERM)."""
    try:
        yield pool
    except BaseException:
        if pool is not None:
            terminate_workers(pool)
        raise
    else:
        if pool is not None:
            pool.shutdown(wait=True)


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP arrived (raised in the main thread by :func:`interrupt_on_term`);
    ``signum`` is the signal's number."""

    def __init__(self, signum: int = signal.SIGTERM) -> None:
        super().__init__(signum)
        self.signum = int(signum)

    def __str__(self) -> str:
        return f"signal {self.signum}"


def interruption(exc: BaseException) -> tuple[int, str]:
    """The exit status and the message of an interruption: ``(130, "interrupted (SIGINT)")``
    for Ctrl-C (KeyboardInterrupt), ``(143, "terminated (SIGTERM)")`` for SIGTERM (128 + the
    signal's number, as a shell reports a process the signal killed)."""
    _PENDING.clear()
    if isinstance(exc, Terminated):
        try:
            name = signal.Signals(exc.signum).name
        except ValueError:
            name = f"signal {exc.signum}"
        return 128 + exc.signum, f"terminated ({name})"
    return 130, "interrupted (SIGINT)"


def signal_exit(signum: int) -> tuple[int, str]:
    """:func:`interruption` for a command that caught signal ``signum`` itself (SIGINT:
    ``(130, "interrupted (SIGINT)")``, SIGTERM: ``(143, "terminated (SIGTERM)")``)."""
    if signum == signal.SIGINT:
        return interruption(KeyboardInterrupt())
    return interruption(Terminated(signum))


#: signals :func:`interrupt_on_term` raised as exceptions and no handler has yet taken
#: (:func:`raise_pending`)
_PENDING: list[int] = []


@contextlib.contextmanager
def interrupt_on_term():
    """Within the block, SIGTERM and SIGHUP raise :class:`Terminated` (a KeyboardInterrupt) in
    the main thread, so that ``finally`` blocks run and worker processes are ended; SIGINT
    raises KeyboardInterrupt as Python's own handler does. Each signal is also remembered
    until :func:`interruption` takes it: an exception raised while a garbage-collector
    callback or a ``__del__`` runs is lost (Python prints it and goes on), and a loop that
    calls :func:`raise_pending` raises it again."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        _PENDING.append(signum)
        raise_pending()

    old = {}
    for sig in (signal.SIGTERM, getattr(signal, "SIGHUP", None), signal.SIGINT):
        if sig is not None:
            old[sig] = signal.signal(sig, handler)
    _PENDING.clear()
    try:
        yield
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)
        _PENDING.clear()


def raise_pending() -> None:
    """Raise again the interruption of a signal whose exception was lost (see
    :func:`interrupt_on_term`); nothing when none is pending. For the loops of long-running
    commands, once per iteration."""
    if _PENDING:
        signum = _PENDING[-1]
        raise KeyboardInterrupt if signum == signal.SIGINT else Terminated(signum)


def hand_over_pending(handler: Callable[[int, Any], None]) -> None:
    """For a command that installs its own SIGINT / SIGTERM handler (one that asks its loop
    to stop instead of raising, as ``cdpr dry-run`` and ``cdpr sim`` do), called once it is
    installed: a signal whose exception was lost before (see :func:`interrupt_on_term`) is
    given to ``handler(signum, None)`` as if it had arrived now, and is no longer pending.
    Nothing when none is pending."""
    if _PENDING:
        signum = _PENDING[-1]
        _PENDING.clear()
        handler(signum, None)


@contextlib.contextmanager
def stopping_on_signals(second_raises: bool = True
                        ) -> Iterator[tuple[threading.Event, list[int]]]:
    """SIGINT and SIGTERM set a stop event instead of raising, for a command whose loop
    stops itself (``cdpr dry-run``, ``cdpr sim``); yields (the event, the signals caught,
    first first). With ``second_raises`` a second signal gives up waiting
    (KeyboardInterrupt, or :class:`Terminated`). A signal pending from before is handed
    over (:func:`hand_over_pending`); the previous handlers are back after. Outside the
    main thread nothing is installed."""
    stop = threading.Event()
    previous = {}
    caught: list[int] = []

    def on_signal(signum, frame) -> None:
        if second_raises and stop.is_set():  # a second Ctrl-C: give up waiting
            raise KeyboardInterrupt if signum == signal.SIGINT else Terminated(signum)
        caught.append(signum)
        stop.set()

    if threading.current_thread() is threading.main_thread():
        for s in (signal.SIGINT, signal.SIGTERM):
            previous[s] = signal.signal(s, on_signal)
        hand_over_pending(on_signal)  # a Ctrl-C a gc callback swallowed before: stop too
    try:
        yield stop, caught
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


class SchedulerError(RuntimeError):
    """The Dask scheduler cannot be reached (or Dask is not installed); names the address."""


@dataclass
class Outcome:
    """The result of ``fn(item)``: ``value``, or ``error`` (``"Type: message"``) if it raised.

    ``elapsed_s`` is the wall time from the start of the run to this completion [s];
    ``trace`` the formatted traceback when it is known.
    """

    item: Any
    value: Any = None
    error: str | None = None
    elapsed_s: float = 0.0
    trace: str | None = None

    @property
    def ok(self) -> bool:
        return self.error is None


def describe_error(exc: BaseException) -> str:
    """``"Type: message"`` of an exception (the type alone if the message is empty)."""
    msg = str(exc).strip()
    name = type(exc).__name__
    if isinstance(exc, BrokenProcessPool):
        msg = f"a worker process died ({msg})" if msg else "a worker process died"
    return f"{name}: {msg}" if msg else name


def _trace(exc: BaseException) -> str:
    return "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))


def run_each(fn: Callable[..., Any], items: Iterable[Any], *, jobs: int = 2,
             scheduler: str | None = None, connect_timeout_s: float = 10.0,
             on_start: Callable[[Any], None] | None = None,
             **kw: Any) -> Iterator[Outcome]:
    """Yield the :class:`Outcome` of ``fn(item, **kw)`` for each item, as they complete.

    Closing the iterator early (or an exception in the consumer, such as
    KeyboardInterrupt) cancels the items not yet started and releases the pool or the
    cluster connection. :class:`SchedulerError` if the Dask scheduler cannot be reached.
    ``on_start(item)`` is called in the consumer's thread when an item starts in this
    process or is handed to a local worker (again if it runs again after a worker died);
    not on Dask, whose scheduler decides when an item starts.
    """
    items = list(items)
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
    if scheduler:
        return _run_dask(fn, items, scheduler, connect_timeout_s, kw)
    if jobs == 1:
        return _run_serial(fn, items, kw, on_start)
    return _run_pool(fn, items, jobs, kw, on_start)


def _run_serial(fn, items, kw, on_start=None) -> Iterator[Outcome]:
    t0 = time.perf_counter()
    for item in items:
        if on_start is not None:
            on_start(item)
        try:
            value = fn(item, **kw)
        except Exception as e:  # noqa: BLE001 - reported in the outcome
            yield Outcome(item, error=describe_error(e), elapsed_s=time.perf_counter() - t0,
                          trace=_trace(e))
        else:
            yield Outcome(item, value=value, elapsed_s=time.perf_counter() - t0)


def _run_pool(fn, items, jobs, kw, on_start=None) -> Iterator[Outcome]:
    """At most ``jobs`` items in flight. If a worker process dies (the pool breaks), the
    items then in flight run again one at a time in a fresh pool: the one that kills its
    worker alone is reported (``BrokenProcessPool``), the others are not lost."""
    workers = min(jobs, max(len(items), 1))
    queue, suspects = deque(items), deque()
    inflight: dict = {}  # future -> (item, runs alone)
    pool = worker_pool(workers)
    t0 = time.perf_counter()
    finished = False

    def submit(item):
        fut = pool.submit(fn, item, **kw)
        if on_start is not None:
            on_start(item)
        return fut

    try:
        while queue or suspects or inflight:
            if suspects and not inflight:
                item = suspects.popleft()
                inflight[submit(item)] = (item, True)
            elif not suspects:
                while queue and len(inflight) < workers:
                    item = queue.popleft()
                    inflight[submit(item)] = (item, False)
            done, _ = wait(inflight, return_when=FIRST_COMPLETED)
            broken = False
            for fut in done:
                item, alone = inflight.pop(fut)
                exc = fut.exception()
                dt = time.perf_counter() - t0
                if exc is None:
                    yield Outcome(item, value=fut.result(), elapsed_s=dt)
                elif isinstance(exc, BrokenProcessPool) and not alone:
                    suspects.append(item)
                    broken = True
                else:
                    broken |= isinstance(exc, BrokenProcessPool)
                    yield Outcome(item, error=describe_error(exc), elapsed_s=dt, trace=_trace(exc))
            if broken:
                for fut, (item, _) in inflight.items():  # all fail with the pool
                    fut.cancel()
                    suspects.append(item)
                inflight.clear()
                terminate_workers(pool)
                pool = worker_pool(workers)
        finished = True
    finally:
        if finished:  # every task done: the idle workers end at once, the manager thread too
            pool.shutdown(wait=True, cancel_futures=True)
        else:  # closed early, an exception, Ctrl-C or SIGTERM: no worker goes on alone
            terminate_workers(pool)


def _run_dask(fn, items, address, connect_timeout_s, kw) -> Iterator[Outcome]:
    try:
        from distributed import Client, as_completed
    except ImportError as e:  # pragma: no cover - depends on the installation
        raise SchedulerError(f"--scheduler {address}: Dask is not installed "
                             f"(pip install 'cdpr-bench[dask]'): {e}") from e
    try:
        client = Client(address, timeout=connect_timeout_s, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as e:
        raise SchedulerError(f"--scheduler {address}: cannot connect: "
                             f"{describe_error(e)}") from e
    return _dask_outcomes(client, as_completed, fn, items, kw)


def _dask_outcomes(client, as_completed, fn, items, kw) -> Iterator[Outcome]:
    futures = {}
    try:
        t0 = time.perf_counter()
        for item in items:
            fut = client.submit(partial(fn, **kw), item, pure=False, retries=0)
            futures[fut] = item
        for fut in as_completed(list(futures), loop=client.loop):
            item = futures.pop(fut)
            dt = time.perf_counter() - t0
            if fut.status == "error":
                exc = fut.exception()
                yield Outcome(item, error=describe_error(exc), elapsed_s=dt, trace=_trace(exc))
            elif fut.status == "cancelled":
                yield Outcome(item, error="CancelledError: cancelled on the cluster", elapsed_s=dt)
            else:
                yield Outcome(item, value=fut.result(), elapsed_s=dt)
            fut.release()
    finally:
        if futures:
            client.cancel(list(futures))
        client.close()


@dataclass
class Forked:
    """A forked child computing a float64 array of ``shape`` (:func:`fork_array`)."""

    pid: int
    fd: int
    shape: tuple[int, ...]


def fork_array(fn: Callable[[], Any], shape: tuple[int, ...]) -> Forked | None:
    """Compute ``fn()`` (an array of ``shape``, float64) in a forked child of this process,
    its memory as it is now: the other core's share of work that needs this process's whole
    state (a finite-difference Jacobian's columns). None where this system cannot fork.

    The child asks the kernel for SIGKILL when this process ends, takes SIGINT and SIGTERM
    with the default action, and ends with :func:`os._exit` (no buffers flushed twice, no
    handler of this process run); :func:`join_array` reaps it, :func:`kill_forked` ends
    it early."""
    if not hasattr(os, "fork"):
        return None
    parent = os.getpid()
    r, w = os.pipe()
    try:
        pid = os.fork()
    except OSError:
        os.close(r)
        os.close(w)
        return None
    if pid == 0:  # the child: never returns
        global _BUSY
        _BUSY = None  # (a helper claims no core of its own)
        code = 1
        try:
            os.close(r)
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, signal.SIG_DFL)
            if sys.platform.startswith("linux"):
                import ctypes

                ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL, 0, 0, 0)
            if os.getppid() != parent:
                os._exit(1)
            import numpy as np

            out = np.ascontiguousarray(fn(), dtype=float)
            if out.shape != tuple(shape):
                os._exit(1)
            view = memoryview(out.tobytes())
            while len(view):
                view = view[os.write(w, view):]
            code = 0
        except BaseException:  # noqa: BLE001 - the parent computes it again
            code = 1
        finally:
            os._exit(code)
    os.close(w)
    return Forked(pid, r, tuple(shape))


def join_array(child: Forked) -> Any:
    """The array the child computed, or None where it failed (the caller computes it
    itself); the child reaped either way."""
    import numpy as np

    want = int(np.prod(child.shape)) * 8
    chunks, got = [], 0
    try:
        while got < want:
            b = os.read(child.fd, min(want - got, 1 << 20))
            if not b:
                break
            chunks.append(b)
            got += len(b)
    finally:
        os.close(child.fd)
        _, status = os.waitpid(child.pid, 0)
    if got != want or status != 0:
        return None
    return np.frombuffer(b"".join(chunks), dtype=float).reshape(child.shape).copy()


def kill_forked(child: Forked) -> None:
    """End the child now and reap it (the caller leaves by an exception)."""
    with contextlib.suppress(ProcessLookupError):
        os.kill(child.pid, signal.SIGKILL)
    with contextlib.suppress(OSError):
        os.close(child.fd)
    with contextlib.suppress(ChildProcessError):
        os.waitpid(child.pid, 0)
