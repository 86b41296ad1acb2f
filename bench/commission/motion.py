"""``cdpr commission enable|disable|jog|home WINCH``: one winch at a time.

WINCH is a cable id (``21``) or ``node:N``. Everything that can move a winch (enable, jog,
homing mode) first listens ``--listen`` seconds and refuses when another master is active
on the bus, asks for confirmation (``--yes`` skips it), then runs this process as the
drive's master (:class:`hal.motion.AxisMaster`: the HAL's configuration table, profile
position or homing mode, SYNC at the bus period). On any error, timeout or Ctrl-C the drive
is disabled (PDO, then NMT pre-operational and controlword 0 by SDO) and the state it was
left in is printed and reported.

- ``enable``: power the drive and hold its position until Enter, ``q``, the end of stdin,
  ``--duration`` or Ctrl-C; then disable.
- ``disable``: disable voltage (NMT pre-operational, controlword 0 by SDO); with
  ``--fault-reset`` a faulted drive is reset first. Never refused: it is the way out.
- ``jog``: hold ``+`` to pay cable out, ``-`` to reel it in (the terminal's key repeat keeps
  the input coming); when no key comes for ``--deadman`` seconds the winch halts, then is
  disabled; the next key enables it again. Space stops, ``q`` quits. Speed ``--speed``
  (refused beyond the winch file's ``max_speed_m_s``), travel at most ``--travel`` from where
  the jog started and never beyond ``[min_length_m, max_length_m]``; more than
  :data:`LOADED_JOG_MAX_M` only with ``--platform-supported`` (default travel
  :data:`DEFAULT_TRAVEL_M`, capped without it). ``--platform``: the Cartesian jog
  (:mod:`bench.commission.platform`).

``enable``, ``jog`` and ``home`` watch every cable (``--modbus``,
:mod:`bench.commission.watch`): all tensions are shown live, and when one leaves the
tension window, or is about to, the drive quick-stops, holds, and is disabled.
- ``home``: ``--method 35|37`` runs CiA 402 homing on the current position (the position
  becomes ``--offset`` counts); ``--length L`` references the winch: the current position
  reads L metres, i.e. ``length_at_zero_m`` of the winch parameter file is rewritten (the
  old file is kept as a timestamped backup). Both together: home, then reference. A homing
  that changed the count marks the platform reference lost (the state file of
  :mod:`bench.commission.reference`).
"""

from __future__ import annotations

import argparse
import time

from bench.commission.common import (
    CommissionError,
    Ui,
    confirm,
    guard_other_master,
    network_of,
    resolve_winch,
    sigint_deferred,
    who,
    winch_file,
    winches_of,
)
from bench.commission.keys import KeyReader, cbreak
from bench.commission.report import Section
from bench.commission.watch import horizon_s, open_guard

#: the farthest a single-winch jog may go on a loaded robot without --platform-supported [m]
LOADED_JOG_MAX_M = 0.005
#: the default single-winch jog travel [m]
DEFAULT_TRAVEL_M = 0.010


def _close_guard(guard, section: Section) -> None:
    if guard is None:
        return
    guard.close()
    sm = guard.summary()
    lo = ", ".join(f"{c} {v if v is not None else '-'}" for c, v in sm["min_n"].items())
    section.fact("lowest tensions [N]", lo)


class _Status:
    """Progress of a motion on stderr (:class:`bench.progress.Progress`): one live line on
    a terminal, else a line per phase change and every few seconds."""

    def __init__(self, label: str, guard=None) -> None:
        from bench.progress import Progress

        self.guard = guard
        self.phase = ""
        self.prog = Progress(label, None)

    def __call__(self, fb, phase: str) -> None:
        line = f"{fb.length_m:.4f} m  {phase:<10} {fb.state.name}"
        if self.guard is not None:
            line += " | " + self.guard.line()
        self.prog.update(detail=line, force=phase != self.phase)
        self.phase = phase

    def end(self) -> None:
        self.prog.close()


def _master(args, net, w, k):
    from hal.motion import AxisMaster

    return AxisMaster(net, w, k, args.eds, clock=args.hal_clock, pace=True)


