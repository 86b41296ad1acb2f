"""In-process lock-step: CAN frames handed to their receiver in the sender's thread.

python-can's ``virtual`` bus queues each frame for every other bus of the channel, and each
bus's notifier thread (canopen's :class:`canopen.Network`) takes it from there: in a
lock-step dry run in one process, every cycle then waits for two thread hand-offs (the
RPDOs and the SYNC to the simulated drives, their TPDOs back to the HAL), each a context
switch on a busy machine. :func:`deliver_in_sender_thread` makes a network's bus receive
its frames synchronously: a frame sent by any other bus of the channel is given to the
network's listeners at once, in the sending thread, under the notifier's own lock (so
deliveries to one network stay one at a time, as with its thread). Nothing else changes:
the same frames, the same canopen callbacks, the same HAL and simulated drives.

Delivery falls back to the queue (and the notifier thread) while frames queued before are
still waiting (order is kept) and when a listener itself sends to the same network in the
same thread (no re-entry).
"""

from __future__ import annotations

import queue
import threading

import can
import canopen
from can.interfaces import virtual


class _DirectQueue(queue.Queue):
    """A virtual bus's receive queue whose ``put`` delivers to the listeners at once."""

    def __init__(self, deliver, lock) -> None:
        super().__init__()
        self._deliver = deliver
        self._delivery_lock = lock
        self._inside = threading.local()
        self.direct = 0  #: frames delivered in the sender's thread
        self.queued = 0  #: frames left to the notifier thread

    def put(self, item, block: bool = True, timeout: float | None = None) -> None:
        if self.queue or getattr(self._inside, "active", False):
            self.queued += 1
            super().put(item, block, timeout)
            return
        with self._delivery_lock:
            self._inside.active = True
            try:
                self._deliver(item)
            finally:
                self._inside.active = False
        self.direct += 1


def deliver_in_sender_thread(network: canopen.Network) -> _DirectQueue:
    """Make the connected ``network`` (on a python-can ``virtual`` bus) receive every frame
    in the thread that sends it (see the module docstring); returns the new receive queue
    (its ``direct``/``queued`` count the frames). TypeError for another kind of bus."""
    bus = network.bus
    notifier = network.notifier
    if not isinstance(bus, virtual.VirtualBus) or notifier is None:
        raise TypeError(f"synchronous delivery needs a connected network on a virtual bus, "
                        f"got {type(bus).__name__}")
    listeners = list(network.listeners)

    def deliver(msg: can.Message) -> None:
        for listener in listeners:
            listener(msg)

    lock = getattr(notifier, "_lock", None) or threading.Lock()
    direct = _DirectQueue(deliver, lock)
    with virtual.channels_lock:
        old = bus.queue
        with old.mutex:  # frames already queued stay first, for the notifier thread
            direct.queue.extend(old.queue)
            old.queue.clear()
        i = next(i for i, q in enumerate(bus.channel) if q is old)
        bus.channel[i] = direct
        bus.queue = direct
    return direct


__all__ = ["deliver_in_sender_thread"]
