"""``cdpr commission check``: each drive's parameters against the HAL's configuration table.

The table is the one the HAL writes at every start (:func:`hal.drives_config.drive_settings`
from the EDS and the winch parameter file): communication (SYNC, heartbeat, master-loss
objects), PDO mapping, mode, interpolation period, following error, limits, ramps,
quick-stop and fault-reaction options. ``check`` reads each object by SDO (the values in
the drive's RAM) and lists every difference; it never writes without ``--apply``.

``--apply`` (after confirmation, refused while another master is active or a drive is
enabled) writes the table with the HAL's own sequence, reads it back, stores it in the
drive (0x1010 "save") and checks again. ``--dcf DIR`` writes each drive's configuration as
``DIR/node<N>_cable<C>.dcf`` (after ``--apply`` when both are given).

Safety failures: a difference on an object that decides whether a drive stops when its
master dies (consumer heartbeat 0x1016, producer heartbeat 0x1017, error behaviour
0x1029, RPDO deadline 0x1400:5, abort connection 0x6007, quick stop 0x605A, fault
reaction 0x605E; :data:`hal.drives_config.SAFETY_OBJECTS`) is also listed under
``safety_failures`` with the safe value (the table's) and why the drive's value is unsafe.

Exit status: 0 when every drive matches (after ``--apply``: when the writes fixed
everything), 1 when a difference (a safety failure among them) remains or a drive could
not be read.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bench.commission.common import (
    CommissionError,
    Ui,
    confirm,
    guard_other_master,
    network_of,
    resolve_winch,
    who,
    winches_of,
)
from bench.commission.report import Section
from bench.commission.values import annotate, describe


def _check_nodes(net, w, ks, eds, ui: Ui) -> tuple[list[dict], dict]:
    import canopen

    from hal.drives_config import DriveConfigError, drive_settings, verify_identity
    from hal.sdo_config import compare_configuration

    out, nodes = [], {}
    for k in ks:
        nid = int(w.node_id[k])
        name = who(w, k)
        node = nodes.get(nid)
        if node is None:
            node = canopen.RemoteNode(nid, canopen.import_od(str(eds), nid))
            node.sdo.RESPONSE_TIMEOUT = 0.3
            net.add_node(node)
            nodes[nid] = node
        entry: dict = {"node_id": nid, "cable": w.cables[k], "differences": []}
        try:
            verify_identity(node, name)
            settings = drive_settings(w, k, node.object_dictionary)
            diffs = compare_configuration(node, settings, name)
            entry["differences"] = [annotate(d.as_dict(), d.index, w, k) for d in diffs]
            entry["safety_failures"] = _safety_failures(diffs, w, k)
            entry["objects"] = len({(s.index, s.subindex) for s in settings if s.verify})
            ui.progress(f"  {name}: {len(diffs)} difference(s) in {entry['objects']} objects")
        except DriveConfigError as exc:
            entry["error"] = str(exc)
            ui.progress(f"  {name}: {exc}")
        out.append(entry)
    return out, nodes


def _safety_failures(diffs, w, k: int) -> list[dict]:
    """The differences on objects that decide whether the drive stops when its master dies
    (:data:`hal.drives_config.SAFETY_OBJECTS`): object, name, the drive's value, the safe
    value (the table's) and why the drive's value is unsafe."""
    from hal.drives_config import safety_failure

    out = []
    for d in diffs:
        why = safety_failure(d.index, d.subindex, d.expected, d.actual)
        if why is not None:
            out.append({"object": f"0x{d.index:04X}:{d.subindex:02X}", "name": d.name,
                        "actual": d.actual, "safe_value": d.expected,
                        "actual_text": describe(d.index, d.subindex, d.actual, w, k)[0],
                        "safe_text": describe(d.index, d.subindex, d.expected, w, k)[0],
                        "why": why})
    return out


def _print(ui: Ui, results: list[dict]) -> None:
    for r in results:
        head = f"node {r['node_id']} (cable {r['cable']})"
        if "error" in r:
            ui.say(f"{head}: NOT CHECKED: {r['error']}")
        elif not r["differences"]:
            ui.say(f"{head}: matches the configuration ({r.get('objects', 0)} objects)")
        else:
            ui.say(f"{head}: {len(r['differences'])} difference(s)")
            for f in r.get("safety_failures", []):
                ui.say(f"    SAFETY FAILURE {f['object']} {f['name']}: drive has "
                       f"{f['actual_text']}, safe value {f['safe_text']}: {f['why']}")
            for d in r["differences"]:
                ui.say(f"    {d['index']}:{d['subindex']:02X} {d['name']}: expected "
                       f"{d['expected_text']}, drive has {d['actual_text']}")


def _table(section: Section, results: list[dict], title: str) -> None:
    section.text(title)
    rows = []
    for r in results:
        if "error" in r:
            rows.append([r["node_id"], r["cable"], "-", "not checked", "", r["error"]])
        for d in r["differences"]:
            rows.append([r["node_id"], r["cable"], f"{d['index']}:{d['subindex']:02X}",
                         d["name"], d["expected_text"], d["actual_text"]])
    safety = [[r["node_id"], r["cable"], f["object"], f["name"], f["safe_text"],
               f["actual_text"], f["why"]] for r in results for f in r.get("safety_failures", [])]
    if safety:
        section.text("Safety failures (the drive would not stop safely when the master is "
                     "lost):")
        section.table(["node", "cable", "object", "name", "safe value", "actual", "why"],
                      safety)
    if rows:
        section.table(["node", "cable", "object", "name", "expected", "actual"], rows)
    else:
        section.text("Every drive matches the configuration.")


def run(args: argparse.Namespace, ui: Ui, section: Section) -> int:
    from hal.drives_cia402 import DriveState, decode_states
    from hal.drives_config import DriveConfigError, drive_settings, sdo_read
    from hal.sdo_config import apply_configuration, export_dcf

    w = winches_of(args)
    section.fact("winch file", w.source)
    section.fact("EDS", args.eds)
    ks = [resolve_winch(w, x) for x in args.winch] if args.winch else list(range(len(w)))
    with network_of(args) as net:
        ui.progress(f"checking {len(ks)} drive(s) against the HAL table ({w.source}, "
                    f"{args.eds}) ...")
        results, nodes = _check_nodes(net, w, ks, args.eds, ui)
        _table(section, results, "Differences found:")
        applied: list[int] = []
        if args.apply and any(r["differences"] for r in results):
            todo = [r for r in results if r["differences"] and "error" not in r]
            guard_other_master(net, w, args.listen, ui, section)
            for r in todo:  # never reconfigure a drive with its power stage on
                node = nodes[r["node_id"]]
                name = f"node {r['node_id']} (cable {r['cable']})"
                sw = int(sdo_read(node, 0x6041, 0, name))
                state = DriveState(int(decode_states([sw])[0]))
                if state in (DriveState.OPERATION_ENABLED, DriveState.QUICK_STOP_ACTIVE):
                    raise CommissionError(f"{name} is {state.name}: disable it before --apply")
            n = sum(len(r["differences"]) for r in todo)
            _print(ui, results)
            confirm(args, f"Write {n} object(s) to {len(todo)} drive(s) and store them "
                    "(0x1010)?", ui)
            for r in todo:
                k = w.index_of_node(r["node_id"])
                node = nodes[r["node_id"]]
                name = who(w, k)
                ui.progress(f"  {name}: writing the table and storing it ...")
                apply_configuration(node, drive_settings(w, k, node.object_dictionary), name,
                                    store=not args.no_store)
                applied.append(r["node_id"])
            section.fact("applied", f"nodes {applied}" + (" (not stored: --no-store)"
                                                          if args.no_store else
                                                          ", stored with 0x1010"))
            before = results
            results, nodes = _check_nodes(net, w, ks, args.eds, ui)
            _table(section, results, "After --apply:")
            ui.say(f"written{'' if args.no_store else ' and stored'}: nodes {applied}; "
                   f"{sum(len(r['differences']) for r in before)} difference(s) before, "
                   f"{sum(len(r['differences']) for r in results)} now")
            if args.no_store and any(r.get("safety_failures") for r in before):
                ui.say("NOT STORED (--no-store): the safety values written return to the "
                       "drives' power-on values at their next power cycle or node reset")
        dcf = []
        if args.dcf:
            d = Path(args.dcf)
            for r in results:
                if "error" in r:
                    continue
                k = w.index_of_node(r["node_id"])
                path = d / f"node{r['node_id']}_cable{w.cables[k]}.dcf"
                try:
                    p, failed = export_dcf(nodes[r["node_id"]], path, who(w, k))
                except DriveConfigError as exc:
                    r["dcf_error"] = str(exc)
                    continue
                r["dcf"] = str(p)
                dcf.append(str(p))
                if failed:
                    r["dcf_unread"] = failed
            ui.say(f"DCF: {len(dcf)} file(s) in {d}")
            section.fact("DCF files", ", ".join(dcf) or "none")
    _print(ui, results)
    n_diff = sum(len(r["differences"]) for r in results)
    n_err = sum("error" in r for r in results)
    n_safety = sum(len(r.get("safety_failures", [])) for r in results)
    section.fact("result", f"{n_diff} difference(s), {n_safety} safety failure(s), {n_err} "
                 "drive(s) not checked")
    if n_safety:
        ui.say(f"SAFETY FAILURE: {n_safety} object(s) on "
               f"{sum(bool(r.get('safety_failures')) for r in results)} drive(s) would let a "
               "drive keep moving (or drop its load) when the master is lost; `check "
               "--apply` writes and stores (0x1010) the safe values")
    ui.emit({"drives": results, "applied": applied, "dcf": dcf,
             "safety_failures": n_safety, "ok": n_diff == 0 and n_err == 0})
    return 0 if n_diff == 0 and n_err == 0 else 1