def _finish(master, ui: Ui, section: Section, status: _Status | None = None) -> str:
    with sigint_deferred():
        if status is not None:
            status.end()
        state, problems = master.finish()
        master.close()
    for t, text in master.log:
        section.bullets([f"{time.strftime('%H:%M:%S', time.localtime(t))} {text}"])
    for p in problems:
        ui.progress(f"warning: {p}")
    section.json_extra["state"] = state
    section.fact("drive left", state + ("; " + "; ".join(problems) if problems else ""))
    ui.say(f"{master.who()}: left {state}")
    return state


def _prepare(args, ui: Ui, section: Section, net, w, k, what: str) -> None:
    section.fact("winch", who(w, k))
    section.fact("winch file", w.source)
    guard_other_master(net, w, args.listen, ui, section)
    confirm(args, f"{what} winch {w.cables[k]} ({who(w, k)}): it can move.", ui)


# ---------------------------------------------------------------------------- enable


def run_enable(args: argparse.Namespace, ui: Ui, section: Section) -> int:
    from hal.motion import MODE_PP, GuardStop, hold_enabled

    w = winches_of(args)
    k = resolve_winch(w, args.winch)
    if args.duration is not None and args.duration <= 0:
        raise CommissionError(f"--duration {args.duration}: must be > 0", 2)
    with network_of(args) as net:
        _prepare(args, ui, section, net, w, k, "Enable")
        guard = open_guard(args, ui, section, w.cables, horizon_s(0.0, 1.0), required=False)
        master = _master(args, net, w, k)
        status = _Status(f"winch {w.cables[k]}", guard)
        keys = KeyReader(enter_quits=True)
        reason = ""
        stop = ""
        fb0 = fb = None
        try:
            fb0 = master.start(MODE_PP)
            t_end = None if args.duration is None else master.now() + args.duration
            ui.progress(f"{master.who()}: enabled, holding position; Enter or q disables"
                        + (f" (after {args.duration:g} s at most)" if t_end else ""))
            with cbreak():
                keys.start()

                def keep(fb) -> bool:
                    nonlocal reason
                    cmd = keys.poll()
                    if cmd is not None and cmd.name == "EOF" and t_end is not None:
                        cmd = None  # no more keys: --duration ends the hold
                    if cmd is not None and cmd.name in ("QUIT", "EOF", "STOP"):
                        reason = "operator" if cmd.name != "EOF" else "input ended"
                        return False
                    if t_end is not None and master.now() >= t_end:
                        reason = f"--duration {args.duration:g} s"
                        return False
                    return True

                try:
                    fb = hold_enabled(master, keep, status, guard=guard)
                except GuardStop as exc:
                    stop = reason = str(exc)
                    fb = master.feedback()
        finally:
            state = _finish(master, ui, section, status)
            _close_guard(guard, section)
    if stop:
        ui.say(f"STOPPED by the cable watch: {stop}")
        section.fact("cable watch stop", stop)
    drift = fb.length_m - fb0.length_m
    section.fact("result", f"held at {fb0.length_m:.4f} m, moved {drift * 1e3:+.3f} mm, "
                 f"ended by {reason}")
    ui.say(f"held at {fb0.length_m:.4f} m; moved {drift * 1e3:+.3f} mm while enabled")
    ui.emit({"winch": w.cables[k], "node_id": int(w.node_id[k]), "length_m": fb.length_m,
             "moved_m": drift, "ended_by": reason, "state": state,
             "cable_watch": guard.summary() if guard else None})
    return 1 if stop else 0


# ---------------------------------------------------------------------------- disable


