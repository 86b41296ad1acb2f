"""Terminal output: tables (bench.tables), CANopen values as CANopen people read them
(bench.commission.values), non-physical option values refused (bench.commands.argtypes)."""

from __future__ import annotations

import io
import json
import re
import sys

import pytest

from bench.cli import main
from bench.commission.values import describe, heartbeat_text, mapping_text
from bench.tables import col, render
from controller.winch import load_winches

W = load_winches()


class Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


# ---------------------------------------------------------------------------- tables

COLS = [col("node"), col("status", justify="left"), col("tension", "N"),
        col("notes", justify="left")]
ROWS = [[1, "ok", "412.3", ""], [127, "missing", None, "no answer"]]


def test_table_into_a_pipe_is_plain_aligned_text_with_units_in_the_headers():
    text = render(COLS, ROWS, stream=io.StringIO())
    assert "\x1b" not in text
    lines = text.splitlines()
    assert lines[0].split() == ["node", "status", "tension", "[N]", "notes"]
    # right-justified numbers end in the same column; None is shown as '-'
    assert lines[1].index("412.3") + 5 == lines[2].index("-") + 1
    assert lines[2].rstrip().endswith("no answer") and lines[1] == lines[1].rstrip()
    assert all(line.startswith("  ") for line in lines)  # indented under its title


def test_table_on_a_terminal_is_styled():
    text = render(COLS, ROWS, stream=Tty())
    assert "\x1b[" in text and "tension [N]" in re.sub(r"\x1b\[[0-9;]*m", "", text)


def test_monitor_table_into_a_pipe_has_no_ansi_codes():
    from types import SimpleNamespace

    from bench.commission.monitor import render as monitor_render

    s = SimpleNamespace(cable="21", node_id=3, nmt_state="OPERATIONAL",
                        state="OPERATION_ENABLED", error_code=0, length_m=12.3456,
                        velocity_m_s=0.01, torque_permille=120, current_permille=None)
    lines = monitor_render([s], None, None, 0.12, 100, [], "monitor", False,
                           stream=io.StringIO())
    text = "\n".join(lines)
    assert "\x1b" not in text
    for header in ("length [m]", "v [m/s]", "tension [N]", "age [s]"):
        assert header in text
    assert "12.3456" in text


# ---------------------------------------------------------------------------- CANopen values


def test_pdo_mapping_entries_in_hex_with_what_they_map():
    assert mapping_text(0x607A0020) == "0x607A0020 (0x607A:00, 32 bit)"
    assert describe(0x1600, 2, 1618608160)[0] == "0x607A0020 (0x607A:00, 32 bit)"
    assert describe(0x1A00, 1, 0x60410010)[0] == "0x60410010 (0x6041:00, 16 bit)"
    assert describe(0x1A00, 1, 0)[0] == "0 (empty)"
    assert describe(0x1600, 0, 2)[0] == "2"  # the count of entries stays a count


def test_consumer_heartbeat_entries_name_node_and_time():
    assert heartbeat_text(8323322) == "node 127, 250 ms"
    assert describe(0x1016, 1, 0x007F00FA)[0] == "node 127, 250 ms"
    assert describe(0x1016, 1, 0)[0] == "not watched (0)"
    assert describe(0x1016, 0, 1)[0] == "1"  # sub-index 0: the number of entries


def test_cob_ids_and_times():
    assert describe(0x1005, 0, 0x80)[0] == "0x00000080"
    assert describe(0x1400, 1, 0x80000203)[0] == "0x80000203 (disabled)"
    assert describe(0x1800, 1, 0x183)[0] == "0x00000183"
    assert describe(0x1400, 5, 20)[0] == "20 ms" and describe(0x1017, 0, 100)[0] == "100 ms"
    assert describe(0x605A, 0, 6)[0] == "6"  # small numbers stay decimal


def test_positions_in_metres_with_the_counts_kept_under_their_unit():
    k = 2
    counts = int(W.axis(k).m_to_counts(12.5))
    text, extra = describe(0x607D, 2, counts, W, k)
    assert text == f"{W.axis(k).counts_to_m(counts):.4f} m ({counts} counts)"
    assert extra["counts"] == counts and extra["m"] == pytest.approx(12.5, abs=1e-6)
    text, extra = describe(0x6081, 0, 500000, W, k)
    assert extra == {"counts_s": 500000,
                     "m_s": pytest.approx(500000 * W.metres_per_count[k], rel=1e-12)}
    assert text.endswith("m/s (500000 counts/s)")
    # without the winch file: counts stay counts
    assert describe(0x607D, 2, counts) == (f"0x{counts:08X}" if counts >= 0x10000
                                           else str(counts), {})


