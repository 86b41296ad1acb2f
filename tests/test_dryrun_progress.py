"""``cdpr dry-run``'s progress bar: its percentage and its time say the same thing."""

from __future__ import annotations

import re
from types import SimpleNamespace

import pytest

from bench.commands.dryrun import _progress_printer

LINE = re.compile(r"([\d.]+)%, t ([\d.]+)/([\d.]+) s")


def _res(simulated_s: float, path_s: float = 50.2) -> SimpleNamespace:
    return SimpleNamespace(path_s=path_s, simulated_s=simulated_s, cycles=100, overruns=0,
                           events=[], pose_error_rms_m=None)


def _show(capsys, duration, res, t_traj) -> tuple[float, float, float, str]:
    _progress_printer(False, duration)(res, t_traj)
    line = capsys.readouterr().err.strip()
    m = LINE.search(line)
    assert m, line
    return float(m[1]), float(m[2]), float(m[3]), line


@pytest.mark.parametrize("duration, sim, t_traj, pct, end", [
    (2.0, 0.98, 0.0, 0.0, 2.0),     # initialising (1 s before the path): 0 %, not 49 %
    (2.0, 2.0, 1.0, 50.0, 2.0),
    (2.0, 3.0, 2.0, 100.0, 2.0),
    (None, 1.0, 0.0, 0.0, 50.2),
    (None, 26.1, 25.1, 50.0, 50.2),
    (100.0, 26.1, 25.1, 50.0, 50.2),  # a --duration beyond the path: the path's end
])
def test_percent_and_time_agree(capsys, duration, sim, t_traj, pct, end):
    got_pct, t, got_end, line = _show(capsys, duration, _res(sim), t_traj)
    assert got_pct == pytest.approx(pct, abs=0.05) and got_end == end
    assert got_pct == pytest.approx(100 * t / got_end, abs=0.1)
    assert ("--duration, path 50.2 s" in line) == (duration is not None and duration < 50.2)


def test_into_a_pipe_one_line_every_few_seconds_not_per_update(capsys, monkeypatch):
    """Not a terminal: 20 s of updates every 0.05 s (the loop calls 4 per second) print a
    line at once, then one per period, then the last one: not one line per update."""
    from bench import progress

    now = [100.0]
    monkeypatch.setattr(progress.time, "perf_counter", lambda: now[0])
    show = _progress_printer(False, 20.0)
    for i in range(401):
        show(_res(1.0 + 0.05 * i), 0.05 * i)
        now[0] += 0.05
    lines = capsys.readouterr().err.splitlines()
    assert "\x1b" not in "".join(lines) and "\r" not in "".join(lines)
    assert 3 <= len(lines) <= 20.0 / progress.PIPE_PERIOD_S + 2, lines
    assert LINE.search(lines[0])[1] == "0.0" and LINE.search(lines[-1])[1] == "100.0"


def test_quiet_prints_nothing(capsys):
    show = _progress_printer(True, None)
    for i in range(10):
        show(_res(float(i)), float(i))
    assert capsys.readouterr().err == ""
