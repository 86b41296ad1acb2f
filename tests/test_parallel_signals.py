"""Worker processes end with their parent, whatever the signal (bench.parallel).

A separate Python process runs two long worker tasks (through ``run_each``, as
``cdpr evaluate`` does, or through ``worker_pool`` + ``ending_workers``, as ``cdpr
diagnose`` does, its workers' jobs with forked helpers as a split Jacobian has); each
worker (and helper) writes its pid to a file when it starts. The parent
alone is then sent SIGTERM, SIGINT or SIGKILL, and no worker may be left after a
generous wait.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

WORK = '''
import os, sys, time

def work(i, d):
    open(os.path.join(d, f"w{os.getpid()}"), "w").close()
    time.sleep(600)
    return i
'''

RUN_EACH = WORK + '''
from contextlib import closing
from bench.parallel import interrupt_on_term, run_each

if __name__ == "__main__":
    with interrupt_on_term(), closing(run_each(work, [0, 1], jobs=2, d=sys.argv[1])) as it:
        for o in it:
            pass
'''

POOL = WORK + '''
from bench.parallel import ending_workers, interrupt_on_term, worker_pool

if __name__ == "__main__":
    with interrupt_on_term():
        pool = worker_pool(2)
        with ending_workers(pool):
            futs = [pool.submit(work, i, sys.argv[1]) for i in range(2)]
            for f in futs:
                f.result()
'''

# a core-sharing pool (``cdpr diagnose``'s): each worker's job forks a helper
# (``fork_array``, as a finite-difference Jacobian's split does), which must end too
HELPERS = WORK + """
from bench.parallel import (ending_workers, fork_array, interrupt_on_term, job_running,
                            worker_pool)

def helped(i, d):
    with job_running():
        def helper():
            open(os.path.join(d, f"h{os.getpid()}"), "w").close()
            time.sleep(600)
            return [0.0]
        fork_array(helper, (1,))
        return work(i, d)

if __name__ == "__main__":
    with interrupt_on_term():
        pool = worker_pool(2, share_cores=True)
        with ending_workers(pool):
            futs = [pool.submit(helped, i, sys.argv[1]) for i in range(2)]
            for f in futs:
                f.result()
"""

SCRIPTS = {"run_each": (RUN_EACH, 2), "pool": (POOL, 2), "pool_helpers": (HELPERS, 4)}


def _default_signals() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("State:"):
                    return "Z" not in line.split()[1]
    except FileNotFoundError:
        return False
    return True


def _wait(cond, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.1)
    return cond()


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc to watch processes")
@pytest.mark.parametrize("script", list(SCRIPTS))
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT, signal.SIGKILL])
def test_workers_end_with_their_parent(tmp_path, script, sig):
    src = tmp_path / "parent.py"
    text, n_procs = SCRIPTS[script]
    src.write_text(textwrap.dedent(text))
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    # the parent starts with default signal dispositions (a shell that runs the tests in
    # the background leaves SIGINT ignored, and Python then keeps ignoring it)
    proc = subprocess.Popen([sys.executable, str(src), str(tmp_path)], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            preexec_fn=_default_signals)
    workers: list[int] = []
    try:
        assert _wait(lambda: len(list(tmp_path.glob("[wh]*"))) == n_procs, 60), \
            proc.stderr.read().decode() if proc.poll() is not None else "workers did not start"
        workers = [int(p.name[1:]) for p in tmp_path.glob("[wh]*")]
        assert all(_alive(w) for w in workers)
        os.kill(proc.pid, sig)  # the parent alone, not its process group
        proc.wait(timeout=60)
        assert _wait(lambda: not any(_alive(w) for w in workers), 30), \
            f"workers {[w for w in workers if _alive(w)]} outlived their parent"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for w in workers:
            if _alive(w):
                os.kill(w, signal.SIGKILL)


IDLE = '''
import os, sys
from bench.parallel import ending_workers, interrupt_on_term, worker_pool

def pid(_):
    return os.getpid()

def main():
    with interrupt_on_term():
        pool = worker_pool(2)
        with ending_workers(pool):
            pool.submit(pid, 0).result()
            for p in pool._processes:  # every worker started, now waiting for work
                open(os.path.join(sys.argv[1], f"w{p}"), "w").close()
            print("idle", file=sys.stderr, flush=True)
            while True:
                pool.submit(pid, 0).result()  # the workers stay in the pool's hands

if __name__ == "__main__":
    try:
        main()
    except KeyboardInterrupt:  # the parent's own report is bench.cli's business
        sys.exit(130)
'''


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc to watch processes")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_workers_told_to_stop_end_quietly(tmp_path, sig):
    """The parent ends its workers (SIGTERM) when it is interrupted: no worker prints a
    traceback (a fork inherits the parent's SIGTERM handler, which raises Terminated)."""
    src = tmp_path / "parent.py"
    src.write_text(textwrap.dedent(IDLE))
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, str(src), str(tmp_path)], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_default_signals)
    workers: list[int] = []
    try:
        assert proc.stderr.readline() == "idle\n"
        workers = [int(p.name[1:]) for p in tmp_path.glob("w*")]
        assert len(workers) == 2
        os.kill(proc.pid, sig)
        err = proc.stderr.read()  # until the parent and every worker closed it
        proc.wait(timeout=60)
        assert "Traceback" not in err and "Terminated" not in err, err
        assert proc.returncode != 0
        assert _wait(lambda: not any(_alive(w) for w in workers), 30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for w in workers:
            if _alive(w):
                os.kill(w, signal.SIGKILL)


def _pid(_):
    return os.getpid()


def test_a_terminated_pool_leaves_its_wakeup_pipe_closed():
    """After :func:`terminate_workers` the pool's manager thread has ended and closed its
    wake-up pipe: Python's exit hook (3.11) writes to that pipe without a lock, and a
    thread still closing it then makes the interpreter print ``Bad file descriptor``
    (1 in ~50 of the test above)."""
    from bench.parallel import terminate_workers, worker_pool

    pool = worker_pool(2)
    pool.submit(_pid, 0).result()
    wakeup = pool._executor_manager_thread_wakeup
    manager = pool._executor_manager_thread
    terminate_workers(pool)
    assert not manager.is_alive()
    assert wakeup._closed