# ---------------------------------------------------------------------------- refusals


@pytest.mark.parametrize("argv, words", [
    (["dry-run", "paper-centre", "--duration", "-5"], "--duration: -5"),
    (["dry-run", "paper-centre", "--duration", "0"], "--duration: 0"),
    (["dry-run", "paper-centre", "--duration", "nan"], "--duration: nan"),
    (["dry-run", "paper-centre", "--duration", "inf"], "--duration: inf"),
    (["commission", "check", "--can", "virtual:x", "--listen", "-1"], "--listen: -1"),
    (["commission", "scan", "--can", "virtual:x", "--sdo-timeout", "0"], "--sdo-timeout: 0"),
    (["commission", "reference", "--can", "virtual:x", "--samples", "0"], "--samples: 0"),
    (["commission", "home", "21", "--can", "virtual:x", "--length", "-2"], "--length: -2"),
    (["commission", "tare", "21", "--modbus", "127.0.0.1:1", "--load", "-3"], "--load: -3"),
    (["evaluate", "--cases", "1", "--connect-timeout", "-1"], "--connect-timeout: -1"),
    (["sim", "--can-port", "-1"], "--can-port: -1"),
    (["evaluate", "--cases", "1", "--seed", "-3"], "--seed: -3"),
    (["campaign", "s.toml", "out", "--seed", "-1"], "--seed: -1"),
])
def test_non_physical_values_are_refused_with_exit_2_and_the_range(capsys, argv, words):
    with pytest.raises(SystemExit) as e:
        main(argv)
    err = capsys.readouterr().err
    assert e.value.code == 2 and words in err, err
    assert re.search(r"in [\[(][-\d.inf]+, [\d.inf]+[\])]", err), err  # the allowed range


def test_refusal_under_json_is_one_json_object(capsys):
    with pytest.raises(SystemExit) as e:
        main(["dry-run", "paper-centre", "--duration", "-5", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert e.value.code == 2 and "(0, inf)" in out["error"]


def test_a_positive_duration_still_parses():
    from bench.cli import build_parser

    args = build_parser("dry-run").parse_args(["dry-run", "paper-centre", "--duration", "2.5"])
    assert args.duration == 2.5


def test_commission_check_text_in_a_pipe_prints_canopen_forms(capsys):
    """``commission check`` on drives out of the box: mapping and heartbeat entries as
    CANopen people write them, never 1618608160 or 8323322; no ANSI codes in a pipe."""
    sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
    from test_commission import Rig

    r = Rig()
    try:
        code = main(["commission", "check", "21", "--can", r.can, "--no-report"])
    finally:
        r.close()
    out = capsys.readouterr().out
    assert code == 1 and "\x1b" not in out
    assert "0x1600:02 RPDO1 map Target position: expected 0x607A0020 (0x607A:00, 32 bit)" in out
    assert "0x1016:01 consumer heartbeat time (master): expected node 127, 250 ms" in out
    assert "1618608160" not in out and "8323322" not in out
    assert re.search(r"0x607D:02 software position limit max: expected \d+\.\d{4} m "
                     r"\(\d+ counts\)", out), out


# ---------------------------------------------------------------------------- properties

from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


@given(index=st.integers(0x1000, 0xFFFF), sub=st.integers(0, 0xFF),
       bits=st.sampled_from([8, 16, 32, 64]))
def test_a_mapping_entry_reads_back_as_the_object_it_maps(index, sub, bits):
    value = index << 16 | sub << 8 | bits
    text = describe(0x1A00, 1, value)[0]
    m = re.fullmatch(r"0x([0-9A-F]{8}) \(0x([0-9A-F]{4}):([0-9A-F]{2}), (\d+) bit\)", text)
    assert m, text
    assert (int(m[1], 16), int(m[2], 16), int(m[3], 16), int(m[4])) == (value, index, sub, bits)


@given(node=st.integers(1, 127), ms=st.integers(1, 0xFFFF))
def test_a_heartbeat_entry_names_its_node_and_time(node, ms):
    assert describe(0x1016, 1, node << 16 | ms)[0] == f"node {node}, {ms} ms"
