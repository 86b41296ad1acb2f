"""A close of a background writer that a Ctrl-C interrupts while it waits for the writer
thread is done whole by the next close (``bench.recording.BackgroundWriter``): the rows
queued after the thread's last take are written and the file is closed."""

from __future__ import annotations

import threading

import pytest

from bench.recording import CsvStream


def test_a_close_interrupted_in_its_wait_is_finished_by_the_next(tmp_path, monkeypatch):
    path = tmp_path / "rows.csv"
    w = CsvStream(path, ["t", "x"], flush_s=60.0)
    for k in range(5):
        w.append([k, 2 * k])
    join = threading.Thread.join
    calls = []

    def interrupted(self, timeout=None):
        calls.append(1)
        if len(calls) == 1:
            raise KeyboardInterrupt
        return join(self, timeout)

    monkeypatch.setattr(threading.Thread, "join", interrupted)
    with pytest.raises(KeyboardInterrupt):
        w.close()
    w.close()
    rows = [[float(v) for v in line.split(",")] for line in path.read_text().splitlines()[1:]]
    assert rows == [[k, 2 * k] for k in range(5)]
    assert w._f.closed
