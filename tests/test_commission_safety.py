"""``cdpr commission check``: the drives' master-loss objects as safety failures, and
``check --apply`` storing the safe values (0x1010) so that they survive a power cycle.

Eight simulated drives (:mod:`firmware_sim.cia402_drive`) fresh from the factory: the EDS
power-on values 0x1016:01 = 0 (master heartbeat not watched), 0x1400:05 = 0 (no RPDO
deadline), 0x6007 = 1 and 0x605A = 2 let a drive keep moving after its master died, and
0x1017 = 0 (no heartbeat of its own) hides a dead drive from the master.
"""

from __future__ import annotations

import json
import time

import canopen
import pytest

from bench.cli import main
from firmware_sim.cia402_drive import EDS_PATH
from hal.drives_config import drive_settings, safety_failure
from hal.sdo_config import compare_configuration
from tests.test_commission import Rig, W

#: the issue's four, and the drive's own heartbeat 0x1017 = 0 (the master cannot see it die)
POWER_ON_UNSAFE = {"0x1016:01", "0x1017:00", "0x1400:05", "0x6007:00", "0x605A:00"}


def cli(capsys, *argv: str) -> tuple[int, dict]:
    capsys.readouterr()
    code = main(["commission", *argv, "--json"])
    out = capsys.readouterr().out.strip().splitlines()
    return code, json.loads(out[-1]) if out else {}


@pytest.fixture
def rig():
    r = Rig()
    yield r
    r.close()


def test_safety_failure_names_only_differing_safety_objects():
    assert safety_failure(0x1016, 1, 0x7F00FA, 0) is not None
    assert "not watched" in safety_failure(0x1016, 1, 0x7F00FA, 0)
    assert safety_failure(0x1016, 1, 0x7F00FA, 0x7F00FA) is None  # the safe value
    assert safety_failure(0x6065, 0, 100, 5) is None  # a difference, not a safety object
    assert "RPDO deadline" in safety_failure(0x1400, 5, 20, 0)
    assert safety_failure(0x6007, 0, 3, None).startswith("cannot be read")


def test_fresh_drives_fail_on_safety_and_apply_stores_the_safe_values(rig, capsys):
    code, out = cli(capsys, "check", "--can", rig.can, "--no-report")
    assert code == 1 and not out["ok"]
    assert out["safety_failures"] == 8 * len(POWER_ON_UNSAFE)
    for d in out["drives"]:
        got = {f["object"] for f in d["safety_failures"]}
        assert got == POWER_ON_UNSAFE, d["node_id"]
        for f in d["safety_failures"]:
            assert f["why"] and f["safe_value"] != f["actual"]
    code = main(["commission", "check", "--can", rig.can, "--no-report"])
    said = capsys.readouterr().out
    assert code == 1 and "SAFETY FAILURE 0x1016:01" in said and "safe value" in said
    assert "node 127, 250 ms" in said and "keeps moving" in said

    code, out = cli(capsys, "check", "--can", rig.can, "--apply", "--yes", "--listen", "0.1",
                    "--no-report")
    assert code == 0 and out["applied"] == list(range(1, 9)) and out["safety_failures"] == 0

    # a power cycle and an NMT reset node: the stored values come back, not the EDS's
    for nid in (1, 2, 3, 4):
        rig.bank.drive(nid).power_off()
        rig.bank.drive(nid).power_on()
    for nid in (5, 6, 7, 8):
        rig.bank.drive(nid).reset_node()
    rig.net.nmt.send_command(0x82)  # reset communication, every node
    time.sleep(0.1)
    node = canopen.RemoteNode(4, canopen.import_od(str(EDS_PATH), 4))
    rig.net.add_node(node)
    left = compare_configuration(node, drive_settings(W, W.index_of_node(4),
                                                      node.object_dictionary), "n4")
    assert [d.index for d in left] == [0x6060]  # process data (rww), written at each start
    code, out = cli(capsys, "check", "--can", rig.can, "--no-report")
    assert out["safety_failures"] == 0
    assert all(d["safety_failures"] == [] for d in out["drives"])
    # only the mode of operation (not stored, written at each start) differs
    assert {x["index"] for d in out["drives"] for x in d["differences"]} <= {"0x6060"}


def test_apply_without_store_loses_the_safe_values_on_a_power_cycle(rig, capsys):
    code, out = cli(capsys, "check", "21", "--can", rig.can, "--apply", "--yes", "--no-store",
                    "--listen", "0", "--no-report")
    assert code == 0 and out["safety_failures"] == 0
    nid = int(W.node_id[W.cables.index("21")])
    rig.bank.drive(nid).power_off()
    rig.bank.drive(nid).power_on()
    time.sleep(0.05)
    code, out = cli(capsys, "check", "21", "--can", rig.can, "--no-report")
    assert code == 1 and {f["object"] for f in out["drives"][0]["safety_failures"]} \
        == POWER_ON_UNSAFE


def test_the_safety_objects_are_documented():
    from pathlib import Path

    from hal.drives_config import SAFETY_OBJECTS

    page = (Path(__file__).resolve().parents[1] / "docs" / "reference"
            / "validation.md").read_text()
    for index, sub in SAFETY_OBJECTS:
        assert f"| 0x{index:04X}:{sub:02X} |" in page
