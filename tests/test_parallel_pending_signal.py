"""A signal whose exception was lost (raised while a garbage-collector callback or a
``__del__`` ran: Python prints it and goes on) is raised again by
:func:`bench.parallel.raise_pending`, so that a long-running command's loop still ends with
the signal's exit status (``cdpr commission monitor`` ran its whole --duration once)."""

from __future__ import annotations

import os
import signal
import time

import pytest

from bench.parallel import Terminated, interrupt_on_term, interruption, raise_pending


def _lose_the_signal(sig: int) -> None:
    """Send ``sig`` to this process and swallow what its handler raises, as a gc callback
    does."""
    try:
        os.kill(os.getpid(), sig)
        time.sleep(0.5)  # the handler runs here at the latest
    except KeyboardInterrupt:
        pass


@pytest.mark.parametrize("sig,code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_lost_interruption_is_raised_again(sig, code):
    with interrupt_on_term():
        raise_pending()  # nothing pending: nothing raised
        _lose_the_signal(sig)
        with pytest.raises(KeyboardInterrupt) as got:
            raise_pending()
        assert interruption(got.value)[0] == code
        assert isinstance(got.value, Terminated) == (sig != signal.SIGINT)
        raise_pending()  # taken by interruption(): nothing pending any more


def test_nothing_is_pending_after_the_block():
    with interrupt_on_term():
        _lose_the_signal(signal.SIGTERM)
    raise_pending()
