"""``cdpr commission scan``: what is on the CAN bus and the Modbus network, against what the
configuration expects.

Drives: every node id 1..127 is probed (SDO upload of 0x1000, heartbeats heard in the
window), then each node's device type and identity (0x1018: vendor, product, revision,
serial) are read and set against the winch parameter file (which node ids) and the EDS
(which device): ``ok``, ``missing``, ``extra``, ``wrong_vendor``, ``wrong_product``,
``wrong_revision``, ``wrong_device_type`` or ``no_sdo`` (heard, but no SDO answer: NMT
STOPPED?). Load cells: one read of every unit of the register map (``--probe-units``: also
ids outside it, to find extra devices). Read-only. Exit status 1 when anything is not ok.
"""

from __future__ import annotations

import argparse
import time

from bench.commission.common import (
    CommissionError,
    Ui,
    network_of,
    register_map_of,
    tension_window_of,
    winches_of,
)
from bench.commission.report import Section


def expected_identity(eds: str) -> dict[str, int | None]:
    """Device type, vendor id, product code and revision the EDS describes."""
    import canopen

    od = canopen.import_od(str(eds))
    info = od.device_information

    def default(index: int, sub: int) -> int | None:
        try:
            obj = od[index]
            var = obj if sub == 0 and not hasattr(obj, "subindices") else obj[sub]
            return int(var.default) if var.default is not None else None
        except (KeyError, TypeError, ValueError):
            return None

    return {"device_type": default(0x1000, 0),
            "vendor_id": info.vendor_number if info.vendor_number is not None
            else default(0x1018, 1),
            "product_code": info.product_number if info.product_number is not None
            else default(0x1018, 2),
            "revision": info.revision_number if info.revision_number is not None
            else default(0x1018, 3)}


def drive_rows(found, winches, ident: dict) -> list[dict]:
    """The scan table: one row per expected node and per extra node, in node id order."""
    by_id = {n.node_id: n for n in found}
    expected = {int(nid): winches.cables[k] for k, nid in enumerate(winches.node_id)}
    rows = []
    for nid in sorted(set(by_id) | set(expected)):
        n = by_id.get(nid)
        exp = None
        if nid in expected:
            exp = {"cable": expected[nid], "vendor_id": ident["vendor_id"],
                   "product_code": ident["product_code"], "revision": ident["revision"],
                   "device_type": ident["device_type"]}
        row = {"node_id": nid, "vendor_id": None, "product_code": None, "revision": None,
               "serial": None, "device_type": None, "nmt_state": None, "expected": exp}
        problems: list[str] = []
        if n is None:
            status = "missing"
            problems.append(f"node {nid} (cable {expected[nid]}) did not answer")
        else:
            row.update(vendor_id=n.vendor_id, product_code=n.product_code, revision=n.revision,
                       serial=n.serial, device_type=n.device_type, nmt_state=n.nmt_state)
            if not n.answered_sdo:
                status = "no_sdo"
                problems.append(n.error)
            elif exp is None:
                status = "extra"
                problems.append(f"node {nid} is not in the winch parameter file")
            else:
                status = "ok"
                for key, st in (("vendor_id", "wrong_vendor"), ("product_code", "wrong_product"),
                                ("device_type", "wrong_device_type"),
                                ("revision", "wrong_revision")):
                    want, got = exp[key], row[key]
                    if want is not None and got != want:
                        problems.append(f"{key} {_hex(got)}, expected {_hex(want)}")
                        if status == "ok":
                            status = st
        row["status"] = status
        row["problems"] = problems
        rows.append(row)
    return rows


def _hex(v: int | None) -> str:
    return "-" if v is None else f"0x{v:08X}"


def _units(text: str | None) -> list[int]:
    if not text:
        return []
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        try:
            lo, hi = int(a), int(b or a)
        except ValueError:
            raise CommissionError(f"--probe-units {text!r}: expected ids like 1-16,20", 2) from None
        if not (1 <= lo <= hi <= 247):
            raise CommissionError(f"--probe-units {text!r}: Modbus unit ids are 1..247", 2)
        out.extend(range(lo, hi + 1))
    return out


