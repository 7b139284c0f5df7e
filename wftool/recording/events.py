"""What a live run hands its recordings: its events in order (`Event`), health snapshots
(`StreamHealth`, with the FC's newest `UplinkReport`), and the `Sink` protocol of whatever
keeps or shows them.

    Event("connected", t)                  # t: OBC monotonic time, s
    Event("bytes", t, data)                # one read, exactly as read
    Event("command", t, rc=(1500, ...))    # RC sent: roll pitch yaw throttle aux3 aux4
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, NamedTuple, Protocol

from wftool.fsp import ESTIMATORS, StatePacket, UplinkStatus

EventKind = Literal["connected", "disconnected", "bytes", "command"]
EVENT_KINDS: tuple[EventKind, ...] = ("connected", "disconnected", "bytes", "command")
"""In the order of their numbers in the ROS 2 event messages (CONNECTED = 0, ...)."""
EVENT_TOPIC = "/fsp/events"
"""Where a recording of the FSP stream keeps its events."""
METADATA_NAME = "wftool.verify"
"""The metadata record of a recorded run (`run_metadata`)."""


class Event(NamedTuple):
    """One thing a run saw. A tuple, so a batch of them costs no more than tuples."""

    kind: EventKind
    t: float
    """OBC monotonic time, s."""
    data: bytes = b""
    """A read's bytes (the MSP baseline's requests, too)."""
    rc: tuple[int, ...] = ()
    """A command's RC values."""


@dataclass(frozen=True)
class UplinkReport:
    """The FC's newest uplink status (E3, spec §12): what it made of the commands, its FC
    times on the OBC clock. What `/fsp/uplink_status` carries."""

    status: UplinkStatus
    t: float
    """OBC time the FC sent it (its `tx_time_us` through the run's clock; when it was read
    if the clock could not place it), s."""
    timed_out_t: float | None
    """OBC time of the FC's latest command timeout (`timed_out_us`); None before the first."""
    exit_t: float | None = None
    """OBC time the OBC last lost its authority or link (`exit_us`, spec §15); None before
    the first, or from firmware that does not report it."""


@dataclass(frozen=True)
class StreamHealth:
    """A snapshot of the stream's counters: what `/fsp/health` carries; and the FC's newest
    uplink status, for `/fsp/uplink_status`."""

    t: float
    """OBC monotonic time of the snapshot, s."""
    seq: int
    epoch: int
    e1: bool
    clock_locked: bool
    connected: bool
    packets: int
    frames: int
    lost_frames: int
    lost_packets: int
    fc_drops: int
    rejected_chunks: int
    resets: int
    reconnects: int
    uplink: UplinkReport | None = None
    """The FC's newest uplink status; None before the first (an FC never sent a command
    sends none)."""


def new_uplink(health: StreamHealth, before: StreamHealth | None) -> UplinkReport | None:
    """The uplink status `health` carries if the snapshot `before` it did not: what a sink
    publishes once."""
    uplink = health.uplink
    if uplink is None or (before is not None and uplink is before.uplink):
        return None
    return uplink


class Sink(Protocol):
    """Whatever keeps or shows a live run: the live loop hands each of them every event,
    and each read's packets with the latest health snapshot (the same object until a new
    one is taken, so a sink writes or publishes each snapshot once)."""

    def event(self, event: Event) -> None: ...

    def packets(self, packets: Sequence[StatePacket], health: StreamHealth | None) -> None: ...

    def close(self) -> None: ...


def run_metadata(
    port: str,
    baudrate: int,
    expected_rate_hz: float | None,
    uplink_rate_hz: float | None,
    clock: str = ESTIMATORS[0],
) -> dict[str, str]:
    """What a recording keeps about its run, for a replay to set up the same monitor."""
    return {
        "port": port,
        "baud": str(baudrate),
        "expected_rate_hz": str(expected_rate_hz or ""),
        "uplink_rate_hz": str(uplink_rate_hz or ""),
        "clock": clock,
    }
