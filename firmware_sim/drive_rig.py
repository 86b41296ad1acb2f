"""A simulated winch rig in its own process: eight CiA 402 drives behind a socketcand hub.

    python -m firmware_sim.drive_rig --port 0 [--host 127.0.0.1] [--winches FILE]
                                     [--clock sync|wall] [--channel can0]

prints one JSON line on stdout once it serves, e.g.::

    {"interface": "socketcand", "host": "127.0.0.1", "port": 40123, "channel": "can0",
     "can": "socketcand:127.0.0.1:40123", "node_ids": [1, ..., 8], "clock": "sync"}

and runs until SIGTERM / SIGINT (or until stdin closes with ``--stdin-eof-exits``).
A controller connects with ``--can socketcand:127.0.0.1:PORT`` (python-can's own
``socketcand`` interface). With ``--interface socketcan --channel vcan0`` the drives sit
directly on a SocketCAN bus instead (no hub).

Inside, the hub bridges its TCP clients to an in-process python-can ``virtual`` bus on
which :class:`~firmware_sim.drive_bank.SimulatedWinchBank` runs the drives.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import time

import can
import numpy as np

from controller.winch import load_winches
from firmware_sim.can_hub import CanHub
from firmware_sim.drive_bank import SimulatedWinchBank


class DriveRig:
    """Hub + bank in one object (for in-process use and for :func:`main`)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0, channel: str = "can0",
                 winches_path: str | None = None, clock: str = "sync",
                 initial_lengths_m: float | list[float] = 10.0) -> None:
        self.winches = load_winches(winches_path)
        bridge = f"drive-rig-{os.getpid()}-{id(self):x}"
        self._hub_bus = can.Bus(interface="virtual", channel=bridge)
        self.hub = CanHub(host, port, channel=channel, bus=self._hub_bus)
        self.bank = SimulatedWinchBank(
            can.Bus(interface="virtual", channel=bridge),
            self.winches,
            clock=time.monotonic if clock == "wall" else None,
        )
        self.bank.set_positions_m(np.broadcast_to(np.asarray(initial_lengths_m, float),
                                                  (len(self.winches),)))
        self.channel = channel
        self.clock = clock

    def start(self) -> DriveRig:
        self.hub.start()
        self.bank.start()
        return self

    def endpoint(self) -> dict:
        host, port = self.hub.address
        return {
            "interface": "socketcand",
            "host": host,
            "port": port,
            "channel": self.channel,
            "can": f"socketcand:{host}:{port}" + ("" if self.channel == "can0"
                                                  else f":{self.channel}"),
            "node_ids": [int(x) for x in self.winches.node_id],
            "clock": self.clock,
        }

    def close(self) -> None:
        self.hub.close()
        self.bank.close()
        self._hub_bus.shutdown()

    def __enter__(self) -> DriveRig:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m firmware_sim.drive_rig", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--host", default="127.0.0.1", help="address the hub binds (default loopback)")
    p.add_argument("--port", type=int, default=0, help="TCP port of the hub (0: any free one)")
    p.add_argument("--channel", default="can0", help="socketcand channel name served")
    p.add_argument("--winches", default=None, help="winch parameter TOML (default ROCASPECT)")
    p.add_argument("--clock", choices=("sync", "wall"), default="sync",
                   help="sync: drive time advances by the SYNC period per SYNC (deterministic); "
                        "wall: drives follow the wall clock")
    p.add_argument("--lengths", type=float, nargs="+", default=[10.0], metavar="M",
                   help="initial cable lengths [m]: one for all or one per winch (default 10)")
    p.add_argument("--interface", default=None,
                   help="run the drives directly on this python-can interface (no hub)")
    p.add_argument("--stdin-eof-exits", action="store_true",
                   help="exit when stdin is closed (the parent went away)")
    args = p.parse_args(argv)

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    if args.stdin_eof_exits:
        def _watch() -> None:
            sys.stdin.read()
            stop.set()
        threading.Thread(target=_watch, daemon=True).start()

    if args.interface:
        winches = load_winches(args.winches)
        bank = SimulatedWinchBank(can.Bus(interface=args.interface, channel=args.channel),
                                  winches, clock=time.monotonic if args.clock == "wall" else None)
        bank.set_positions_m(np.broadcast_to(np.asarray(args.lengths, float), (len(winches),)))
        bank.start()
        print(json.dumps({"interface": args.interface, "channel": args.channel,
                          "can": f"{args.interface}:{args.channel}",
                          "node_ids": [int(x) for x in winches.node_id], "clock": args.clock}),
              flush=True)
        stop.wait()
        bank.close()
        return 0

    if len(args.lengths) not in (1, 8):
        p.error(f"--lengths takes 1 or 8 values, got {len(args.lengths)}")
    rig = DriveRig(args.host, args.port, args.channel, args.winches, args.clock,
                   args.lengths if len(args.lengths) > 1 else args.lengths[0]).start()
    print(json.dumps(rig.endpoint()), flush=True)
    try:
        stop.wait()
    finally:
        rig.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
