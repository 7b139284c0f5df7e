"""The gate between ROS 2 commands and the FC: what may be sent, and what was dropped.

    gate = CommandGate(max_age_ns=50_000_000)
    gate.offer((1500, 1500, 1500, 1000, 1000, 1000), stamp_ns, now_ns)   # from a callback
    rc = gate.take(now_ns)          # in the loop that owns the port: the command to send

A command is sent at most once, only while it is fresh, and never made up: the gate never
repeats a command the sender stopped sending, so a dead or stalled ROS 2 publisher reaches
the FC as silence, which its command timeout handles (spec §11). Everything offered is
counted by what became of it (`CommandCounts`).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass, replace

from wftool.fsp.encoder import checked_rc
from wftool.fsp.packets import RcValues

DEFAULT_MAX_AGE_NS = 50_000_000
"""How old a command may be when it is sent: the FC's default command timeout (spec §11),
so a command is never older when it leaves than the FC would let one last."""
FUTURE_TOLERANCE_NS = 2_000_000
"""How far ahead of the node's clock a stamp may be. One host's senders share the clock; a
stamp further ahead is another clock's, or a lie, and would stay "fresh" too long."""


@dataclass(frozen=True)
class CommandCounts:
    """What became of the commands offered: totals of the run so far."""

    received: int = 0
    sent: int = 0
    """Written to the FC (a command taken while the port went away is in no count)."""
    stale: int = 0
    """Older than the limit when offered, or when it was its turn to be sent."""
    future: int = 0
    """Stamped ahead of the node's clock (beyond FUTURE_TOLERANCE_NS)."""
    out_of_range: int = 0
    """Not what a command may carry (`wftool.fsp.encoder.checked_rc`): six whole values
    within Betaflight's pulse range `RC_PULSE_US`."""
    not_newer: int = 0
    """Stamped no later than a command taken before: a repeat, a replay, or out of order."""
    superseded: int = 0
    """Replaced by a newer command before it was sent."""

    @property
    def dropped(self) -> int:
        return self.stale + self.future + self.out_of_range + self.not_newer + self.superseded


class CommandGate:
    """Commands offered (from any thread) and taken (by the loop that writes the port)."""

    def __init__(self, max_age_ns: int = DEFAULT_MAX_AGE_NS) -> None:
        if max_age_ns <= 0:
            raise ValueError("the command age limit must be positive")
        self.max_age_ns = max_age_ns
        self._lock = threading.Lock()
        self._counts = CommandCounts()
        self._pending: tuple[RcValues, int] | None = None  # (rc, stamp)
        self._newest_ns: int | None = None  # stamp of the newest command taken

    @property
    def counts(self) -> CommandCounts:
        with self._lock:
            return self._counts

    def offer(self, rc: Sequence[int], stamp_ns: int, now_ns: int) -> str | None:
        """Take `rc` (stamped `stamp_ns` on the clock of `now_ns`) as the next command to
        send; None if taken, else the `CommandCounts` field it was counted under."""
        try:
            values = checked_rc(rc)
        except (TypeError, ValueError):
            verdict: str | None = "out_of_range"
        else:
            verdict = self._verdict(stamp_ns, now_ns)
        with self._lock:
            counts = replace(self._counts, received=self._counts.received + 1)
            if verdict is None:
                if self._pending is not None:
                    counts = replace(counts, superseded=counts.superseded + 1)
                self._pending = (values, stamp_ns)
                self._newest_ns = stamp_ns
            else:
                counts = replace(counts, **{verdict: getattr(counts, verdict) + 1})
            self._counts = counts
        return verdict

    def _verdict(self, stamp_ns: int, now_ns: int) -> str | None:
        """What is wrong with a command's stamp, if anything."""
        if stamp_ns - now_ns > FUTURE_TOLERANCE_NS:
            return "future"
        if now_ns - stamp_ns > self.max_age_ns:
            return "stale"
        newest = self._newest_ns
        if newest is not None and stamp_ns <= newest:
            return "not_newer"
        return None

    def take(self, now_ns: int) -> RcValues | None:
        """The command to send now, if one is pending and still fresh; it is not offered
        again, whether or not the port takes it (`sent` counts those it took)."""
        with self._lock:
            pending, self._pending = self._pending, None
            if pending is None:
                return None
            rc, stamp_ns = pending
            if now_ns - stamp_ns > self.max_age_ns:
                self._counts = replace(self._counts, stale=self._counts.stale + 1)
                return None
            return rc

    def sent(self) -> None:
        """The command `take` gave was written to the FC."""
        with self._lock:
            self._counts = replace(self._counts, sent=self._counts.sent + 1)

    @property
    def pending(self) -> bool:
        with self._lock:
            return self._pending is not None
