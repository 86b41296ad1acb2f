"""In-process lock-step: CAN frames handed to their receiver in the sender's thread.

python-can's ``virtual`` bus queues each frame for every other bus of the channel, and each
bus's notifier thread (canopen's :class:`canopen.Network`) takes it from there: in a
lock-step dry run in one process, every cycle then waits for two thread hand-offs (the
RPDOs and the SYNC to the simulated drives, their TPDOs back to the HAL), each a context
switch on a busy machine. :func:`deliver_in_sender_thread` makes a network's bus receive
its frames synchronously: a frame sent by any other bus of the channel is given to the
network's listeners at once, in the sending thread, one delivery at a time (as with the
notifier thread, which from then on only idles). Nothing else changes: the same frames in
the same order, the same canopen callbacks, the same HAL and simulated drives.

A frame sent to the network from inside one of its own deliveries (a listener that
answers itself) is delivered right after that delivery ends, in order, never re-entering
it. Switch before the traffic that matters: frames the notifier thread holds at the moment
of the switch may still arrive after the first ones delivered directly.
"""

from __future__ import annotations

import queue
import threading
from collections import deque

import can
import canopen
from can.interfaces import virtual


class _DirectQueue(queue.Queue):
    """A virtual bus's receive queue whose ``put`` delivers to the listeners at once (its
    ``get`` never has a frame: the notifier thread idles)."""

    def __init__(self, listeners: list) -> None:
        super().__init__()
        self._listeners = listeners
        self._lock = threading.RLock()  # one delivery at a time
        self._inside = threading.local()  # this thread is delivering now
        self._later: deque[can.Message] = deque()  # sent from inside a delivery
        self.direct = 0  #: frames delivered as they were sent
        self.deferred = 0  #: frames sent from inside a delivery, delivered after it

    def put(self, item, block: bool = True, timeout: float | None = None) -> None:
        if getattr(self._inside, "active", False):
            self.deferred += 1
            self._later.append(item)  # only the thread holding the lock gets here
            return
        with self._lock:
            self._inside.active = True
            try:
                self._deliver(item)
                self.direct += 1
                while self._later:
                    self._deliver(self._later.popleft())
            finally:
                self._inside.active = False

    def _deliver(self, msg: can.Message) -> None:
        for listener in self._listeners:
            listener(msg)


def deliver_in_sender_thread(network: canopen.Network) -> _DirectQueue:
    """Make the connected ``network`` (on a python-can ``virtual`` bus) receive every frame
    in the thread that sends it (see the module docstring); returns the new receive queue
    (``direct``/``deferred`` count the frames). TypeError for another kind of bus."""
    bus = network.bus
    if not isinstance(bus, virtual.VirtualBus) or network.notifier is None:
        raise TypeError(f"synchronous delivery needs a connected network on a virtual bus, "
                        f"got {type(bus).__name__}")
    direct = _DirectQueue(list(network.listeners))
    with direct._lock:
        with virtual.channels_lock:
            old = bus.queue
            i = next(i for i, q in enumerate(bus.channel) if q is old)
            bus.channel[i] = direct
            bus.queue = direct
        with old.mutex:  # frames that were waiting: delivered first, in order
            waiting = list(old.queue)
            old.queue.clear()
        direct._inside.active = True
        try:
            for msg in waiting:
                direct._deliver(msg)
        finally:
            direct._inside.active = False
    return direct


__all__ = ["deliver_in_sender_thread"]
