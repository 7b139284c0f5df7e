"""The gate between ROS 2 commands and the FC: one publisher at a time, what may be sent, and
what was dropped.

    gate = CommandGate(max_age_ns=50_000_000)
    gate.offer(rc, stamp_ns, publisher, time.monotonic_ns())   # from a callback
    rc = gate.take(time.monotonic_ns())   # in the loop that owns the port: the command to send

One publisher is **latched** while it is live: the first whose command is taken while none
is, until none of its commands has arrived for the age limit; another publisher's commands
meanwhile are counted (`foreign`) and dropped, so two programs never mix their commands
(spec §11 asks the same of the FC). Freshness is the node's own monotonic clock: a command
is sent only if it arrived less than the age limit ago. A publisher's stamps order its
commands and nothing else: one no newer than the newest taken is a repeat or a replay.
When the publisher's clock steps back its commands are not newer until its link ends (one
age limit of silence from the gate), and the next command starts a new link: a step back
costs one timeout, not the step.

A command is sent at most once and never made up: the gate never repeats a command the
sender stopped sending, so a dead or stalled ROS 2 publisher reaches the FC as silence,
which its command timeout handles. Everything offered is counted by what became of it
(`CommandCounts`).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass, replace

from wftool.fsp.encoder import checked_rc
from wftool.fsp.packets import ArmingAction, RcValues

DEFAULT_MAX_AGE_NS = 50_000_000
"""How old a command may be when it is sent, and how long a publisher's silence ends its
link: the FC's default command timeout (spec §11), so a command is never older when it
leaves than the FC would let one last."""


@dataclass(frozen=True)
class CommandCounts:
    """What became of the commands offered: totals of the run so far."""

    received: int = 0
    sent: int = 0
    """Written to the FC (a command taken while the port went away is in no count)."""
    stale: int = 0
    """Arrived longer than the age limit before it was its turn to be sent."""
    out_of_range: int = 0
    """Not what a command may carry (`wftool.fsp.encoder.checked_rc`): six whole values
    within the FC's pulse range (Betaflight's widest, `RC_PULSE_US`, before it has said)."""
    unstamped: int = 0
    """`header.stamp` never set: nothing to order it by."""
    not_newer: int = 0
    """Stamped no later than the publisher's newest command taken: a repeat, a replay, out
    of order, or its clock stepped back."""
    superseded: int = 0
    """Replaced by a newer command before it was sent."""
    foreign: int = 0
    """From another publisher while one was latched (or from one with no identity)."""
    links: int = 0
    """Publishers latched so far: each silence of the age limit ends one."""
    arming_sent: int = 0
    """Arming requests (spec §14) forwarded with a command."""
    arming_refused: int = 0
    """Arming requests not forwarded: the FC's receiver is not the OBC (a safety pilot)."""

    @property
    def dropped(self) -> int:
        return (
            self.stale + self.out_of_range + self.unstamped + self.not_newer + self.superseded
            + self.foreign
        )  # fmt: skip


@dataclass
class _Link:
    publisher: bytes
    newest_stamp_ns: int
    """Of the newest command taken: the next must be stamped later."""
    arrived_ns: int
    """When that command arrived (the monotonic clock of `offer`)."""


@dataclass(frozen=True)
class Taken:
    """A command to send now (`CommandGate.take`)."""

    rc: RcValues
    arming: ArmingAction | None = None
    """An arming request to send right after it (spec §14); None: none asked."""


