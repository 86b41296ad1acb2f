"""The read-only checks of a dry run on given buses, before anything moves.

Two stages, both read-only:

1. :func:`check_drives`, before the HAL opens the bus (on a connection of its own, closed
   again): every drive of the winch file answers with the identity the EDS describes
   (``cdpr commission scan``'s :func:`~bench.commission.scan.drive_rows`), no other master
   is heard (``cdpr commission check``'s listening, :func:`hal.scan.other_master_activity`),
   and the safety parameters each drive holds before this master configures it (consumer
   heartbeat 0x1016, abort connection option 0x6007, quick-stop option 0x605A; after a
   power cycle the stored ones) are the HAL's configuration table's
   (:func:`hal.drives_config.drive_settings`, compared as ``commission check`` does). The
   HAL writes and reads back that table at every start, so a value that differs only
   matters without this master (after a power cycle, for another tool): a problem when
   the site says ``require_stored_safety``, else a warning.
2. :func:`check_readings`, after the HAL started (drives configured, NMT operational,
   disabled) and before the path is checked: every load cell answers, every tension lies
   in the site's window [N], the tracker is locked (a fresh valid fix).

A :class:`Preflight` lists problems (the run is refused) and warnings (said, the run goes
on). No ``firmware_sim`` here: this is the hardware path.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from controller.winch import WinchSet

#: the safety objects compared with the configuration table (index: what it guards)
SAFETY_OBJECTS = {0x1016: "consumer heartbeat (the master watched)",
                  0x6007: "abort connection option (reaction to a lost master)",
                  0x605A: "quick stop option"}


@dataclass
class Preflight:
    """What the checks found: ``problems`` refuse the run, ``warnings`` do not."""

    problems: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    drives: list[dict] = field(default_factory=list)
    safety: list[dict] = field(default_factory=list)
    load_cells: list[dict] = field(default_factory=list)
    tracker: dict | None = None
    other_master: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems

    def as_dict(self) -> dict:
        return {"ok": self.ok, "problems": list(self.problems),
                "warnings": list(self.warnings), "drives": self.drives,
                "safety": self.safety, "load_cells": self.load_cells,
                "tracker": self.tracker, "other_master": self.other_master}


def preflight_text(pf: Preflight) -> list[str]:
    """The operator's lines of the checks: the counts found ok, then each problem and
    warning."""
    lines = [f"preflight: {'ok' if pf.ok else 'REFUSED'}: "
             f"{sum(d['status'] == 'ok' for d in pf.drives)}/{len(pf.drives)} drives, "
             f"{sum(c['status'] == 'ok' for c in pf.load_cells)}/{len(pf.load_cells)} "
             f"load cells, tracker "
             f"{'locked' if (pf.tracker or {}).get('locked') else 'not locked'}"]
    lines += [f"preflight: problem: {p}" for p in pf.problems]
    lines += [f"preflight: warning: {w}" for w in pf.warnings]
    return lines


def check_drives(can, winches: WinchSet, eds: str | Path, window_s: float = 0.3,
                 sdo_timeout_s: float = 0.3, require_stored_safety: bool = True,
                 out: Preflight | None = None) -> Preflight:
    """Stage 1 (see the module docstring) on the bus ``can`` (a ``--can`` spec)."""
    from bench.commission.scan import drive_rows, expected_identity
    from hal.can_bus import connected_network
    from hal.scan import other_master_activity, scan_nodes

    pf = out if out is not None else Preflight()
    ids = [int(x) for x in winches.node_id]
    with connected_network(can) as net:
        found = scan_nodes(net, ids, window_s=window_s, timeout_s=sdo_timeout_s)
        pf.drives = drive_rows(found, winches, expected_identity(str(eds)))
        for row in pf.drives:
            if row["status"] != "ok":
                pf.problems.append(f"drive node {row['node_id']}: {row['status']}: "
                                   f"{'; '.join(row['problems'])}")
        master = getattr(winches.bus, "master_node_id", None)
        pf.other_master = other_master_activity(net, window_s, ids,
                                                (int(master),) if master else ())
        if pf.other_master:
            pf.problems.append(f"another master is active on the bus (heard in {window_s:g} "
                               f"s: {'; '.join(pf.other_master)}): stop it first")
        ok_ids = {r["node_id"] for r in pf.drives if r["status"] == "ok"}
        for k, nid in enumerate(ids):
            if nid in ok_ids:
                _check_safety(net, winches, k, eds, sdo_timeout_s, require_stored_safety, pf)
    return pf


def _check_safety(net, w: WinchSet, k: int, eds, timeout_s: float, required: bool,
                  pf: Preflight) -> None:
    """Compare the stored safety objects of winch ``k`` with the HAL's table."""
    import canopen

    from hal.drives_config import DriveConfigError, drive_settings
    from hal.sdo_config import compare_configuration

    nid = int(w.node_id[k])
    who = f"node {nid} (cable {w.cables[k]})"
    node = canopen.RemoteNode(nid, canopen.import_od(str(eds), nid))
    node.sdo.RESPONSE_TIMEOUT = timeout_s
    net.add_node(node)
    try:
        settings = [s for s in drive_settings(w, k, node.object_dictionary)
                    if s.index in SAFETY_OBJECTS]
        diffs = compare_configuration(node, settings, who)
    except DriveConfigError as exc:
        pf.problems.append(f"{who}: safety parameters not readable: {exc}")
        return
    finally:
        del net[nid]
    for d in diffs:
        entry = {"node_id": nid, "cable": w.cables[k], **d.as_dict()}
        pf.safety.append(entry)
        text = (f"{who}: {d} ({SAFETY_OBJECTS[d.index]}) before this master configured "
                "it: the HAL writes it at start; `cdpr commission check --apply` stores it "
                "in the drive")
        (pf.problems if required else pf.warnings).append(text)


