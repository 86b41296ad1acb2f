"""The simulated robot (firmware_sim/rig.py): drives, load cells and plant coupled."""

from __future__ import annotations

import dataclasses
import socket
import threading
import time

import numpy as np
import pytest

from controller.winch import load_winches, metres_per_count
from firmware_sim.cia402_drive import EDS_PATH
from firmware_sim.plant import Nuisances, Plant, PlantError
from firmware_sim.rig import SimRig, default_scenario
from firmware_sim.scenario import load_scenario
from hal.interface import open_hardware
from hal.loadcell_client import LoadCellClient

W = load_winches()
COUNT_M = float(metres_per_count(W)[0])
TRUTH = """format = "cdpr-scenario/1"
robot = "rocaspect"
seed = 3
init_pose = [9.0, 8.0, 1.2, 0.0, 0.0, 0.0]

[truth.load_cell_calibration]
gain_21 = 1.1
offset_11 = 5.0

[truth.exit_point_offset]
dx_31 = 0.03

[noise]
load_cell_n = 0.0
"""


def _scenario(tmp_path, text=TRUTH):
    p = tmp_path / "scenario.toml"
    p.write_text(text)
    return load_scenario(p)


@pytest.fixture
def manual_rig():
    rig = SimRig(plant_thread=False).start()
    yield rig
    rig.close()


def _refused(spec: str) -> bool:
    host, port = spec.rsplit(":", 1)
    try:
        socket.create_connection((host.split(":")[-1], int(port)), timeout=1.0).close()
    except OSError:
        return True
    return False


def test_rig_starts_with_the_platform_at_the_init_pose(manual_rig):
    rig = manual_rig
    sc = default_scenario()
    plant = Plant(sc.model, sc.truth, sc.init_pose)
    np.testing.assert_allclose(rig.bank.positions_m(), plant.reference, atol=COUNT_M)
    rec = rig.last
    np.testing.assert_allclose(rec.pose, sc.init_pose, atol=1e-5)
    np.testing.assert_allclose(rec.tensions_N, plant.init_tensions, atol=0.05)  # quantised
    np.testing.assert_array_equal(rec.measured_N, rec.tensions_N)  # ideal cells by default
    torque = np.array([d.load_torque_nm for d in rig.bank.drives])
    np.testing.assert_allclose(torque, rec.tensions_N * W.drum_radius_m / W.gear_ratio)
    ep = rig.endpoints()
    assert ep["can"].startswith("virtual:") and ep["modbus"].startswith("127.0.0.1:")
    assert ep["node_ids"] == list(range(1, 9)) and ep["unit_ids"] == list(range(1, 9))


def test_the_scenario_truth_is_what_the_cells_measure(tmp_path):
    sc = _scenario(tmp_path)
    with SimRig(sc, plant_thread=False) as rig:
        rec = rig.last
        np.testing.assert_allclose(rec.pose, sc.init_pose, atol=1e-3)  # truth != model
        gain = np.ones(8)
        gain[2] = 1.1
        offset = np.zeros(8)
        offset[0] = 5.0
        np.testing.assert_allclose(rec.measured_N, gain * rec.tensions_N + offset)
        client = LoadCellClient(rig.modbus_spec)
        try:
            client.poll_once()
            r = client.read()
        finally:
            client.stop()
        assert r.all_ok, r.faults()
        np.testing.assert_allclose(r.values_N, rec.measured_N, rtol=1e-6)  # float32, no noise


def test_manual_settle_is_the_plant_for_the_drive_positions(manual_rig):
    rig = manual_rig
    sc = default_scenario()
    plant = Plant(sc.model, sc.truth, sc.init_pose, Nuisances(0.0, 0.0, 0.0))
    plant.settle(rig.history[-1].readings_m, t=0.0)  # the rig's start-up settle
    moved = rig.bank.positions_m() + np.array([0.0, 0.0, -0.003, 0.0, 0.0, 0.002, 0.0, 0.0])
    rig.bank.set_positions_m(moved)
    readings = rig.bank.positions_m()
    rec = rig.settle_now()
    expect = plant.settle(readings, t=rig.time_s())
    np.testing.assert_array_equal(rec.readings_m, readings)
    np.testing.assert_allclose(rec.tensions_N, expect.tensions, rtol=1e-9)
    np.testing.assert_allclose(rec.pose, expect.pose, atol=1e-12)
    assert rec.tensions_N[2] > rig.history[-2].tensions_N[2] + 10  # pulled in: tighter
    assert rig.settle_now() is rec  # nothing changed: no new settle


def test_the_plant_thread_follows_the_drives():
    with SimRig(plant_rate_hz=50.0) as rig:
        before = rig.last
        rig.bank.set_positions_m(rig.bank.positions_m() + np.array([0.004] + [0.0] * 7))
        rec = rig.wait_settled(timeout_s=10.0)
        np.testing.assert_allclose(rec.readings_m, rig.bank.positions_m(), atol=1e-12)
        assert before.tensions_N[0] - rec.tensions_N[0] > 10  # paid out: slacker
        torque = np.array([d.load_torque_nm for d in rig.bank.drives])
        np.testing.assert_allclose(torque, rec.tensions_N * W.drum_radius_m / W.gear_ratio)