class CommandGate:
    """Commands offered (from any thread) and taken (by the loop that writes the port)."""

    def __init__(self, max_age_ns: int = DEFAULT_MAX_AGE_NS) -> None:
        if max_age_ns <= 0:
            raise ValueError("the command age limit must be positive")
        self.max_age_ns = max_age_ns
        self.pulse_range: tuple[int, int] | None = None
        """The FC's pulse range once its uplink status said it; None: Betaflight's widest."""
        self._lock = threading.Lock()
        self._counts = CommandCounts()
        self._pending: tuple[RcValues, int, ArmingAction | None] | None = None
        self._link: _Link | None = None

    @property
    def counts(self) -> CommandCounts:
        with self._lock:
            return self._counts

    def latched(self, now_ns: int) -> bytes | None:
        """The publisher latched at `now_ns` (its identity as `offer` got it), if one is: its
        newest command taken arrived no more than the age limit before."""
        with self._lock:
            return self._link.publisher if self._live(now_ns) and self._link else None

    def _live(self, now_ns: int) -> bool:
        link = self._link
        if link is not None and now_ns - link.arrived_ns > self.max_age_ns:
            self._link = link = None  # silence ends the link, and with it the publisher's order
        return link is not None

    def offer(
        self,
        rc: Sequence[int],
        stamp_ns: int,
        publisher: bytes | None,
        arrived_ns: int,
        arming: ArmingAction | None = None,
    ) -> str | None:
        """Take `rc` (stamped `stamp_ns` by its publisher, who is `publisher`, None if the
        middleware did not say; arrived at `arrived_ns` on the monotonic clock of `take`),
        with an arming request if one is asked, as the next command to send; None if taken,
        else the `CommandCounts` field it was counted under."""
        with self._lock:
            counts = replace(self._counts, received=self._counts.received + 1)
            verdict = self._verdict(rc, stamp_ns, publisher, arrived_ns)
            if isinstance(verdict, str):
                counts = replace(counts, **{verdict: getattr(counts, verdict) + 1})
            else:
                assert publisher is not None
                link = self._link
                if link is None:
                    self._link = _Link(publisher, stamp_ns, arrived_ns)
                    counts = replace(counts, links=counts.links + 1)
                else:
                    link.newest_stamp_ns, link.arrived_ns = stamp_ns, arrived_ns
                if self._pending is not None:
                    counts = replace(counts, superseded=counts.superseded + 1)
                    if arming is None:
                        arming = self._pending[2]  # a request asked stays asked
                self._pending = (verdict, arrived_ns, arming)
            self._counts = counts
        return verdict if isinstance(verdict, str) else None

    def _verdict(
        self, rc: Sequence[int], stamp_ns: int, publisher: bytes | None, arrived_ns: int
    ) -> str | RcValues:
        """What is wrong with a command (the `CommandCounts` field), or its values if
        nothing is (under the lock)."""
        link = self._link if self._live(arrived_ns) else None
        if publisher is None or (link is not None and publisher != link.publisher):
            return "foreign"
        try:
            values = checked_rc(rc, self.pulse_range)
        except (TypeError, ValueError):
            return "out_of_range"
        if stamp_ns <= 0:
            return "unstamped"
        if link is not None and stamp_ns <= link.newest_stamp_ns:
            return "not_newer"
        return values

    def take(self, now_ns: int) -> Taken | None:
        """The command to send now, if one is pending and still fresh (and within the FC's
        pulse range as known now); it is not offered again, whether or not the port takes it
        (`sent` counts those it took)."""
        with self._lock:
            pending, self._pending = self._pending, None
            if pending is None:
                return None
            rc, arrived_ns, arming = pending
            if now_ns - arrived_ns > self.max_age_ns:
                self._counts = replace(self._counts, stale=self._counts.stale + 1)
                return None
            try:
                checked_rc(rc, self.pulse_range)
            except ValueError:  # the FC said its range since
                self._counts = replace(self._counts, out_of_range=self._counts.out_of_range + 1)
                return None
            return Taken(rc, arming)

    def sent(self) -> None:
        """The command `take` gave was written to the FC."""
        with self._lock:
            self._counts = replace(self._counts, sent=self._counts.sent + 1)

    def arming(self, forwarded: bool) -> None:
        """The arming request of the command `take` gave was forwarded, or refused."""
        field = "arming_sent" if forwarded else "arming_refused"
        with self._lock:
            self._counts = replace(self._counts, **{field: getattr(self._counts, field) + 1})

    @property
    def pending(self) -> bool:
        with self._lock:
            return self._pending is not None
