"""The control cycle of the winch drives' master (:class:`hal.drives.WinchDrives`): what
arrived is checked (TPDO deadline, heartbeats, another master), the CiA 402 states are
updated, RPDOs and SYNC go out; and the blocking cycles (lock-step waits, enabling,
shutdown).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import can
import numpy as np

from hal.bus_watch import (
    DRIVE_LOST,
    FOREIGN_MASTER,
    feedback_lost,
)
from hal.can_bus import send_frames
from hal.drives_base import (
    _ENABLE_RANK,
    CODE_HEARTBEAT,
    CODE_PDO_TIMEOUT,
    FOREIGN_HOLD_S,
    MISSING_WAIT_S,
    NMT_OPERATIONAL,
    BusLinkError,
    DriveLostError,
    DriveStartupError,
)
from hal.drives_cia402 import (
    CW_FAULT_RESET,
    RQ,
    ST,
    SW_INTERNAL_LIMIT,
    DriveState,
    controlwords,
    decode_states,
    emcy_text,
    enabling,
    faulted,
)
from hal.sync_count import common_sample

if TYPE_CHECKING:
    from hal.drives import WinchDrives


class CycleMixin:
    """The cycle: receive, state machine, transmit; lock-step and enabling (a part of
    :class:`hal.drives.WinchDrives`)."""

    # --------------------------------------------- receive and detection

    def _expected(self) -> np.ndarray:
        """Drives that owe a TPDO per SYNC (started by us, operational as far as we know,
        not lost)."""
        op = (self._nmt == NMT_OPERATIONAL) | (self._nmt == -1)
        return (self._started & self._armed & ~self._rebooted & ~self._hb_lost & ~self._relink
                & ~self._lost & op)

    def exchange(self) -> None:
        """One control cycle: process what arrived, run the state machine, send RPDOs + SYNC.

        Never blocks (no SDO, no sleep). Same as :meth:`receive` then :meth:`transmit`.
        """
        self.receive()
        self.transmit()

    def receive(self) -> None:
        """First half of a cycle: process the TPDOs, heartbeats and EMCYs that arrived since
        the last call (positions, states, detection). Never blocks. Call once per cycle,
        before :meth:`transmit` (a TPDO is expected per SYNC sent)."""
        self._window_mark = [len(w) for w in self._window]
        self._drain()
        self._check_link()
        with self._rx:
            counts = self._rx_count.copy()
            sw = self._rx_sw.copy()
            pos = self._rx_pos.copy()
            pos_t = self._rx_sync_t.copy()
        fresh = counts > self._seen
        n_new = counts - self._seen
        self._seen = counts
        # an answer is owed per SYNC sent since the last receive (none: nothing is missing)
        expected = self._expected() if self._syncs != self._syncs_seen else self._no_one
        self._syncs_seen = self._syncs
        self._check_pdos(fresh, n_new, expected)
        self._sw = np.where(fresh, sw, self._sw)
        self._pos = np.where(fresh, pos, self._pos)
        self._pos_t = np.where(fresh, pos_t, self._pos_t)
        self._take_sample()
        # a node its heartbeat says is outside OPERATIONAL sends no PDO: a TPDO counted now
        # was sent before it left (its statusword is old news)
        out_of_op = (self._nmt != NMT_OPERATIONAL) & (self._nmt != -1)
        self._heartbeats_back()
        # the state is known only from fresh feedback of a node that is not lost: while its
        # heartbeat is lost it is UNKNOWN every cycle, whatever TPDOs still come (the node
        # needs recover() or its heartbeat back); a drive_lost node has no fresh TPDO
        self._have |= fresh & ~self._relink & ~out_of_op & ~self._hb_lost
        self._nmt_wait[fresh] = -np.inf  # PDOs only flow in OPERATIONAL
        self._check_feedback(fresh, expected)
        self._update_states(expected)
        self._check_heartbeats()
        self._check_foreign()

    def _take_sample(self) -> None:
        """The drives' positions at one SYNC (:meth:`WinchDrives.positions_sample`); the
        kept positions are read only where the latest ones answer different SYNCs."""
        t = self._pos_t[np.isfinite(self._pos_t)]
        if not t.size or t.min() == t.max():
            self._sample_pos = self._pos.astype(float)
            self._sample_t = float(t[0]) if t.size else np.nan
            return
        with self._rx:
            kept_t, kept_pos = self._rx_kept_t.copy(), self._rx_kept_pos.copy()
        self._sample_pos, self._sample_t = common_sample(
            self._pos_t, self._pos.astype(float), kept_t, kept_pos.astype(float),
            self._deadline_s)

    def _check_feedback(self, fresh: np.ndarray, expected: np.ndarray) -> None:
        """TPDO deadline: a drive silent for the deadline is lost (state unknown, asked to
        quick stop); its TPDOs back end it."""
        now = self._clock()
        if np.count_nonzero(fresh):
            self._last_tpdo_t[fresh] = now
        back = self._lost & fresh
        for k in np.flatnonzero(back) if np.count_nonzero(back) else ():
            self._lost[k] = False
            self._event(k, "tpdo_resumed", CODE_PDO_TIMEOUT, "TPDOs back: state known again")
        if not np.count_nonzero(self._miss_streak):
            return
        lost = feedback_lost(np.where(expected, self._miss_streak, 0), now - self._last_tpdo_t,
                             self.tpdo_deadline_cycles, self.tpdo_deadline_min_s)
        for k in np.flatnonzero(lost) if np.count_nonzero(lost) else ():
            self._lost[k] = True
            self._have[k] = False  # its state is unknown now, never its last live one
            # its TPDOs lost for the deadline: its count no longer matches the SYNCs (the
            # offset kept would stamp its answers the gap early), a new stream when back
            self._align[k].restart()
            self._setpoint_ok[k] = False
            self._request[k] = RQ.QUICK_STOP  # hold, if it still hears us
            self._event(k, DRIVE_LOST, CODE_PDO_TIMEOUT, self._lost_text(k, now))

    def _lost_text(self, k: int, now: float) -> str:
        return (f"no TPDO for {self._miss_streak[k]} SYNCs ({now - self._last_tpdo_t[k]:.3f} "
                f"s; deadline {self.tpdo_deadline_cycles} SYNCs and "
                f"{self.tpdo_deadline_min_s:.3f} s): state unknown")

    def _check_foreign(self) -> None:
        """Frames another master sent (queued by :attr:`foreign`): an event when the
        condition starts, a fault while it lasts."""
        frames = self.foreign.take()
        if not frames:
            return
        now = self._clock()
        for f in frames:
            if f.node_id in self.node_ids:
                k = self.node_ids.index(f.node_id)
                if now > self._foreign_until[k]:
                    self._event(k, FOREIGN_MASTER, 0, f"{f.text} (another master on the bus)")
                self._foreign_until[k] = now + FOREIGN_HOLD_S
                self._foreign_text[k] = f.text
            else:
                if now > self._foreign_bus_until:
                    self._bus_event(f"{f.text} (another master on the bus)", FOREIGN_MASTER, 0)
                self._foreign_bus_until = now + FOREIGN_HOLD_S
                self._foreign_bus_text = f.text

    def _check_pdos(self, fresh: np.ndarray, n_new: np.ndarray, expected: np.ndarray) -> None:
        if (np.count_nonzero(fresh) == fresh.size and not np.count_nonzero(self._miss_streak)
                and not np.count_nonzero(n_new > 1)):
            return  # every drive answered once, none was missing: nothing to report
        for k in np.flatnonzero(expected & ~fresh):
            if self._miss_streak[k] == 0:
                self._event(k, "tpdo_missing", CODE_PDO_TIMEOUT,
                            f"no TPDO for SYNC {self._syncs}")
            self._miss_streak[k] += 1
        for k in np.flatnonzero(fresh & (self._miss_streak > 0)):
            if self._miss_streak[k] > 1:
                self._event(k, "tpdo_missing", CODE_PDO_TIMEOUT,
                            f"TPDOs back after {self._miss_streak[k]} missed SYNCs")
            self._miss_streak[k] = 0
        for k in np.flatnonzero(expected & (n_new > 1)):
            self._event(k, "tpdo_late", CODE_PDO_TIMEOUT,
                        f"{n_new[k]} TPDOs in one cycle: one arrived late")

    def _heartbeats_back(self) -> None:
        """Heartbeats of lost nodes that came again (``heartbeat_resumed``): their TPDOs of
        this cycle give their state again."""
        if self.hb_timeout_s <= 0 or self._link_down:
            return
        now = self._clock()
        self._hb_last = np.maximum(self._hb_last, self._rx_hb_t)
        back = self._hb_lost & (now - self._hb_last <= self.hb_timeout_s + 1e-9)
        for k in np.flatnonzero(back) if np.count_nonzero(back) else ():
            self._hb_lost[k] = False
            self._event(k, "heartbeat_resumed", CODE_HEARTBEAT, "heartbeat back")

    def _check_heartbeats(self) -> None:
        """Nodes silent beyond the heartbeat timeout: ``heartbeat_lost``, state UNKNOWN from
        this cycle on until the heartbeat is back (or :meth:`recover`)."""
        if self.hb_timeout_s <= 0 or self._link_down:
            return
        now = self._clock()
        self._hb_last = np.maximum(self._hb_last, self._rx_hb_t)
        watched = self._started & ~self._rebooted & ~self._relink
        lost = watched & ~self._hb_lost & (now - self._hb_last > self.hb_timeout_s + 1e-9)
        for k in np.flatnonzero(lost) if np.count_nonzero(lost) else ():
            self._hb_lost[k] = True
            self._have[k] = False  # its state is unknown now
            self._states[k] = ST.UNKNOWN
            self._setpoint_ok[k] = False
            self._request[k] = RQ.QUICK_STOP  # hold, if it still hears us
            self._event(k, "heartbeat_lost", CODE_HEARTBEAT,
                        f"no heartbeat for {now - self._hb_last[k]:.3f} s "
                        f"(> {self.winches.bus.heartbeat_misses} periods)")

    # ---------------------------------------------------- CiA 402 states

    def _cause(self, k: int) -> int:
        """The EMCY that came with drive ``k``'s transition to Fault: of the EMCYs since it
        was last seen not faulted, the first that is not a communication warning (0x81xx,
        0x82xx), else the first; 0 if none came."""
        codes = self._window[k]
        for code in codes:
            if code >> 8 not in (0x81, 0x82):
                return code
        return codes[0] if codes else 0

    def _update_states(self, expected: np.ndarray) -> None:
        old = self._states
        new = decode_states(self._sw, self._have)
        was_fault = faulted(old)
        now_fault = faulted(new)
        any_fault = bool(np.count_nonzero(was_fault) or np.count_nonzero(now_fault))
        for k in np.flatnonzero(now_fault & ~was_fault) if any_fault else ():
            code = self._cause(k)
            self._fault_code[k] = code
            text = emcy_text(code) if code else "fault without EMCY (read 0x603F)"
            self._event(k, "fault", code, f"{DriveState(new[k]).name}: {text}")
            self._request[k] = RQ.DISABLE
            self._confirm_fault_code(int(k))
        cleared = ~now_fault & was_fault & (new != ST.UNKNOWN) if any_fault else ()
        for k in np.flatnonzero(cleared) if any_fault else ():
            self._event(k, "fault_cleared", 0, f"now {DriveState(new[k]).name}")
            self._fault_code[k] = 0
        known_ok = ~now_fault & (new != ST.UNKNOWN)
        for k in np.flatnonzero(known_ok) if any(self._window_mark) else ():
            del self._window[k][:self._window_mark[k]]
        # a drive that quick-stopped on its own (master lost, 0x6007) holds there until the
        # controller enables it again: the master never re-enables it by itself
        qs = new == ST.QUICK_STOP_ACTIVE
        for k in np.flatnonzero(qs & (old != ST.QUICK_STOP_ACTIVE)
                                & (self._request != RQ.QUICK_STOP)) if np.count_nonzero(qs) else ():
            self._self_stopped[k] = True
            self._request[k] = RQ.QUICK_STOP
            code = next((c for c in reversed(self._window[k]) if c), int(self._code[k]))
            why = emcy_text(code) if code else "no EMCY"
            self._event(k, "quick_stop", code, f"the drive stopped on its own ({why}): held in "
                        "Quick Stop Active until enable()")
        self._self_stopped &= qs | (new == ST.UNKNOWN)
        self._drop_enable(old, new)
        oe = new == ST.OPERATION_ENABLED
        entering = oe & ~self._setpoint_ok
        self._target[entering] = self._pos[entering]  # hold where it stands
        self._setpoint_ok = oe
        limit = oe & ((self._sw & SW_INTERNAL_LIMIT) != 0)
        for k in np.flatnonzero(limit & ~self._limit) if np.count_nonzero(limit) else ():
            self._event(k, "internal_limit", 0, "software position limit reached (bit 11)")
        self._limit = limit
        self._states = new

    def _drop_enable(self, old: np.ndarray, new: np.ndarray) -> None:
        """A drive asked to be enabled that went back along the enable path (Operation
        Enabled -> Switched On -> Ready To Switch On -> Switch On Disabled) without the master
        asking: switched off by another master (an SDO write of 0x6040) or by itself. The
        master stops asking (never enables it again by itself, until :meth:`enable`) and
        leaves it where it is: an event ``switched_off``."""
        back = (self._request == RQ.ENABLE) & (_ENABLE_RANK[new] >= 0) & (
            _ENABLE_RANK[new] < _ENABLE_RANK[old])
        for k in np.flatnonzero(back) if np.count_nonzero(back) else ():
            off = new[k] in (ST.SWITCH_ON_DISABLED, ST.NOT_READY_TO_SWITCH_ON)
            self._request[k] = RQ.OFF if off else RQ.DISABLE
            self._event(k, "switched_off", 0, f"{DriveState(old[k]).name} -> "
                        f"{DriveState(new[k]).name} without the master asking (another master? "
                        "the drive itself?): not enabled again until enable()")

    # ---------------------------------------------------------- transmit

    def transmit(self) -> None:
        """Second half of a cycle: state machine requests, RPDOs (setpoints) + SYNC out.
        Never blocks."""
        self._send_outputs()
        self._cycle_heartbeat()
        self.cycle += 1

    def _note_sync_sent(self) -> None:
        """Keep the wall time (``time.time()``, the frames' time stamps' clock) at which the
        SYNC of master clock ``_sync_t`` goes out, taken just before it is written (after
        the RPDOs): a TPDO stamped before it answers an earlier SYNC
        (:meth:`ReceiveMixin._sync_answered`)."""
        self._sync_sent.note(time.time(), self._sync_t)

    def _restart_counts(self) -> None:
        """Every drive's count of TPDOs anew (:meth:`hal.sync_count.CountAlignment.restart`):
        a SYNC kept in the history that the drives may not have received (its send failed)
        breaks the count as a lost TPDO does, and would stamp every later answer a period
        early for the count window."""
        for align in self._align:
            align.restart()

    def _send_outputs(self) -> None:
        states = self._states
        cw = controlwords(states, self._request).astype(np.int64)
        # fault reset: bit 7 low for one cycle, then high while the drive is in Fault
        resetting = self._reset_left > 0
        if np.count_nonzero(resetting):
            cw = np.where(resetting & ((self._last_cw & CW_FAULT_RESET) == 0) & faulted(states),
                          CW_FAULT_RESET, cw)
            hold = resetting & ((self._last_cw & CW_FAULT_RESET) != 0) & faulted(states)
            cw = np.where(hold, CW_FAULT_RESET, cw)
            done = resetting & ~faulted(states)
            self._reset_left[done] = 0
            self._reset_left[resetting & ~done] -= 1
            for k in np.flatnonzero(resetting & ~done & (self._reset_left == 0)):
                self._event(k, "fault_reset_failed", int(self._fault_code[k]),
                            "still in Fault after the reset edge (cause persists?)")
        # a drive not enabled, or being enabled now, gets its actual position as target
        going = enabling(states, cw)
        target = np.where(self._setpoint_ok & ~going, self._target, self._pos)
        self._target = target
        self._last_cw = cw
        send = self._started & ~self._rebooted & ~self._relink
        if self._link_down or not self.link_up():
            self._syncs += 1  # the cycle happened; nothing can go out (see _check_link)
            return
        pack = self._rpdo.pack
        cws, targets, ids = cw.tolist(), target.tolist(), self.node_ids  # plain ints
        rpdos = [can.Message(arbitration_id=0x200 + ids[k], data=pack(cws[k], targets[k]),
                             is_extended_id=False) for k in np.flatnonzero(send).tolist()]
        sync = can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)
        bus = self.network.bus
        # the SYNC's time, before it goes (its answers may come within send); a clock that
        # counts SYNCs moves by one period as it is sent
        self._sync_t = ((self._syncs + 1) * self.period_s if self._sync_clocked
                        else self._clock())
        noted = self._sync_sent.sent
        try:
            with self._send_lock:
                if hasattr(bus, "send_batch"):  # one write: nothing can answer in between
                    with self._rx:
                        self._expect = self._rx_count.copy()
                    self._note_sync_sent()
                    send_frames(bus, rpdos + [sync])
                else:  # answers to the RPDOs (delivered at once in lock-step) come first
                    send_frames(bus, rpdos)
                    with self._rx:
                        self._expect = self._rx_count.copy()
                    self._note_sync_sent()
                    bus.send(sync)
        except (can.CanError, OSError) as exc:
            # the bus refused the frames (bus off, link down): report once per streak and
            # keep cycling; the drives' heartbeats and TPDOs tell what happened to them
            if self._sync_sent.sent != noted:  # a SYNC kept that may not have gone out
                self._restart_counts()
            if not self._bus_failing:
                self._bus_event(f"sending RPDOs/SYNC failed: {exc}")
            self._bus_failing = True
        else:
            if self._bus_failing:
                self._bus_event("sending works again")
            self._bus_failing = False
        self._syncs += 1
        self._armed |= send

    # --------------------------------------------------- blocking cycles

    def wait_feedback(self, timeout: float = 0.5, missing_timeout: float | None = None
                      ) -> bool:
        """Wait until every expected drive answered the last SYNC (lock-step; blocks at most
        ``timeout`` [s, wall], or ``missing_timeout`` when every drive not yet answered
        missed the SYNC before too: default :data:`MISSING_WAIT_S`, one SYNC period on the
        wall clock). A miss counts towards the TPDO deadline, after which the drive is lost
        and no longer waited for: the cycles go on at the master's pace."""
        if missing_timeout is None:
            missing_timeout = self.period_s if self._wall_clock else MISSING_WAIT_S
        mask = self._expected()
        if not np.count_nonzero(mask):
            return True
        missed_before = self._miss_streak != 0
        deadline = time.monotonic() + timeout
        short = False  # the short bound is set
        with self._rx:
            while True:
                pending = mask & (self._rx_count <= self._expect)
                if not np.count_nonzero(pending):
                    return True
                if not short and not np.count_nonzero(pending & ~missed_before):
                    # only drives that missed the SYNC before: a short wait more
                    deadline = min(deadline, time.monotonic() + missing_timeout)
                    short = True
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._rx.wait(left)

    def step(self, timeout: float = 0.5) -> bool:
        """exchange() then wait_feedback(): one lock-step cycle (blocks)."""
        self.exchange()
        return self.wait_feedback(timeout)

    def run_until(self, done: Callable[[WinchDrives], bool], max_cycles: int,
                  timeout: float = 0.5) -> bool:
        """Lock-step cycles until ``done(self)`` or ``max_cycles`` (blocks)."""
        for _ in range(max_cycles):
            self.step(timeout)
            if done(self):
                return True
        return False

    def enable_and_wait(self, max_cycles: int = 50, restart_tries: int = 0) -> None:
        """Enable all drives and cycle until they are Operation Enabled (blocks).

        Fails at once (nothing is sent) with BusLinkError when the link is down, and with
        DriveStartupError naming the drives that need :meth:`recover` first (reset, silent,
        behind a lost link) or whose state is unknown. ``restart_tries`` > 0 (start-up,
        before anything moved): such drives are restarted first, as a CANopen master
        restarts a slave after an error control event (:meth:`restart_for_enable`)."""
        self._require_link("enable")
        self._drain()
        self._check_link()
        if self._link_down:
            raise BusLinkError(f"enable: {self._link_why()}")
        if restart_tries > 0:
            self.restart_for_enable(restart_tries)
        bad = [f"{self.who(k)}: {self._why_not_ready(k)}" for k in range(self.n)
               if self._why_not_ready(k)]
        if bad:
            raise DriveStartupError(f"enable refused: {'; '.join(bad)} ({self._producer_text()})")
        self.enable()
        ok = self._blocking("enable", lambda: self.run_until(
            lambda d: bool(np.all(d.states() == ST.OPERATION_ENABLED) or d._lost.any()),
            max_cycles))
        if self._lost.any():
            ks = np.flatnonzero(self._lost)
            # the others: no pending enable; those already enabled quick-stop
            oe = self._states == ST.OPERATION_ENABLED
            self._request[~self._lost & ~oe & (self._request == RQ.ENABLE)] = RQ.DISABLE
            self._request[~self._lost & oe] = RQ.QUICK_STOP
            raise DriveLostError(
                f"{DRIVE_LOST} while enabling: " + "; ".join(
                    f"{self.who(k)}: {self._lost_text(k, self._clock())}" for k in ks),
                tuple(self.node_ids[k] for k in ks))
        if not ok:
            bad = [f"{self.who(k)}: {DriveState(s).name}" for k, s in enumerate(self._states)
                   if s != ST.OPERATION_ENABLED]
            # the drives that did not come keep no pending enable: a later fault reset or
            # recovery must not enable them behind the controller's back
            late = self._states != ST.OPERATION_ENABLED
            held = late & (self._states == ST.QUICK_STOP_ACTIVE)
            self._request[late & ~held] = RQ.DISABLE
            self._request[held] = RQ.QUICK_STOP
            if not self.link_up():
                raise BusLinkError(f"enable: {self._link_why()}")
            raise DriveStartupError(
                f"not Operation Enabled after {max_cycles} cycles: {'; '.join(bad)}")

    def shutdown(self, max_cycles: int = 20) -> None:
        """Disable voltage on all drives (cycling until Switch On Disabled), then NMT pre-op.
        BusLinkError (after marking the drives stopped) when the link is down."""
        try:
            self._require_link("shutdown")

            def off() -> None:
                self.off()
                self.run_until(lambda d: bool(np.all(d.states() != ST.OPERATION_ENABLED)),
                               max_cycles)
                for k in range(self.n):
                    if self._started[k]:
                        self._send_nmt(k, 0x80)

            self._blocking("shutdown", off)
        finally:
            self._started[:] = False


__all__ = ["CycleMixin"]
