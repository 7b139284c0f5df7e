"""The uplink check: command packets with a known pattern, watched for in the FC's stream.

The roll channel steps through distinct values, each held long enough for the FC's RX
task to pick it up. The first streamed frame whose RC roll shows a step's value closes the
OBC → FC → OBC loop for that step; the time since the step was first sent is its round trip.
Throttle stays at its minimum and only roll, pitch, yaw, throttle, aux3 and aux4 are sent.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from wftool.errors import UsageError
from wftool.fsp import StatePacket
from wftool.fsp.schedule import RATE_HZ_MAX

PATTERN = (1100, 1300, 1500, 1700, 1900, 1200, 1400, 1600, 1800)
NEUTRAL = 1500
THROTTLE_MIN = 1000
STEP_S = 0.1
"""How long each roll value is held."""


def check_uplink_rate(rate_hz: float, name: str = "the uplink rate") -> float:
    """`rate_hz`, if commands can be sent at it: finite, above 0 and at most RATE_HZ_MAX,
    else a `UsageError` naming it as `name`. The FC applies the newest command once per FSP
    task run, and the task runs once per frame (at most RATE_HZ_MAX): faster is lost."""
    if not (math.isfinite(rate_hz) and 0 < rate_hz <= RATE_HZ_MAX):
        raise UsageError(
            f"{name} must be above 0 and at most {RATE_HZ_MAX} commands/s (the FC applies one "
            f"per FSP frame at most), not {rate_hz:g}"
        )
    return rate_hz


def pattern_command(index: int, rate_hz: float) -> tuple[int, int, int, int, int, int]:
    """Command number `index` of the pattern sent at `rate_hz`."""
    hold = max(1, math.ceil(STEP_S * rate_hz))
    roll = PATTERN[(index // hold) % len(PATTERN)]
    return (roll, NEUTRAL, NEUTRAL, THROTTLE_MIN, THROTTLE_MIN, THROTTLE_MIN)


class UplinkPattern:
    """The pattern sent at `rate_hz` from `start` (a `live.Commander`): `command(t)` is the
    one due at `due`; `sent(t)` moves on (a command that could not be sent is sent again)."""

    def __init__(self, rate_hz: float, start: float) -> None:
        self.rate_hz = rate_hz
        self.period = 1.0 / rate_hz
        self.due = start
        self.index = 0

    def command(self, t: float) -> tuple[int, int, int, int, int, int]:
        return pattern_command(self.index, self.rate_hz)

    def sent(self, t: float) -> None:
        self.index += 1
        # A loop late by more than a period skips ahead: one command catches up, no burst.
        self.due = max(self.due + self.period, t - self.period)

    def arming(self, t: float) -> None:
        """The pattern never arms or disarms."""
        return None


@dataclass(frozen=True)
class UplinkStats:
    commands_sent: int
    steps_sent: int
    steps_echoed: int
    rtt_p50_ms: float | None
    rtt_p99_ms: float | None
    rtt_max_ms: float | None

    @property
    def echoed_fraction(self) -> float:
        # The newest step may still be in flight when the run ends.
        due = max(self.steps_sent - 1, 0)
        return min(1.0, self.steps_echoed / due) if due else 0.0


class UplinkTracker:
    """Matches sent roll steps with their first echo in the stream."""

    def __init__(self) -> None:
        self._commands = 0
        self._steps: list[tuple[int, float]] = []  # (roll value, first sent at)
        self._echoed: set[int] = set()
        self._rtts: list[float] = []
        self._last_roll: int | None = None
        self._last_sent: int | None = None
        """The roll of the step being sent; None after a command that did not steer."""

    def sent(self, rc: Sequence[int], t: float, steering: bool = True) -> None:
        """A command left at `t`; `steering`: the FC's newest status said the OBC's commands
        steer (spec §15). One that does not steer is no step to echo (a pilot flies), and
        the next one that does starts a step of its own."""
        self._commands += 1
        if not steering:
            self._last_sent = None
            return
        roll = rc[0]
        if self._last_sent != roll:
            self._steps.append((roll, t))
            self._last_sent = roll

    def observe(self, packet: StatePacket, t: float) -> None:
        for frame in packet.frames:
            roll = frame.values[13]
            if roll == self._last_roll:
                continue
            self._last_roll = roll
            for index in range(len(self._steps) - 1, -1, -1):
                value, sent_at = self._steps[index]
                if value == roll and sent_at <= t:
                    if index not in self._echoed:
                        self._echoed.add(index)
                        self._rtts.append(t - sent_at)
                    break

    def stats(self) -> UplinkStats:
        rtts = sorted(self._rtts)

        def quantile(q: float) -> float | None:
            return 1e3 * rtts[round(q * (len(rtts) - 1))] if rtts else None

        return UplinkStats(
            commands_sent=self._commands,
            steps_sent=len(self._steps),
            steps_echoed=len(self._echoed),
            rtt_p50_ms=quantile(0.5),
            rtt_p99_ms=quantile(0.99),
            rtt_max_ms=1e3 * rtts[-1] if rtts else None,
        )
