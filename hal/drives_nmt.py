"""Network management of the winch drives' master (:class:`hal.drives.WinchDrives`): the
link, the master heartbeat producer, start-up (NMT reset, boot-up, SDO configuration, NMT
start), recovery and restarts before enabling, and the background SDO reads of fault
codes. Blocking calls, outside the control cycle.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable

import can
import numpy as np

from hal.drives_base import (
    CODE_HEARTBEAT,
    NMT_NAMES,
    NMT_OPERATIONAL,
    NMT_START_TRIES,
    BusLinkError,
    DriveStartupError,
)
from hal.drives_cia402 import (
    RQ,
    ST,
    DriveState,
    decode_states,
    emcy_text,
    faulted,
)
from hal.drives_config import (
    DriveConfigError,
    configure_node,
    drive_settings,
    holding_problems,
    sdo_read,
    verify_identity,
)
from hal.rt_threads import check_priority, raise_thread

log = logging.getLogger("hal.drives")


class NmtMixin:
    """Link, master heartbeat, start-up and recovery, fault-code SDO (a part of
    :class:`hal.drives.WinchDrives`)."""

    # ---------------------------------------------------------- the link

    def _send_nmt(self, k: int, command: int) -> None:
        self.network.send_message(0, bytes([command, self.node_ids[k]]))

    def link_up(self) -> bool:
        """The bus is usable (a socketcand link that is connected; other buses: always)."""
        return bool(getattr(self.network.bus, "link_up", True))

    def _link_why(self) -> str:
        why = getattr(self.network.bus, "link_error", "") or "link down"
        return f"{self.bus_name}: CAN link down ({why})"

    def _require_link(self, what: str) -> None:
        if not self.link_up():
            raise BusLinkError(f"{what}: {self._link_why()}")

    def _blocking(self, what: str, fn: Callable[[], object]) -> object:
        """Run a blocking operation; a bus that fails under it raises BusLinkError naming the
        bus (never a raw OSError / CanError)."""
        self._require_link(what)
        try:
            return fn()
        except (can.CanError, OSError) as exc:
            raise BusLinkError(f"{what}: {self.bus_name}: {type(exc).__name__}: {exc}") from exc
        except DriveConfigError as exc:
            if not self.link_up():
                raise BusLinkError(f"{what}: {self._link_why()}: {exc}") from exc
            raise

    def _check_link(self) -> None:
        """Per cycle: notice a lost or restored link (a reconnect counts as both)."""
        up = self.link_up()
        epoch = getattr(self.network.bus, "link_epoch", self._link_epoch)
        if (not up or epoch != self._link_epoch) and not self._link_down:
            self._link_down = True
            why = getattr(self.network.bus, "link_error", "") or "reconnected"
            self._bus_event(f"CAN link lost ({why}): drive states unknown", "link_lost")
            lost = self._started.copy()
            self._relink |= lost
            self._have[:] = False
            self._setpoint_ok[:] = False
            self._request[lost] = RQ.QUICK_STOP  # hold, should anything still listen
        if up and self._link_down:
            self._link_down = False
            self._bus_event("CAN link back: the drives stopped on their own (master lost); "
                            "recover() them, then enable()", "link_back", 0)
        self._link_epoch = epoch

    # -------------------------------------------------- master heartbeat

    def _master_heartbeat(self) -> None:
        mid = self.winches.bus.master_node_id
        try:
            with self._send_lock:
                self.network.bus.send(can.Message(arbitration_id=0x700 + mid,
                                                  data=bytes([NMT_OPERATIONAL]),
                                                  is_extended_id=False))
        except (can.CanError, OSError):
            pass  # a dead link: the cycle reports it
        now = time.monotonic()
        gap = now - self._mhb_wall
        if gap < np.inf:
            self._mhb_gap_max = max(self._mhb_gap_max, gap)
            if gap > self.winches.bus.master_heartbeat_timeout_s > 0:
                self._mhb_late += 1
        self._mhb_wall = now

    def producer_stats(self) -> dict:
        """The master heartbeat producer so far: ``scheduling`` (what its thread got),
        ``gap_max_s`` (longest wall time between two heartbeats sent [s]), ``late`` (gaps
        longer than the drives' consumer time, ``master_heartbeat_timeout_s``: each one
        let the drives conclude that their master is gone)."""
        return {"scheduling": self.producer_scheduling,
                "gap_max_s": float(self._mhb_gap_max), "late": int(self._mhb_late)}

    def _producer_text(self) -> str:
        st = self.producer_stats()
        return (f"master heartbeat: longest gap {st['gap_max_s']:.3f} s, {st['late']} longer "
                f"than the drives' consumer time {self.winches.bus.master_heartbeat_timeout_s:g}"
                f" s; producer thread {st['scheduling']}")

    def set_producer_priority(self, priority: int) -> str:
        """The master heartbeat thread's SCHED_FIFO priority (0: normal scheduling, as it
        is); applied at once when it runs, else when :meth:`start` starts it. Returns
        :attr:`producer_scheduling`."""
        self.producer_priority = check_priority(priority)  # ValueError naming the range
        t = self._mhb_thread
        if t is not None and t.native_id is not None and priority > 0:
            self.producer_scheduling = raise_thread(self.producer_priority, t.native_id)
        return self.producer_scheduling

    def _mhb_loop(self) -> None:
        self.producer_scheduling = raise_thread(self.producer_priority)
        period = self.winches.bus.master_heartbeat_period_s
        while not self._mhb_stop.wait(max(0.001, period - (time.monotonic() - self._mhb_wall))):
            if time.monotonic() - self._mhb_wall >= period - 1e-4:
                self._master_heartbeat()

    def _start_master_heartbeat(self) -> None:
        if self.winches.bus.master_heartbeat_period_s <= 0 or self._mhb_thread is not None:
            return
        self._mhb_stop.clear()
        self._master_heartbeat()
        self._mhb_thread = threading.Thread(target=self._mhb_loop, name="master-heartbeat",
                                            daemon=True)
        self._mhb_thread.start()

    def _cycle_heartbeat(self) -> None:
        """On a non-wall clock, also one heartbeat per period of that clock (the drives on
        the same clock then hear it at the period, however fast the cycles run)."""
        period = self.winches.bus.master_heartbeat_period_s
        if self._wall_clock or period <= 0 or self._mhb_thread is None:
            return
        now = self._clock()
        if now - self._mhb_clock >= period - 1e-9:
            self._mhb_clock = now
            self._master_heartbeat()

    # ----------------------------------------------- start-up (blocking)

    def start(self, timeout: float = 3.0, nodes: Iterable[int] | None = None) -> None:
        """Bring drives to NMT OPERATIONAL with the CSP configuration (blocking; SDO).

        NMT reset communication, wait for each boot-up, check identity against the EDS,
        write and verify the configuration (master-loss monitoring included), read
        statusword and position, NMT start; the master heartbeat runs from here on.
        ``nodes`` are array indices (default: all). Raises DriveStartupError or
        DriveConfigError naming the node, BusLinkError naming the bus.
        """
        if nodes is None:
            for problem in holding_problems(self.winches):
                log.warning("%s", problem)
        self._blocking("start", lambda: self._start(timeout, nodes))

    def _start(self, timeout: float, nodes: Iterable[int] | None) -> None:
        ks = list(range(self.n)) if nodes is None else list(nodes)
        self._start_master_heartbeat()
        before = self._boot_count.copy()
        for k in ks:
            self._send_nmt(k, 0x82)  # reset communication
        self._wait_bootups(ks, before, timeout)
        with self._sdo_lock:
            for k in ks:
                node = self.nodes[k]
                who = self.who(k)
                verify_identity(node, who)
                configure_node(node, drive_settings(self.winches, k, node.object_dictionary),
                               who)
                sw = int(sdo_read(node, 0x6041, 0, who))
                pos = int(sdo_read(node, 0x6064, 0, who))
                with self._rx:
                    self._rx_sw[k] = sw
                    self._rx_pos[k] = pos
                    self._seen[k] = self._rx_count[k]
                self._sw[k], self._pos[k], self._have[k] = sw, pos, True
                self._target[k] = pos
        self._drain_startup(ks)
        now = self._clock()
        self._link_down = False
        self._link_epoch = getattr(self.network.bus, "link_epoch", self._link_epoch)
        states = decode_states(self._sw, self._have)
        for k in ks:
            self._send_nmt(k, 0x01)  # start remote node
            self._started[k] = True
            self._armed[k] = False
            self._align[k].restart()  # a new stream of TPDOs
            self._rebooted[k] = False
            self._relink[k] = False
            self._hb_lost[k] = False
            self._hb_last[k] = now
            self._rx_hb_t[k] = max(self._rx_hb_t[k], now)
            self._rx_hb_state[k] = -1  # the next heartbeat tells the state
            self._nmt[k] = NMT_OPERATIONAL
            self._nmt_wait[k] = now + max(self.hb_timeout_s, self.period_s)
            self._miss_streak[k] = 0
            self._lost[k] = False
            self._last_tpdo_t[k] = now
            # a drive holding in Quick Stop Active (it lost its master) keeps holding
            held = states[k] == ST.QUICK_STOP_ACTIVE
            self._request[k] = RQ.QUICK_STOP if held else RQ.DISABLE
            self._self_stopped[k] = held
            self._setpoint_ok[k] = False
        self._states = states
        for k in ks:
            if faulted(self._states[k:k + 1])[0]:
                if not self._window[k]:  # its EMCY may have gone out before we listened
                    with self._sdo_lock:
                        self._fault_code[k] = int(sdo_read(self.nodes[k], 0x603F, 0,
                                                           self.who(k)))
                else:
                    self._fault_code[k] = self._cause(k)
                code = int(self._fault_code[k])
                text = emcy_text(code) if code else "fault without EMCY (read 0x603F)"
                self._event(k, "fault", code, f"in {DriveState(self._states[k]).name} at "
                            f"start-up: {text}")

    def _wait_bootups(self, ks: list[int], before: np.ndarray, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        with self._rx:
            while True:
                missing = [k for k in ks if self._boot_count[k] <= before[k]]
                left = deadline - time.monotonic()
                if not missing:
                    return
                if left <= 0:
                    who = ", ".join(self.who(k) for k in missing)
                    raise DriveStartupError(
                        f"no boot-up within {timeout:.1f} s after NMT reset from {who}")
                self._rx.wait(left)

    def _drain_startup(self, ks: list[int]) -> None:
        """Consume events of the start-up (boot-ups we caused); keep EMCYs."""
        keep = []
        while self._queue:
            item = self._queue.popleft()
            if item[0] == "hb" and item[1] in ks:
                continue
            keep.append(item)
        self._queue.extend(keep)
        self._drain()

    def _needs_recovery(self) -> np.ndarray:
        return self._rebooted | self._relink | self._hb_lost | (
            self._started & ~np.isin(self._nmt, (NMT_OPERATIONAL, -1)))

    def recover(self, timeout: float = 3.0) -> list[int]:
        """Restart drives that rebooted, went silent and are back, or were behind a lost
        link (blocking; SDO). Returns the node ids restarted. They come back disabled, or
        holding in Quick Stop Active if they stopped on their own: call :meth:`enable`.
        BusLinkError while the link is down.
        """
        self._require_link("recover")
        self._check_link()
        self._drain()
        return self._restart([int(k) for k in np.flatnonzero(self._needs_recovery())], timeout)

    def _restart(self, ks: list[int], timeout: float) -> list[int]:
        """Start drives ``ks`` again (:meth:`start`'s sequence), an event ``recovered``
        each; their node ids."""
        if not ks:
            return []
        self._blocking("recover", lambda: self._start(timeout, ks))
        for k in ks:
            self._event(k, "recovered", 0, "reconfigured and started")
        return [self.node_ids[k] for k in ks]

    def restart_for_enable(self, tries: int = NMT_START_TRIES, timeout: float = 3.0
                           ) -> list[int]:
        """Restart the drives that are not ready to be enabled because they left NMT
        OPERATIONAL, were reset, lost their heartbeat or their TPDOs (e.g. their consumer
        heartbeat expired while the host starved the master's producer) - at start-up,
        before anything moved (blocking; SDO). Each try is :meth:`recover`'s sequence (NMT
        reset, boot-up, configuration, NMT start), then a wait of up to
        :meth:`confirm_window_s` for their heartbeats to say OPERATIONAL; at most
        ``tries`` tries, an event ``nmt_restart`` per drive and try. Returns the node ids
        restarted; raises DriveStartupError naming each node, its NMT state and the
        master heartbeat's record when the last try leaves some not OPERATIONAL."""
        t0 = time.monotonic()
        done: list[int] = []
        left: list[int] = []
        for attempt in range(1, tries + 1):
            self._drain()
            self._require_link("enable")
            self._check_link()
            # and drives whose TPDOs stopped (drive_lost): nothing was enabled yet
            left = [int(k) for k in np.flatnonzero(
                (self._needs_recovery() | self._lost) & self._started)]
            if not left:
                return done
            for k in left:
                why = self._not_ready(k)[0] or "not OPERATIONAL"
                self._event(k, "nmt_restart", CODE_HEARTBEAT, f"{why} before enabling: "
                            f"restart {attempt} of {tries} ({self._producer_text()})")
            done += [self.node_ids[k] for k in left if self.node_ids[k] not in done]
            self._restart(left, timeout)
            left = self._confirm_operational(left)
            if not left:
                return done
        raise DriveStartupError("not NMT OPERATIONAL after " f"{tries} restarts in "
                                f"{time.monotonic() - t0:.1f} s: " + "; ".join(
                                    f"{self.who(k)}: NMT {self._nmt_name(k)}" for k in left)
                                + f" ({self._producer_text()})")

    def confirm_window_s(self) -> float:
        """How long [s, wall] :meth:`restart_for_enable` waits for a restarted drive's
        heartbeat: two of its heartbeat periods and the master's consumer time."""
        bus = self.winches.bus
        return 2.0 * bus.heartbeat_period_s + bus.master_heartbeat_timeout_s

    def _confirm_operational(self, ks: list[int]) -> list[int]:
        """Of drives ``ks`` just NMT-started, those whose heartbeat did not say OPERATIONAL
        within :meth:`confirm_window_s` (none when the drives send no heartbeat)."""
        if self.winches.bus.heartbeat_period_s <= 0:
            return []
        deadline = time.monotonic() + self.confirm_window_s()
        while True:
            left = [k for k in ks if self._rx_hb_state[k] != NMT_OPERATIONAL]
            if not left or time.monotonic() >= deadline:
                break
            time.sleep(min(0.01, max(0.0, deadline - time.monotonic())))
        for k in left:  # what it said last (-1: nothing since the NMT start)
            state = int(self._rx_hb_state[k])
            if state >= 0:
                self._nmt[k] = state
        return left

    def _nmt_name(self, k: int) -> str:
        state = int(self._nmt[k]) if self._rx_hb_state[k] < 0 else int(self._rx_hb_state[k])
        return NMT_NAMES.get(state, f"unknown (no heartbeat within "
                             f"{self.confirm_window_s():.2f} s)" if state < 0 else hex(state))

    def _why_not_ready(self, k: int) -> str:
        """Why drive ``k`` cannot be enabled, with what to do (``""``: ready)."""
        why, advice = self._not_ready(k)
        return f"{why}: {advice}" if why and advice else why

    def _not_ready(self, k: int) -> tuple[str, str]:
        """(why drive ``k`` cannot be enabled, what to do; ``""``: ready / nothing said)."""
        if not self._started[k]:
            return "not started (start() first)", ""
        if self._relink[k]:
            return "behind a lost CAN link", "recover() it first"
        if self._rebooted[k]:
            return "was reset (boot-up)", "recover() it first"
        if self._hb_lost[k]:
            return "heartbeat lost", "recover() it once it is back"
        if self._lost[k]:
            return "TPDOs lost (drive_lost)", "its state is unknown"
        if self._nmt[k] not in (NMT_OPERATIONAL, -1):
            return f"NMT {NMT_NAMES.get(int(self._nmt[k]), '?')}", "recover() it first"
        return "", ""

    # ------------------------------------------------- fault codes (SDO)

    def _confirm_fault_code(self, k: int) -> None:
        """Read 0x603F of drive ``k`` in the background (the cycle never waits for SDO)."""
        if self._worker is None:
            self._worker = threading.Thread(target=self._work, name="drive-sdo", daemon=True)
            self._worker.start()
        self._jobs.put(k)

    def _work(self) -> None:
        while True:
            k = self._jobs.get()
            if k is None or self._closed:
                return
            try:
                with self._sdo_lock:
                    code = int(sdo_read(self.nodes[k], 0x603F, 0, self.who(k)))
                self._queue.append(("603f", k, code, ""))
            except (DriveConfigError, can.CanError, OSError) as exc:
                self._queue.append(("603f", k, None, str(exc)))

    def _fault_code_read(self, k: int, code: int | None, err: str) -> None:
        if not faulted(self._states[k:k + 1])[0]:
            return  # reset meanwhile
        if code is None:
            self._event(k, "sdo_error", 0, f"reading 0x603F error code: {err}")
            return
        if code != self._fault_code[k]:
            old = int(self._fault_code[k])
            self._fault_code[k] = code
            said = f"0x{old:04X}" if old else "no EMCY"
            self._event(k, "fault_code", code, f"0x603F error code 0x{code:04X} "
                        f"({emcy_text(code)}); the fault came with {said}")

    def read_fault_codes(self) -> dict[int, int]:
        """Read 0x603F error code of drives in Fault by SDO (blocking). {node id: code}."""

        def read() -> dict[int, int]:
            out = {}
            for k in np.flatnonzero(faulted(self._states)):
                with self._sdo_lock:
                    code = int(sdo_read(self.nodes[k], 0x603F, 0, self.who(k)))
                self._fault_code[k] = code
                out[self.node_ids[k]] = code
            return out

        return self._blocking("read_fault_codes", read)


__all__ = ["NmtMixin"]
