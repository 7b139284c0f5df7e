"""The virtual FC's true clock: the host `time.monotonic()` instant of every FC time, from the
lockstep anchors the SITL logs, and how late the host let it reach its instants (docs/design.md).

    TrueClock(fc.log_path).instant(frame.time_us)
"""

from __future__ import annotations

import bisect
import re
import time
from dataclasses import dataclass
from pathlib import Path

from wftool.errors import SitlError

U32 = 1 << 32
_ANCHOR = re.compile(
    rb"\[SITL\] lockstep anchor: fc_us=(\d+) monotonic_ns=(\d+) step_us=([\d.]+) reason=([\w-]+)"
)
_LATENESS = re.compile(
    rb"\[SITL\] lockstep lateness: fc_us=(\d+) waits=(\d+) over_100us=(\d+) over_250us=(\d+) "
    rb"over_500us=(\d+) over_1000us=(\d+) max_us=(\d+)"
)
LATE_OVER_US = (100, 250, 500, 1000)
"""The lateness bounds the SITL counts instants over."""
_FUTURE_SLACK_US = 1_000_000
"""Lifting a u32 time: how far past the FC's present it may lie (it cannot: the FC never
runs ahead of the host clock)."""


@dataclass(frozen=True)
class Anchor:
    """One line of the log: FC time `fc_us` is due at host CLOCK_MONOTONIC `monotonic_ns`."""

    fc_us: int
    monotonic_ns: int
    step_us: float
    """The gyro period (exact to the ns: FC time need not move in whole µs)."""
    reason: str


@dataclass(frozen=True)
class Lateness:
    """How late the host let the FC reach its instants: totals up to FC time `fc_us`."""

    fc_us: int
    waits: int
    over_us: dict[int, int]
    """Instants reached later than each of `LATE_OVER_US` µs."""
    max_us: int
    """The latest one so far (since the process started)."""

    def since(self, earlier: Lateness) -> Lateness:
        """The counts between `earlier` and this (its `max_us` stays the running maximum)."""
        over = {bound: count - earlier.over_us[bound] for bound, count in self.over_us.items()}
        return Lateness(self.fc_us, self.waits - earlier.waits, over, self.max_us)


def read_lateness(log_path: Path) -> list[Lateness]:
    """The lateness totals of the latest SITL process in `log_path` (see the module)."""
    try:
        text = log_path.read_bytes()
    except OSError as exc:
        raise SitlError(f"cannot read the SITL log {log_path}: {exc.strerror}") from None
    totals: list[Lateness] = []
    for match in _LATENESS.finditer(text):
        fc_us, waits, *over, max_us = (int(group) for group in match.groups())
        if totals and waits < totals[-1].waits:
            totals = []  # a later process: its totals start again
        totals.append(Lateness(fc_us, waits, dict(zip(LATE_OVER_US, over, strict=True)), max_us))
    return totals


def read_anchors(log_path: Path, offset: int = 0) -> tuple[list[Anchor], int]:
    """The anchors logged from byte `offset` on, and the offset after the last whole line."""
    try:
        with log_path.open("rb") as log:
            log.seek(offset)
            text = log.read()
    except OSError as exc:
        raise SitlError(f"cannot read the SITL log {log_path}: {exc.strerror}") from None
    whole = text.rfind(b"\n") + 1  # a line still being written is read next time
    anchors = [
        Anchor(int(m[1]), int(m[2]), float(m[3]), m[4].decode())
        for m in _ANCHOR.finditer(text, 0, whole)
    ]
    return anchors, offset + whole


class TrueClock:
    """FC time → its true host instant, for the latest SITL process in `log_path`.

    `refresh()` picks up anchors logged since (a host that fell behind); once the log shows a
    new process (`restarted`), this one's anchors are final.
    """

    def __init__(self, log_path: Path) -> None:
        self.log_path = Path(log_path)
        anchors, self._offset = read_anchors(self.log_path)
        starts = [i for i, a in enumerate(anchors) if a.reason == "start"]
        if not starts:
            raise SitlError(f"no lockstep anchor in {self.log_path}: is this the patched SITL?")
        self.anchors: list[Anchor] = anchors[starts[-1] :]
        self._keys = [a.fc_us for a in self.anchors]
        self.restarted = False
        """The log shows a later SITL process; its times are not this clock's."""

    def refresh(self) -> None:
        """Read anchors the SITL logged since (re-anchoring after host lag)."""
        if self.restarted:
            return
        anchors, self._offset = read_anchors(self.log_path, self._offset)
        for anchor in anchors:
            if anchor.reason == "start":
                self.restarted = True
                return
            self.anchors.append(anchor)
            self._keys.append(anchor.fc_us)

    def monotonic(self, fc_us: int) -> float:
        """The host CLOCK_MONOTONIC instant (s) when FC time `fc_us` (micros64) was due."""
        index = max(0, bisect.bisect_right(self._keys, fc_us) - 1)
        anchor = self.anchors[index]
        return (anchor.monotonic_ns + (fc_us - anchor.fc_us) * 1000) * 1e-9

    def micros64(self, fc_time_us: int, now: float | None = None) -> int:
        """`micros64` of an FC time known modulo 2^32 (a raw `micros()`, or the decoder's
        unwrapped time, which starts at the first raw reading): the latest such time not
        after the FC's present at host time `now` (default: now). Exact for times less than
        71 minutes old."""
        now_ns = time.monotonic_ns() if now is None else int(now * 1e9)
        latest = self.anchors[-1]
        present = latest.fc_us + max(0, now_ns - latest.monotonic_ns) // 1000 + _FUTURE_SLACK_US
        return present - (present - fc_time_us) % U32

    def instant(self, fc_time_us: int, now: float | None = None) -> float:
        """The true host instant (s, `time.monotonic`) of an FC time known modulo 2^32."""
        return self.monotonic(self.micros64(fc_time_us, now))


def lateness_between(log_path: Path, start: float, end: float) -> Lateness | None:
    """How late the host ran the latest SITL process in `log_path` between host instants
    `start` and `end` (`time.monotonic`): the totals logged within, told apart (None with
    fewer than two lines within: they come every 10 s of FC time)."""
    clock = TrueClock(log_path)
    clock.refresh()
    within = [t for t in read_lateness(log_path) if start <= clock.monotonic(t.fc_us) <= end]
    return within[-1].since(within[0]) if len(within) >= 2 else None
