"""``measure_raw`` (cdpr commission calibrate/zero): a poll that got no answer (a frame lost on
the line, a unit slow under load) is polled again until the deadline; a cell that reports a
fault stops the measurement at once; no valid reading within the deadline names the last
problem."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from bench.commission.common import CommissionError
from bench.commission.loadcells import measure_raw
from hal.loadcell_client import CableStatus


class Client:
    """A load-cell client whose cell 0 answers with the given statuses in turn (the last
    repeated); each OK answer is a fresh sample (its counter advances) of 100 N."""

    def __init__(self, statuses: list[CableStatus]) -> None:
        self.statuses, self.i, self.counter = statuses, -1, 0
        self.map = SimpleNamespace(describe=lambda k: f"Modbus unit {k + 1} (cable 11)")

    def poll_once(self) -> None:
        self.i = min(self.i + 1, len(self.statuses) - 1)
        self.counter += self.statuses[self.i] is CableStatus.OK

    def read(self):
        st = self.statuses[self.i]
        msg = "" if st is CableStatus.OK else f"Modbus unit 1 (cable 11): {st.name}"
        return SimpleNamespace(status=np.array([int(st)]), messages=[msg],
                               counter=np.array([self.counter]),
                               values_N=np.array([100.0]))


def test_a_poll_without_an_answer_is_polled_again():
    c = Client([CableStatus.TIMEOUT, CableStatus.COMM_ERROR, CableStatus.OK])
    got = measure_raw(c, 0, 3, timeout_s=2.0, period_s=0.001)
    assert got.mean_N == 100.0


@pytest.mark.parametrize("fault", [CableStatus.SENSOR_FAULT, CableStatus.OUT_OF_RANGE,
                                   CableStatus.EXCEPTION, CableStatus.NAN])
def test_a_cell_reporting_a_fault_stops_at_once(fault):
    c = Client([fault, CableStatus.OK])
    with pytest.raises(CommissionError, match=f"{fault.name}: no valid reading$"):
        measure_raw(c, 0, 3, timeout_s=2.0, period_s=0.001)
    assert c.i == 0


def test_no_answer_until_the_deadline_names_the_last_problem():
    c = Client([CableStatus.TIMEOUT])
    with pytest.raises(CommissionError, match="TIMEOUT: no valid reading within 0.05 s"):
        measure_raw(c, 0, 3, timeout_s=0.05, period_s=0.001)