def check_readings(hw, tracker, tension_window_N: tuple[float, float] | None,
                   require_tracker: bool = True, fresh_s: float = 2.0,
                   out: Preflight | None = None) -> Preflight:
    """Stage 2 (see the module docstring): ``hw`` a started
    :class:`hal.interface.WinchHardware`, ``tracker`` a started tracker (or None)."""
    from hal.loadcell_client import CableStatus

    pf = out if out is not None else Preflight()
    hw.sample_tensions()
    r = hw.read()
    lo, hi = tension_window_N if tension_window_N is not None else (-np.inf, np.inf)
    for k, cable in enumerate(r.cables):
        st = CableStatus(int(r.tension_status[k]))
        tau = float(r.tensions_N[k])
        row = {"cable": cable, "unit_id": int(hw.unit_ids[k]), "status": st.name.lower(),
               "tension_n": tau if st is CableStatus.OK else None}
        if st is not CableStatus.OK:
            pf.problems.append(f"load cell Modbus unit {hw.unit_ids[k]} (cable {cable}): "
                               f"{st.name.lower()}")
        elif not lo <= tau <= hi:
            row["status"] = "slack" if tau < lo else "overload"
            pf.problems.append(f"cable {cable}: tension {tau:.1f} N outside the site's window "
                               f"[{lo:g}, {hi:g}] N ({row['status']})")
        pf.load_cells.append(row)
    if tracker is None:
        pf.tracker = {"locked": False, "why": "no tracker"}
        if require_tracker:
            pf.problems.append("no tracker: the site requires one (tracker endpoint)")
        return pf
    rd = tracker.wait_fresh(fresh_s)
    locked = bool(rd.valid) and bool(np.all(np.isfinite(rd.pose)))
    pf.tracker = {"locked": locked, "age_s": float(rd.age_s),
                  "pose": [float(v) for v in rd.pose] if locked else None}
    if not locked:
        (pf.problems if require_tracker else pf.warnings).append(
            f"tracker not locked: no valid fix within {fresh_s:g} s")
    return pf


__all__ = ["SAFETY_OBJECTS", "Preflight", "check_drives", "check_readings"]