def run_disable(args: argparse.Namespace, ui: Ui, section: Section) -> int:
    import canopen

    from hal.drives_cia402 import DriveState, decode_states, emcy_text
    from hal.drives_config import Setting, sdo_read, sdo_write

    w = winches_of(args)
    k = resolve_winch(w, args.winch)
    nid = int(w.node_id[k])
    name = who(w, k)
    section.fact("winch", name)
    with network_of(args) as net:
        node = canopen.RemoteNode(nid, canopen.import_od(str(args.eds), nid))
        net.add_node(node)
        net.send_message(0, bytes([0x80, nid]))  # NMT pre-operational: no PDO any more
        time.sleep(0.05)

        def state_now() -> tuple[DriveState, int]:
            sw = int(sdo_read(node, 0x6041, 0, name))
            return DriveState(int(decode_states([sw])[0])), sw

        before, _ = state_now()
        code = int(sdo_read(node, 0x603F, 0, name)) if before == DriveState.FAULT else 0
        with sigint_deferred():
            if before == DriveState.FAULT and args.fault_reset:
                for cw in (0x0000, 0x0080, 0x0000):
                    sdo_write(node, Setting(0x6040, 0, cw, "controlword"), name)
                ui.progress(f"{name}: fault 0x{code:04X} ({emcy_text(code)}) reset")
                section.fact("fault reset", f"0x{code:04X} {emcy_text(code)}")
            sdo_write(node, Setting(0x6040, 0, 0x0000, "controlword (disable voltage)"), name)
            after, sw = state_now()
        code_after = int(sdo_read(node, 0x603F, 0, name)) if after == DriveState.FAULT else 0
    msg = f"{name}: {before.name} -> {after.name}"
    if code_after:
        msg += f", error code 0x{code_after:04X} {emcy_text(code_after)} (--fault-reset)"
    ui.say(msg)
    section.fact("result", msg)
    ui.emit({"winch": w.cables[k], "node_id": nid, "before": before.name, "state": after.name,
             "statusword": sw, "error_code": code_after})
    return 0 if after in (DriveState.SWITCH_ON_DISABLED, DriveState.READY_TO_SWITCH_ON,
                          DriveState.SWITCHED_ON) else 1


# ---------------------------------------------------------------------------- jog


def jog_window(w, k: int, start_m: float, travel_m: float) -> tuple[float, float]:
    """(lowest, highest) cable length [m] a jog from ``start_m`` may reach."""
    lo, hi = float(w.min_length_m[k]), float(w.max_length_m[k])
    if not lo <= start_m <= hi:
        raise CommissionError(
            f"{who(w, k)}: the cable reads {start_m:.4f} m, outside [{lo}, {hi}] m of "
            f"{w.source}: reference the winch first (cdpr commission home {w.cables[k]} "
            "--length L)")
    return max(lo, start_m - travel_m), min(hi, start_m + travel_m)


def jog_travel(args: argparse.Namespace, span_m: float) -> float:
    """The jog's travel [m]: ``--travel`` or the default; more than
    :data:`LOADED_JOG_MAX_M` only with ``--platform-supported`` (a single winch moved on a
    robot whose platform hangs from its cables slackens or overloads the others)."""
    travel = DEFAULT_TRAVEL_M if args.travel is None else args.travel
    if not 0 < travel <= span_m:
        raise CommissionError(f"--travel {travel:g} m: must be in (0, {span_m:g}] (the length "
                              "range of the cable in the winch file)", 2)
    if travel > LOADED_JOG_MAX_M and not args.platform_supported:
        if args.travel is not None:
            raise CommissionError(
                f"--travel {travel * 1e3:g} mm: a single winch moved more than "
                f"{LOADED_JOG_MAX_M * 1e3:g} mm slackens or overloads the other cables of a "
                "loaded robot; rest the platform on its stand and give --platform-supported, "
                "or jog the platform (cdpr commission jog --platform --step ...)", 2)
        travel = LOADED_JOG_MAX_M
    return travel


