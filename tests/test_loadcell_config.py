"""``--modbus`` spec parsing and the load-cell calibration file."""

from __future__ import annotations

import argparse

import numpy as np
import pytest
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.framer import FramerRTU, FramerSocket

from hal.loadcell_calibration import (
    CalibrationError,
    LoadCellCalibration,
    load_calibration,
    parse_calibration,
)
from hal.modbus_config import (
    ModbusEndpoint,
    ModbusSpecError,
    add_modbus_arguments,
    parse_modbus_spec,
)


@pytest.mark.parametrize(
    ("spec", "expect"),
    [
        ("127.0.0.1:5020", ModbusEndpoint("tcp", host="127.0.0.1", port=5020)),
        ("loadcells.lab:502", ModbusEndpoint("tcp", host="loadcells.lab", port=502)),
        ("[::1]:1502", ModbusEndpoint("tcp", host="::1", port=1502)),
        ("rtu-tcp:10.0.0.7:4001", ModbusEndpoint("rtu-tcp", host="10.0.0.7", port=4001)),
        ("rtu:/dev/ttyUSB0:115200", ModbusEndpoint("rtu", device="/dev/ttyUSB0", baudrate=115200)),
        (
            "rtu:/dev/ttyUSB0:19200:8E1",
            ModbusEndpoint("rtu", device="/dev/ttyUSB0", baudrate=19200, parity="E"),
        ),
        (
            "rtu:socket://127.0.0.1:5020:9600",
            ModbusEndpoint("rtu", device="socket://127.0.0.1:5020", baudrate=9600),
        ),
    ],
)
def test_spec_forms(spec, expect):
    ep = parse_modbus_spec(spec)
    assert ep == expect
    assert parse_modbus_spec(str(ep)) == ep  # str() gives a spec back


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ("", "empty spec"),
        ("127.0.0.1", "missing ':PORT'"),
        ("127.0.0.1:http", "port 'http' is not in 1..65535"),
        ("127.0.0.1:70000", "port '70000'"),
        (":502", "empty host"),
        ("fe80::1:502", "IPv6 in brackets"),
        ("rtu:/dev/ttyUSB0", "serial RTU needs rtu:DEVICE:BAUD"),
        ("rtu:/dev/ttyUSB0:fast", "baud rate 'fast'"),
        ("rtu:/dev/ttyUSB0:19200:9X1", "framing '9X1' must be"),
        ("rtu-tcp:10.0.0.7", "missing ':PORT'"),
        ("tcp:10.0.0.7:502", "unknown scheme 'tcp'"),
    ],
)
def test_malformed_specs_are_explained(spec, match):
    with pytest.raises(ModbusSpecError, match=match):
        parse_modbus_spec(spec)


def test_argparse_turns_bad_specs_into_usage_errors(capsys):
    p = argparse.ArgumentParser(prog="cdpr x")
    add_modbus_arguments(p)
    args = p.parse_args(["--modbus", "rtu-tcp:127.0.0.1:1502", "--loadcell-rate", "20"])
    assert args.modbus.kind == "rtu-tcp" and args.loadcell_rate == 20.0
    with pytest.raises(SystemExit):
        p.parse_args(["--modbus", "127.0.0.1"])
    assert "missing ':PORT'" in capsys.readouterr().err


def test_clients_have_the_right_framing():
    tcp = parse_modbus_spec("127.0.0.1:5020").make_client(0.1)
    rtu_tcp = parse_modbus_spec("rtu-tcp:127.0.0.1:5020").make_client(0.1)
    serial = parse_modbus_spec("rtu:/dev/null-not-a-tty:19200:8E1").make_client(0.1)
    assert isinstance(tcp, ModbusTcpClient) and isinstance(tcp.framer, FramerSocket)
    assert isinstance(rtu_tcp, ModbusTcpClient) and isinstance(rtu_tcp.framer, FramerRTU)
    assert isinstance(serial, ModbusSerialClient) and isinstance(serial.framer, FramerRTU)
    assert serial.comm_params.parity == "E" and serial.comm_params.baudrate == 19200
    assert tcp.retries == 0


# ---- calibration ----------------------------------------------------------
def test_calibration_file_round_trip(tmp_path):
    p = tmp_path / "cal.toml"
    p.write_text("[load_cell_calibration]\ngain_11 = 1.02\noffset_11 = -4.0\ngain_42 = 0.98\n")
    cal = load_calibration(p)
    assert cal.gain.tolist() == [1.02] + [1.0] * 6 + [0.98]
    assert cal.offset_N.tolist() == [-4.0] + [0.0] * 7
    true = np.linspace(50, 400, 8)
    np.testing.assert_allclose(cal.true_from_measured(cal.measured_from_true(true)), true)
    assert cal.as_params()["gain_42"] == 0.98
    # a diagnosis effect's params (flat keys) load the same
    assert parse_calibration(cal.as_params()).gain.tolist() == cal.gain.tolist()


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("gain_51 = 1.0\n", r"cal\.toml: unknown key 'gain_51'"),
        ("scale_11 = 1.0\n", r"cal\.toml: unknown key 'scale_11'"),
        ("gain_11 = 'big'\n", r"cal\.toml: gain_11 = 'big' is not a number"),
        ("gain_11 = 0.0\n", r"cal\.toml:1: gain_11: 0\.0 is outside the physical range 0\.1 <= "
                             r"gain_11 <= 10"),
        ("offset_21 = nan\n", r"cal\.toml:1: offset_21: nan is outside the physical range"),
        ("[load_cell_calibration]\ngain_11 = 1.0\n[other]\nx = 1\n", r"unknown top-level key"),
        ("gain_11 = \n", r"cal\.toml: .*line 1"),
    ],
)
def test_calibration_errors_name_file_and_key(tmp_path, text, match):
    p = tmp_path / "cal.toml"
    p.write_text(text)
    with pytest.raises(CalibrationError, match=match):
        load_calibration(p)


def test_identity_calibration():
    cal = LoadCellCalibration.identity()
    assert cal.true_from_measured(np.arange(8.0)).tolist() == list(np.arange(8.0))


def test_client_from_command_line(tmp_path):
    from hal.loadcell_client import client_from_args

    cal = tmp_path / "cal.toml"
    cal.write_text("gain_22 = 1.1\n")
    p = argparse.ArgumentParser()
    add_modbus_arguments(p)
    args = p.parse_args(
        ["--modbus", "rtu-tcp:127.0.0.1:1502", "--loadcell-calibration", str(cal),
         "--loadcell-timeout", "0.05", "--loadcell-stale", "0.5", "--loadcell-max-age", "2"]
    )
    client = client_from_args(args)
    assert str(client.endpoint) == "rtu-tcp:127.0.0.1:1502"
    assert client.calibration.gain[3] == 1.1 and client.timeout_s == 0.05
    assert client.stale_s == 0.5 and client.max_age_s == 2.0
    with pytest.raises(ValueError, match="give --modbus"):
        client_from_args(p.parse_args([]))
