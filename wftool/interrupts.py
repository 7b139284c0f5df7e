"""Signals that end a run, taken where the run can stop: nothing is cut mid-write.

A signal raises wherever the program happens to be, say inside the write of a recording's
chunk. `stop_on_signals` turns SIGINT, SIGTERM and SIGHUP into a request to stop instead:
the loop sees it, finishes what it writes and closes its files, and only then is the signal
raised, as `KeyboardInterrupt` (SIGINT) or `wftool.errors.Terminated`, which the CLI turns
into exit 130 or 128 + the signal number.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

from wftool.errors import Terminated

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def raise_for(signum: int) -> None:
    """Raise what signal `signum` means to wftool."""
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated(signum)


@contextmanager
def stop_on_signals(stop: threading.Event) -> Iterator[None]:
    """Within the block, a stop signal sets `stop` and the block ends on its own; the signal
    is raised when it has. A second signal raises at once (the user insists). A signal that
    is ignored (SIGINT in a background job) stays ignored. Off the main thread, where
    signals never land, nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []

    def request_stop(signum: int, _frame: object) -> None:
        if received:
            raise_for(signum)
        received.append(signum)
        stop.set()

    previous = {}
    for sig in STOP_SIGNALS:
        if signal.getsignal(sig) is not signal.SIG_IGN:
            previous[sig] = signal.signal(sig, request_stop)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if received:
        raise_for(received[0])
