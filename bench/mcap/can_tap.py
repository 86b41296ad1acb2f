"""Every frame of the drives' CAN bus to a callback (the ``/can`` channel of a recording)."""

from __future__ import annotations


class CanTap:
    """Every frame of a CAN bus to ``on_frame(msg)``: on a ``virtual:CHANNEL`` in the
    sending thread as it is sent (the order of the bus, lock-step included); another bus
    (e.g. the socketcand hub of ``--rig process``, which sends every client the frames in
    one order) through a second connection and a python-can notifier. :meth:`close` detaches."""

    def __init__(self, spec: str, on_frame) -> None:
        import can

        from hal.can_bus import open_bus, parse_can_spec

        self.spec = spec
        self._notifier = None
        s = parse_can_spec(spec)
        if s.interface == "virtual":
            from can.interfaces import virtual

            from bench.dryrun.lockstep_bus import _DirectQueue

            self.bus = virtual.VirtualBus(channel=s.channel)
            direct = _DirectQueue([on_frame])
            with virtual.channels_lock:  # first of the receivers: a frame is logged
                # before any receiver answers it (a SYNC before its TPDOs, as on a wire)
                self.bus.channel.remove(self.bus.queue)
                self.bus.channel.insert(0, direct)
                self.bus.queue = direct
        else:
            self.bus = open_bus(spec)
            self._notifier = can.Notifier(self.bus, [on_frame], timeout=0.05)

    def close(self) -> None:
        if self._notifier is not None:
            self._notifier.stop()
        self.bus.shutdown()