def loadcell_rows(args: argparse.Namespace, ui: Ui) -> list[dict]:
    """One read of every load cell of the map (and of the ``--probe-units`` outside it)."""
    from controller.cable_watch import classify_tensions
    from hal.loadcell_calibration import load_calibration
    from hal.loadcell_client import LoadCellClient

    rmap = register_map_of(args)
    cal = load_calibration(args.loadcell_calibration, rmap.cables) \
        if args.loadcell_calibration else None
    client = LoadCellClient(args.modbus, register_map=rmap, calibration=cal,
                            timeout_s=args.loadcell_timeout, stale_s=args.loadcell_stale)
    try:
        client.poll_once()
        time.sleep(max(0.05, 2.0 / max(args.loadcell_rate, 1e-3)))
        client.poll_once()  # a second read: does the counter advance?
        r = client.read()
        window = tension_window_of(args)
        rows = []
        for k, cable in enumerate(rmap.cables):
            st = r.status_of(cable)
            status = "missing" if st.name in ("TIMEOUT", "COMM_ERROR") else st.name.lower()
            msg = r.messages[k]
            if st.name == "OK":  # a valid reading outside the window is no "ok"
                status = classify_tensions([r.values_N[k]], window)[0]
                if status != "ok":
                    msg = (msg + "; " if msg else "") + f"outside the window {window}"
            rows.append({"device_id": int(rmap.unit_ids[k]), "cable": cable,
                         "tension_n": None if st.name != "OK" else float(r.values_N[k]),
                         "status": status, "message": msg, "expected": True})
        extra = [u for u in _units(args.probe_units) if u not in rmap.unit_ids]
        if extra:
            ui.progress(f"probing Modbus units {extra[0]}..{extra[-1]} outside the map "
                        f"({len(extra)} ids, up to {args.loadcell_timeout:g} s each)")
        for uid in extra:
            answered = _probe_unit(client, uid, rmap)
            if answered:
                rows.append({"device_id": uid, "cable": None, "tension_n": None,
                             "status": "extra", "message": f"Modbus unit {uid} answers but is "
                             "not in the register map", "expected": False})
        return rows
    finally:
        client.stop()


def _probe_unit(client, uid: int, rmap) -> bool:
    """Whether unit ``uid`` answers at all (registers or a Modbus exception)."""
    from pymodbus.exceptions import ModbusException

    try:
        if not client._client.connected:
            client._client.connect()
        rr = client._client.read_input_registers(rmap.block_start, count=rmap.block_count,
                                                 device_id=uid)
    except (ModbusException, OSError, ValueError):
        return False
    return rr is not None


def run(args: argparse.Namespace, ui: Ui, section: Section) -> int:
    from bench.tables import col, render
    from hal.scan import scan_nodes

    w = winches_of(args)
    section.fact("winch file", w.source)
    section.fact("EDS", args.eds)
    ident = expected_identity(args.eds)
    if not 0 < args.window <= 10:
        raise CommissionError(f"--window {args.window}: must be in (0, 10] s", 2)
    ui.progress(f"scanning node ids 1..127 on {args.can} ({args.window:g} s window) ...")
    with network_of(args) as net:
        found = scan_nodes(net, range(1, 128), window_s=args.window,
                           timeout_s=args.sdo_timeout)
    drives = drive_rows(found, w, ident)
    cells: list[dict] = []
    if args.modbus is not None:
        ui.progress(f"reading the load cells at {args.modbus} ...")
        cells = loadcell_rows(args, ui)
    bad = [d for d in drives if d["status"] != "ok"] + [c for c in cells if c["status"] != "ok"]

    ui.say(f"drives on {args.can} (expected: {w.source}, {args.eds}):")
    ui.say(render([col("node"), col("cable"), col("status", justify="left"), col("vendor"),
                   col("product"), col("revision"), col("serial"),
                   col("notes", justify="left")],
                  [[d["node_id"], d["expected"]["cable"] if d["expected"] else "-",
                    d["status"], _hex(d["vendor_id"]), _hex(d["product_code"]),
                    _hex(d["revision"]), _hex(d["serial"]), "; ".join(d["problems"])]
                   for d in drives], stream=ui.out))
    if args.modbus is not None:
        ui.say(f"load cells at {args.modbus}:")
        ui.say(render([col("unit"), col("cable"), col("status", justify="left"),
                       col("tension", "N"), col("message", justify="left")],
                      [[c["device_id"], c["cable"] or "-", c["status"],
                        "-" if c["tension_n"] is None else f"{c['tension_n']:.1f}",
                        c["message"]] for c in cells], stream=ui.out))
    else:
        ui.say("load cells: not scanned (no --modbus)")
    ui.say(f"{len(drives) - sum(d['status'] != 'ok' for d in drives)} of {len(drives)} drive "
           f"rows ok, {len(bad)} problem(s)")

    section.fact("result", f"{len(found)} node(s) answered, {len(bad)} problem(s)")
    section.table(["node", "cable", "status", "vendor", "product", "revision", "serial", "notes"],
                  [[d["node_id"], d["expected"]["cable"] if d["expected"] else "-", d["status"],
                    _hex(d["vendor_id"]), _hex(d["product_code"]), _hex(d["revision"]),
                    _hex(d["serial"]), "; ".join(d["problems"])] for d in drives])
    section.table(["unit", "cable", "status", "tension [N]", "notes"],
                  [[c["device_id"], c["cable"] or "-", c["status"],
                    "-" if c["tension_n"] is None else f"{c['tension_n']:.1f}", c["message"]]
                   for c in cells])
    ui.emit({"drives": drives, "load_cells": cells, "ok": not bad})
    return 1 if bad else 0