def run_jog(args: argparse.Namespace, ui: Ui, section: Section) -> int:
    if args.platform:
        from bench.commission.platform import run_platform_jog

        return run_platform_jog(args, ui, section)
    if args.winch is None:
        raise CommissionError("give a WINCH (cable id or node:N), or --platform for a "
                              "Cartesian jog", 2)
    from hal.motion import MODE_PP
    from hal.motion import run_jog as jog

    w = winches_of(args)
    k = resolve_winch(w, args.winch)
    ax = w.axis(k)
    speed = args.speed if args.speed is not None else min(0.05, ax.profile_speed_m_s)
    if not 0 < speed <= ax.max_speed_m_s:
        raise CommissionError(f"--speed {speed:g} m/s: must be in (0, {ax.max_speed_m_s:g}] "
                              f"(max_speed_m_s of cable {ax.cable} in {w.source})", 2)
    travel = jog_travel(args, ax.max_length_m - ax.min_length_m)
    if not 0 < args.deadman <= 5:
        raise CommissionError(f"--deadman {args.deadman:g} s: must be in (0, 5]", 2)
    guard = None
    with network_of(args) as net:
        master = _master(args, net, w, k)
        try:
            start_m = ax.counts_to_m(master.read_position())
            lo, hi = jog_window(w, k, start_m, travel)
            section.fact("jog", f"speed {speed:g} m/s, window [{lo:.4f}, {hi:.4f}] m, "
                         f"dead-man {args.deadman:g} s"
                         + (", platform supported" if args.platform_supported else ""))
            _prepare(args, ui, section, net, w, k, "Jog")
            guard = open_guard(args, ui, section, w.cables,
                               horizon_s(speed, ax.quick_stop_decel_m_s2),
                               required=not args.platform_supported)
        except BaseException:
            master.close()
            if guard is not None:
                guard.close()
            raise
        status = _Status(f"winch {w.cables[k]}", guard)
        keys = KeyReader()
        res = None
        try:
            master.start(MODE_PP)
            master.set_profile(int(round(speed / ax.metres_per_count)))
            ui.progress(f"{master.who()}: jog at {speed:g} m/s within [{lo:.4f}, {hi:.4f}] m "
                        f"(travel {travel * 1e3:g} mm). Hold + (out) or - (in); release: stop "
                        f"after {args.deadman:g} s; space stops, q quits"
                        + (f"; stops when a tension leaves {guard.window}" if guard else ""))
            with cbreak():
                keys.start()
                res = jog(master, keys.poll, int(round(ax.m_to_counts(hi))),
                          int(round(ax.m_to_counts(lo))), args.deadman, on_cycle=status,
                          guard=guard)
        finally:
            state = _finish(master, ui, section, status)
            _close_guard(guard, section)
    section.fact("result", f"from {res.start_m:.4f} m to {res.end_m:.4f} m "
                 f"(range {res.min_m:.4f}..{res.max_m:.4f} m), {res.moves} move(s), "
                 f"{res.deadman_stops} dead-man stop(s), ended by {res.reason}")
    if res.guard_stop:
        ui.say(f"STOPPED by the cable watch: {res.guard_stop}")
    ui.say(f"jog: {res.start_m:.4f} m -> {res.end_m:.4f} m, {res.deadman_stops} dead-man "
           f"stop(s), ended by {res.reason}")
    ui.emit({"winch": w.cables[k], "node_id": int(w.node_id[k]), "start_m": res.start_m,
             "end_m": res.end_m, "min_m": res.min_m, "max_m": res.max_m, "moves": res.moves,
             "deadman_stops": res.deadman_stops, "ended_by": res.reason, "state": state,
             "window_m": [lo, hi], "speed_m_s": speed, "travel_m": travel,
             "guard_stop": res.guard_stop,
             "cable_watch": guard.summary() if guard else None})
    return 1 if res.guard_stop else 0


# ---------------------------------------------------------------------------- home


def _reference_lost(args, ui: Ui, section: Section, mark_lost, state_path, cable: str,
                    method: int) -> None:
    """A homing changed a count: the platform reference is lost (said, and recorded)."""
    path = state_path(args)
    why = (f"cdpr commission home {cable} --method {method} changed the count of cable "
           f"{cable} at {time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())}")
    was = mark_lost(path, why)
    msg = ("the winches' reference is lost: the count of cable " + cable + " changed; "
           "Cartesian motion (jog --platform) is refused until `cdpr commission reference` "
           "has run again" + (f" ({path} marked referenced = false)" if was else ""))
    ui.say(msg)
    section.fact("reference", msg)


