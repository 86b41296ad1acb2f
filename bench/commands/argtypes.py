"""Argument types for numeric options: a non-physical value (negative, zero where zero
means nothing, NaN, infinite, out of range) is a usage error (exit status 2) whose message
names the value and the allowed range, e.g. ``argument --duration: -5: must be a finite
number in (0, inf)``.

Use as ``p.add_argument("--duration", type=positive_float, ...)``; a bounded option as
``type=float_in(0, 100, lo_open=True)``. Endpoints a command listens on (``cdpr sim``)
are parsed by :func:`listen_endpoint`.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

_INF = math.inf


def _interval(lo: float, hi: float, lo_open: bool, hi_open: bool) -> str:
    left = "(" if lo_open else "["
    right = ")" if hi_open or hi == _INF else "]"
    return f"{left}{lo:g}, {hi:g}{right}"


def float_in(lo: float = -_INF, hi: float = _INF, lo_open: bool = False,
             hi_open: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite float in the interval (``lo_open``/``hi_open``: bound
    excluded); anything else raises :class:`argparse.ArgumentTypeError` naming the range."""
    rng = _interval(lo, hi, lo_open, hi_open)

    def parse(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text}: not a number (allowed {rng})") from None
        below = x <= lo if lo_open else x < lo
        above = x >= hi if hi_open else x > hi
        if not math.isfinite(x) or below or above:
            raise argparse.ArgumentTypeError(f"{text}: must be a finite number in {rng}")
        return x

    parse.__name__ = f"float in {rng}"
    return parse


def int_in(lo: int | None = None, hi: int | None = None) -> Callable[[str], int]:
    """An argparse type: an integer in [lo, hi] (None: unbounded on that side)."""
    rng = f"[{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}]"
    if hi is None:
        rng = rng[:-1] + ")"

    def parse(text: str) -> int:
        try:
            x = int(text, 0)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text}: not an integer (allowed {rng})") from None
        if (lo is not None and x < lo) or (hi is not None and x > hi):
            raise argparse.ArgumentTypeError(f"{text}: must be an integer in {rng}")
        return x

    parse.__name__ = f"integer in {rng}"
    return parse


#: seconds, metres, hertz, newtons...: finite and > 0
positive_float = float_in(0.0, _INF, lo_open=True)
#: finite and >= 0
nonnegative_float = float_in(0.0, _INF)
#: a count: an integer >= 1
positive_int = int_in(1, None)
#: an integer >= 0
nonnegative_int = int_in(0, None)
#: a TCP port (0: any free one)
tcp_port = int_in(0, 65535)


def listen_endpoint(option: str, text: str, schemes: tuple[str, ...]) -> tuple[str, str, int]:
    """``[SCHEME:]HOST:PORT`` of an address to listen on (PORT 0: any free one) as
    ``(scheme, host, port)``; ``scheme`` is ``schemes[0]`` when not given. ValueError naming
    ``option``, the text and the accepted forms."""
    forms = " or ".join(f"{s}:HOST:PORT" for s in schemes) + " or HOST:PORT"
    scheme, rest = schemes[0], text
    head, sep, tail = text.partition(":")
    if sep and head in schemes:
        scheme, rest = head, tail
    host, sep, port = rest.rpartition(":")
    try:
        p = int(port)
    except ValueError:
        p = -1
    if not sep or not host or not 0 <= p <= 65535:
        raise ValueError(f"{option} {text!r}: expected {forms} (PORT in 0..65535, 0: any "
                         "free one)")
    return scheme, host, p


#: where ``--live`` serves when given without an address (the one source of that default)
LIVE_ADDRESS = "127.0.0.1:8765"


def add_format_and_live(p: argparse.ArgumentParser, mcap_note: str, shows: str) -> None:
    """``--format csv|mcap|both`` (what ``--record`` writes; ``mcap_note`` says what the MCAP
    file holds beyond the rows) and ``--live [HOST:PORT]`` (``shows``: what Foxglove shows)."""
    p.add_argument("--format", choices=("csv", "mcap", "both"), default="csv",
                   help=f"--record as the CSV directory, as DIR/recording.mcap (MCAP, zstd, "
                        f"{mcap_note}), or both [csv]")
    p.add_argument("--live", nargs="?", const=LIVE_ADDRESS, default=None, metavar="HOST:PORT",
                   help=f"show {shows} live in Foxglove: a WebSocket server on HOST:PORT "
                        f"[{LIVE_ADDRESS}]")
