"""Betaflight's modes: their permanent ids, the ranges on AUX channels that switch them (CLI
`aux`, MSP_MODE_RANGES), and whether a switch can turn one off.

A range is on while its channel's value v (held within 900–2099 µs) is `start` ≤ v < `end`
(`isRangeActive` in rc_modes.c); a range with `start` ≥ `end` is an unused slot.
"""

from __future__ import annotations

from dataclasses import dataclass

AUX_CHANNELS = 14
"""Betaflight's AUX channels (MAX_AUX_CHANNEL_COUNT: 18 channels, 4 of them sticks)."""
MODE_ARM = 0
MODE_FAILSAFE = 27
MODE_MSP_OVERRIDE = 50
MODE_NAMES = {
    0: "ARM", 1: "ANGLE", 2: "HORIZON", 3: "ALTHOLD", 5: "HEADFREE", 6: "PASSTHRU",
    13: "BEEPER", 19: "OSD DISABLE", 26: "BLACKBOX", 27: "FAILSAFE", 28: "AIR MODE",
    35: "FLIP OVER AFTER CRASH", 36: "PREARM", 39: "VTX PIT MODE", 46: "GPS RESCUE",
    50: "MSP OVERRIDE", 53: "LAUNCH CONTROL",
}  # fmt: skip
"""Permanent mode ids (msp_box.c) of the `aux` command and MSP_BOXIDS, for messages."""
RANGE_MIN_US, RANGE_STEP_US = 900, 25
"""A mode range's steps on the wire (MSP_MODE_RANGES): 900 µs + 25 µs a step."""
SWITCH_ENDS_US = (1000, 2000)
"""Where a two- or three-position switch of a radio sits at either end."""
SWITCH_LOW_US = 1100
"""A switch's low end reads at most this (1000 µs, with a radio's endpoints and jitter): a
range that switches a mode off must leave it out (`AuxRange.off_us`)."""


def mode_name(mode: int) -> str:
    return MODE_NAMES.get(mode, f"mode {mode}")


@dataclass(frozen=True)
class AuxRange:
    """One line of the CLI `aux` command: a mode on an AUX channel within a range."""

    slot: int
    mode: int
    """The mode's permanent id (`MODE_NAMES`)."""
    channel: int
    """0 = AUX1."""
    start: int
    end: int
    logic: int = 0
    linked: int = 0

    @classmethod
    def parse(cls, line: str) -> AuxRange:
        return cls(*(int(field) for field in line.split()[1:8]))

    @property
    def usable(self) -> bool:
        """Betaflight's IS_RANGE_USABLE: an empty range is an unused slot."""
        return self.start < self.end

    @property
    def aux(self) -> int:
        """The AUX channel's number: 1 for AUX1."""
        return self.channel + 1

    def covers(self, value_us: int) -> bool:
        """Whether the mode is on with its channel at `value_us` (`isRangeActive`)."""
        value = min(max(value_us, RANGE_MIN_US), 2099)
        return self.usable and self.start <= value < self.end

    @property
    def on_us(self) -> int:
        """A channel value in the middle of the range: the switch on."""
        return (self.start + self.end) // 2

    @property
    def off_us(self) -> int | None:
        """Where the switch is off: its low end (`SWITCH_ENDS_US`), which the range must leave
        out (start above `SWITCH_LOW_US`) — a switch at rest, or one a pilot flicks down, is
        off; None if the range takes the low end in (900-2100, 1000-2000, 900-1300)."""
        return SWITCH_ENDS_US[0] if self.start > SWITCH_LOW_US else None

    def command(self) -> str:
        fields = (self.slot, self.mode, self.channel, self.start, self.end, self.logic)
        return "aux " + " ".join(str(f) for f in (*fields, self.linked))

    def describe(self) -> str:
        return f"aux {self.slot}: {mode_name(self.mode)} on AUX{self.aux} {self.start}-{self.end}"


def parse_mode_ranges(payload: bytes) -> list[AuxRange]:
    """MSP_MODE_RANGES: every slot (permanent mode id, AUX channel, start and end step), used
    or not, as `aux` lists them."""
    return [
        AuxRange(
            slot,
            payload[offset],
            payload[offset + 1],
            RANGE_MIN_US + RANGE_STEP_US * payload[offset + 2],
            RANGE_MIN_US + RANGE_STEP_US * payload[offset + 3],
        )
        for slot, offset in enumerate(range(0, len(payload) - 3, 4))
    ]