def test_drift_moves_the_platform_with_the_winches_still(tmp_path):
    sc = _scenario(tmp_path, 'format = "cdpr-scenario/1"\n[nuisance]\ndrift_m_per_h = 0.9\n')
    with SimRig(sc, plant_thread=False) as rig:
        first = rig.settle_now()
        assert rig.settle_now() is first  # time stands still without SYNC (sync clock)
        rig.bank.advance(4.0)  # 4 s of drive time: 1 mm of creep on every cable
        assert rig.time_s() == pytest.approx(first.t_s + 4.0, abs=1e-6)
        rec = rig.settle_now()
        np.testing.assert_array_equal(rec.readings_m, first.readings_m)
        assert rec.pose[2] < first.pose[2] - 5e-4  # longer cables: the platform sinks


def test_the_cells_keep_sampling_while_nothing_moves(manual_rig):
    client = LoadCellClient(manual_rig.modbus_spec, stale_s=0.25)
    try:
        client.poll_once()
        c0 = client.read().counter
        deadline_ok = client.start().wait_sweeps(3, timeout_s=5.0)
        assert deadline_ok
        r = client.read()
        while np.any(r.counter == c0):  # the rig samples at 50 Hz: poll with a deadline
            assert client.wait_sweeps(1, timeout_s=5.0)
            r = client.read()
        assert r.all_ok, r.faults()
    finally:
        client.stop()


def test_plant_errors_keep_the_last_rest_position(manual_rig, monkeypatch):
    rig = manual_rig
    last = rig.last

    def fail(*_a, **_k):
        raise PlantError("plant: no rest position found (test)")

    monkeypatch.setattr(rig.plant, "settle", fail)
    rig.bank.set_positions_m(rig.bank.positions_m() + 0.01)
    assert rig.settle_now() is last
    assert len(rig.plant_errors) == 1 and "no rest position found (test)" in rig.plant_errors[0]


def test_hub_and_rtu_in_process_with_the_hal():
    with SimRig(hub_port=0, rtu=True) as rig:
        assert rig.can_spec.startswith("socketcand:127.0.0.1:")
        assert rig.modbus_spec.startswith("rtu-tcp:127.0.0.1:")
        hw = open_hardware(rig.can_spec, rig.modbus_spec, eds=EDS_PATH, clock="sync")
        try:
            hw.start()
            hw.enable()
            assert hw.sample_tensions()
            r = hw.read()
            assert r.ok, r.faults
            np.testing.assert_allclose(r.tensions_N, rig.last.measured_N,
                                       atol=5 * rig.scenario.noise.load_cell_n)
        finally:
            hw.close()


def test_close_is_clean_and_idempotent():
    rig = SimRig(hub_port=0).start()
    can_spec, modbus = rig.can_spec, rig.modbus_spec
    assert not _refused(modbus)
    rig.close()
    rig.close()
    assert _refused(modbus)
    assert _refused(can_spec.removeprefix("socketcand:"))
    # threads of this rig end (poll: a thread may still be unwinding on a loaded machine)
    deadline = time.monotonic() + 5.0
    stale = {"sim-rig", "loadcell-modbus-server", "can-hub-accept"}
    while stale & {t.name for t in threading.enumerate()} and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not stale & {t.name for t in threading.enumerate()}


def test_winches_for_other_cables_are_refused():
    w = dataclasses.replace(W, cables=("11", "12", "21", "22", "31", "32", "41", "43"))
    with pytest.raises(ValueError, match="winches .* are for cables"):
        SimRig(winches=w)


def test_wall_clock_rig_with_a_wall_clock_hal():
    """Real-time mode: drives on time.monotonic, the plant's time is the wall clock."""
    with SimRig(clock="wall") as rig:
        hw = open_hardware(rig.can_spec, rig.modbus_spec, eds=EDS_PATH, clock="wall")
        try:
            hw.start()
            hw.enable()
            t0 = rig.time_s()
            l0 = hw.read().lengths_m
            for i in range(1, 51):  # not paced: only the coupling is checked here
                hw.step(l0 + np.array([0.002] + [0.0] * 7) * i / 50)
            deadline = time.monotonic() + 10.0
            while np.abs(rig.bank.positions_m()[0] - (l0[0] + 0.002)) > 1e-5:
                assert time.monotonic() < deadline, "drive did not reach the setpoint"
                hw.step()
            rec = rig.wait_settled(timeout_s=10.0)
            assert rec.t_s > t0 and rig.time_s() > t0
            assert hw.sample_tensions()
            r = hw.read()
            assert np.all(r.tension_status == 0), r.faults
            np.testing.assert_allclose(r.tensions_N, rec.measured_N,
                                       atol=5 * rig.scenario.noise.load_cell_n + 0.05)
        finally:
            hw.close()
