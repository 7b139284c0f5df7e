"""Waiting on a condition, not on a clock: what the tests share for it.

A host-clock sleep stands in for something else: that the FC has run long enough (its own
clock says so, and a loaded host runs the virtual FC slower), that a peer has answered, that
a file has its content. `wait_for` polls the condition itself, up to a timeout that is only a
bound on "never", far above what the condition takes.
"""

from __future__ import annotations

import time
from collections.abc import Callable

POLL_S = 0.01


def wait_for(condition: Callable[[], object], timeout: float, poll: float = POLL_S) -> bool:
    """Whether `condition()` became true within `timeout` seconds (polled every `poll`)."""
    deadline = time.monotonic() + timeout
    while True:
        if condition():
            return True
        if time.monotonic() > deadline:
            return False
        time.sleep(poll)