def run_home(args: argparse.Namespace, ui: Ui, section: Section) -> int:
    from bench.commission.files import set_length_at_zero
    from bench.commission.reference import mark_lost, state_path
    from hal.motion import MODE_HOMING, run_homing

    if args.method is None and args.length is None:
        raise CommissionError("give --method 35|37 (CiA 402 homing on the current position) "
                              "and/or --length L (reference: the current position reads L m)", 2)
    if args.offset and args.method is None:
        raise CommissionError("--offset needs --method", 2)
    w = winches_of(args)
    k = resolve_winch(w, args.winch)
    ax = w.axis(k)
    path = winch_file(args)
    if args.length is not None and not ax.min_length_m <= args.length <= ax.max_length_m:
        raise CommissionError(f"--length {args.length:g} m: outside [{ax.min_length_m:g}, "
                              f"{ax.max_length_m:g}] m of cable {ax.cable} in {w.source}", 2)
    out: dict = {"winch": ax.cable, "node_id": ax.node_id, "method": args.method,
                 "reference_lost": False}
    with network_of(args) as net:
        master = _master(args, net, w, k)
        try:
            before = master.read_position()
        except BaseException:
            master.close()
            raise
        out["position_before_counts"] = before
        out["position_before_m"] = float(ax.counts_to_m(before))
        section.fact("position before", f"{before} counts = {ax.counts_to_m(before):.4f} m")
        after = before
        if args.method is not None:
            try:
                _prepare(args, ui, section, net, w, k, f"Home (method {args.method})")
            except BaseException:
                master.close()
                raise
            guard = None
            started = done = False
            try:
                guard = open_guard(args, ui, section, w.cables, horizon_s(0.0, 1.0),
                                   required=False)
                master.start(MODE_HOMING)
                master.set_homing(args.method, args.offset)
                started = True
                fb = run_homing(master, guard=guard)
                after = fb.position_counts
                done = True
            finally:
                state = _finish(master, ui, section)
                _close_guard(guard, section)
                if started and (not done or after != before):  # the count may have moved
                    _reference_lost(args, ui, section, mark_lost, state_path, ax.cable,
                                    args.method)
                    out["reference_lost"] = True
            out["state"] = state
            ui.say(f"{who(w, k)}: homed (method {args.method}): reading "
                   f"{ax.counts_to_m(before):.4f} m ({before} counts) -> "
                   f"{ax.counts_to_m(after):.4f} m ({after} counts)")
            section.fact("homing", f"method {args.method}, offset {args.offset}: position "
                         f"{before} -> {after} counts")
        else:
            master.close()
    out["position_after_counts"] = after
    out["position_after_m"] = float(ax.counts_to_m(after))
    if args.length is not None:
        l0_old = ax.length_at_zero_m
        l0 = float(args.length - ax.direction * after * ax.metres_per_count)
        if args.method is None:
            confirm(args, f"Reference cable {ax.cable}: position {after} counts reads "
                    f"{args.length:g} m (length_at_zero_m {l0_old!r} -> {l0!r} in {path})?", ui)
        w2, saved = set_length_at_zero(path, ax.cable, l0)
        check = w2.axis(k).counts_to_m(after)
        out.update(length_m=check, length_at_zero_m_old=l0_old, length_at_zero_m=l0,
                   winch_file=str(path), backup=str(saved) if saved else None)
        ui.say(f"cable {ax.cable}: length_at_zero_m {l0_old!r} -> {l0!r} written to {path}"
               + (f" (old file kept as {saved})" if saved else ""))
        ui.say("the drive's software position limits (0x607D) follow from it: the HAL writes "
               "them at start; `cdpr commission check --apply` stores them in the drive")
        section.fact("referencing", f"position {after} counts = {args.length:g} m: "
                     f"length_at_zero_m {l0_old!r} -> {l0!r} in {path}"
                     + (f", backup {saved}" if saved else ""))
    ui.emit(out)
    return 0
