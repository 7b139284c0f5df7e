"""Polling MSP on a fixed schedule: the stock-Betaflight baseline the paper compares FSP with,
each reply stamped on reception (how the FC answers, how this asks: docs/design.md).

    poller = MspPoller(open_port("socket://127.0.0.1:5761", timeout=0), PAPER_SCHEDULE)
    result = poller.run(duration_s=30, observer=recorder)
    print(result.commands[Cmd.RAW_IMU].replies, result.commands[Cmd.RAW_IMU].sent)
"""

from __future__ import annotations

import math
import threading
import time
from array import array
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

from wftool.errors import UsageError
from wftool.fc.msp import Cmd, FrameReader, MspFrame, MspVersion, encode_request
from wftool.link.transport import Port, port_errors, read_within, selectable_fd
from wftool.stats import quantile

DEFAULT_WINDOW = 4
"""Requests in flight at most: 36 bytes of MSP v2 requests (24 of v1), far below any FC
receive buffer, and four task runs of backlog."""
REPLY_TIMEOUT_S = 0.5
"""A request unanswered this long is lost (an FC answers within a few task runs)."""


@dataclass(frozen=True)
class PollRate:
    """One command of a schedule and how often to ask for it."""

    cmd: int
    rate_hz: float

    @property
    def name(self) -> str:
        try:
            return Cmd(self.cmd).name
        except ValueError:
            return str(self.cmd)


PAPER_SCHEDULE: tuple[PollRate, ...] = (
    PollRate(Cmd.RAW_IMU, 1000.0),
    PollRate(Cmd.RC, 100.0),
    PollRate(Cmd.ATTITUDE, 100.0),
    PollRate(Cmd.ANALOG, 10.0),
)
"""The paper's MSP baseline: the IMU at 1 kHz, RC and attitude at 100 Hz, battery at 10 Hz."""


def parse_schedule(texts: Sequence[str]) -> tuple[PollRate, ...]:
    """`NAME=HZ` items (e.g. `RAW_IMU=1000`, names of `Cmd`) as a schedule."""
    rates = []
    for text in texts:
        name, equals, value = text.partition("=")
        try:
            cmd = Cmd[name.strip().upper().removeprefix("MSP_")]
            rate = float(value) if equals else float("nan")
        except (KeyError, ValueError):
            known = ", ".join(rate.name for rate in PAPER_SCHEDULE)
            raise UsageError(
                f"expected NAME=HZ with an MSP command name (e.g. {known}), got {text!r}"
            ) from None
        if not 0 < rate <= 10_000:
            raise UsageError(f"{text!r}: the rate must be above 0 and at most 10000 Hz")
        rates.append(PollRate(cmd, rate))
    return tuple(rates)


def describe(schedule: Sequence[PollRate], window: int) -> str:
    """The schedule in words, for the user to see what is asked."""
    rates = ", ".join(f"{rate.name} {rate.rate_hz:g} Hz" for rate in schedule)
    total = sum(rate.rate_hz for rate in schedule)
    return (
        f"{rates} ({total:g} requests/s), at most {window} in flight; replies stamped on reception"
    )


def check_poll(schedule: Sequence[PollRate], window: int) -> None:
    """A schedule and window a poller can run, or `UsageError`."""
    if not schedule:
        raise UsageError("the MSP schedule is empty")
    if len({rate.cmd for rate in schedule}) != len(schedule):
        raise UsageError("each command may appear once in the schedule")
    if window < 1:
        raise UsageError(f"the request window must be at least 1, not {window}")


@dataclass(frozen=True)
class MspReply:
    """One reply, stamped on reception."""

    cmd: int
    payload: bytes
    t: float
    """OBC monotonic time (s) at which the read that completed the reply returned."""
    error: bool = False
    """`$M!`/`$X!`: the FC did not know the command."""
    requested_at: float | None = None
    """When the request it answers was written; None if none was waiting for it."""


class PollObserver(Protocol):
    """What sees a run as it happens (the recording): the bytes both ways, and the replies."""

    def connected(self, t: float) -> None: ...

    def request(self, t: float, wire: bytes) -> None: ...

    def read(self, t: float, data: bytes) -> None: ...

    def reply(self, reply: MspReply) -> None: ...

    def disconnected(self, t: float) -> None: ...


@dataclass
class CommandStats:
    """How one command of the schedule fared."""

    name: str
    rate_hz: float
    slots: int = 0
    """Slots that came during the run (duration × rate); each was sent, skipped or missed."""
    sent: int = 0
    skipped: int = 0
    """Slots not sent: the window had no room before the command's next slot came."""
    missed: int = 0
    """Slots that passed while the poller was late (not sent)."""
    replies: int = 0
    error_replies: int = 0
    lost: int = 0
    """Requests never answered: overtaken by a later reply, or given up after the timeout."""
    latencies_s: array = field(default_factory=lambda: array("d"), repr=False)
    """Per matched reply: reception minus request time."""

    def as_json(self, duration_s: float) -> dict:
        latency = sorted(self.latencies_s)

        def pick(q: float) -> float | None:
            return quantile(latency, q) * 1e3 if latency else None

        return {
            "command": self.name,
            "rate_hz": self.rate_hz,
            "slots": self.slots,
            "sent": self.sent,
            "skipped": self.skipped,
            "missed": self.missed,
            "replies": self.replies,
            "error_replies": self.error_replies,
            "lost": self.lost,
            "sent_rate_hz": self.sent / duration_s if duration_s > 0 else 0.0,
            "reply_rate_hz": self.replies / duration_s if duration_s > 0 else 0.0,
            "latency_median_ms": pick(0.5),
            "latency_p99_ms": pick(0.99),
        }


@dataclass
class PollResult:
    """What a run asked and got, per command (in schedule order)."""

    duration_s: float
    window: int
    version: int
    commands: dict[int, CommandStats]
    corrupt_frames: int = 0
    """Frames with a bad checksum (dropped)."""
    stray_replies: int = 0
    """Replies no request was waiting for (e.g. late answers from before the run)."""
    echoed_requests: int = 0
    """Requests that came back on the link (it echoes what it gets); never replies."""
    interrupted: bool = False
    """Ctrl-C ended the run."""

    def as_json(self) -> dict:
        return {
            "duration_s": self.duration_s,
            "window": self.window,
            "msp_version": self.version,
            "corrupt_frames": self.corrupt_frames,
            "stray_replies": self.stray_replies,
            "echoed_requests": self.echoed_requests,
            "interrupted": self.interrupted,
            "commands": [stats.as_json(self.duration_s) for stats in self.commands.values()],
        }


class MspPoller:
    """Polls `schedule` on an open link (how: docs/design.md)."""

    def __init__(
        self,
        link: Port,
        schedule: Sequence[PollRate] = PAPER_SCHEDULE,
        *,
        window: int = DEFAULT_WINDOW,
        version: MspVersion = MspVersion.V1,
        reply_timeout_s: float = REPLY_TIMEOUT_S,
        now: Callable[[], float] = time.monotonic,
    ) -> None:
        check_poll(schedule, window)
        self.link = link
        self.schedule = tuple(schedule)
        self.window = window
        self.version = version
        self.reply_timeout_s = reply_timeout_s
        self._now = now
        self._wires = {rate.cmd: encode_request(rate.cmd, b"", version) for rate in self.schedule}
        self._fd = selectable_fd(link)
        self._in_flight: deque[tuple[int, float]] = deque()
        self._waiting: dict[int, float] = {}
        self._frames = FrameReader()

    def run(
        self,
        duration_s: float | None,
        observer: PollObserver | None = None,
        stop: threading.Event | None = None,
    ) -> PollResult:
        """Poll for `duration_s` (None: until `stop` is set or Ctrl-C), then wait up to the
        reply timeout for the answers still due. Ctrl-C ends the run like `stop`
        (`PollResult.interrupted`); port failures raise `PortError`."""
        if duration_s is not None and not duration_s > 0:
            raise UsageError(f"the duration must be positive, not {duration_s:g} s")
        stats = {rate.cmd: CommandStats(rate.name, rate.rate_hz) for rate in self.schedule}
        result = PollResult(0.0, self.window, int(self.version), stats)
        self._in_flight.clear()
        self._waiting.clear()
        self._frames = FrameReader()
        with port_errors(self.link.port or "link"):
            self.link.reset_input_buffer()
            start = self._now()
            end = start + duration_s if duration_s is not None else math.inf
            if observer is not None:
                observer.connected(start)
            try:
                self._poll(start, end, result, observer, stop)
                self._drain(result, observer)
            except KeyboardInterrupt:
                result.interrupted = True
            finally:
                finished = self._now()
                result.duration_s = min(finished, end) - start
                for cmd, _ in self._in_flight:
                    stats[cmd].lost += 1
                for cmd in self._waiting:  # the run ended before the window had room
                    stats[cmd].skipped += 1
                self._in_flight.clear()
                self._waiting.clear()
                if observer is not None:
                    observer.disconnected(finished)
        return result

    def _poll(
        self,
        start: float,
        end: float,
        result: PollResult,
        observer: PollObserver | None,
        stop: threading.Event | None,
    ) -> None:
        now, stats, in_flight = self._now, result.commands, self._in_flight
        periods = [1.0 / rate.rate_hz for rate in self.schedule]
        commands = [rate.cmd for rate in self.schedule]
        index = {cmd: i for i, cmd in enumerate(commands)}
        next_slot = [start] * len(commands)
        waiting = self._waiting  # command -> the time of its slot waiting for room
        t = start
        while t < end and not (stop is not None and stop.is_set()):
            for i, cmd in enumerate(commands):
                if next_slot[i] > t:
                    continue
                command = stats[cmd]
                slots = int((t - start) / periods[i]) + 1  # slots 0 .. slots - 1 have come
                command.missed += slots - command.slots - 1  # came and went while we were away
                command.slots = slots
                if cmd in waiting:
                    command.skipped += 1  # its successor came before the window had room
                waiting[cmd] = start + (slots - 1) * periods[i]
                next_slot[i] = start + slots * periods[i]
            self._expire(stats, t)
            # The waiting slots in the order they came, while the window has room.
            for cmd in sorted(waiting, key=waiting.__getitem__):
                if len(in_flight) >= self.window:
                    break
                sent_at = now()
                if sent_at >= next_slot[index[cmd]]:
                    continue  # its slot went by while this program was held up: skipped
                del waiting[cmd]
                wire = self._wires[cmd]
                self.link.write(wire)
                in_flight.append((cmd, sent_at))
                stats[cmd].sent += 1
                if observer is not None:
                    observer.request(sent_at, wire)
            self._receive(min(min(next_slot), end) - now(), result, observer)
            t = now()

    def _drain(self, result: PollResult, observer: PollObserver | None) -> None:
        """The replies still due for requests already sent, up to the reply timeout."""
        deadline = self._now() + self.reply_timeout_s
        while self._in_flight and (left := deadline - self._now()) > 0:
            self._receive(left, result, observer)

    def _receive(self, timeout: float, result: PollResult, observer: PollObserver | None) -> None:
        data = read_within(self.link, self._fd, timeout)
        if not data:
            return
        t = self._now()
        if observer is not None:
            observer.read(t, data)
        frames = self._frames.feed(data)
        result.corrupt_frames = self._frames.corrupt
        result.echoed_requests = self._frames.requests
        self._replies(frames, t, result, observer)

    def _expire(self, stats: dict[int, CommandStats], t: float) -> None:
        in_flight = self._in_flight
        while in_flight and t - in_flight[0][1] > self.reply_timeout_s:
            stats[in_flight.popleft()[0]].lost += 1

    def _replies(
        self, frames: list[MspFrame], t: float, result: PollResult, observer: PollObserver | None
    ) -> None:
        """The frames a read completed, stamped `t`, each matched to its request."""
        in_flight, stats = self._in_flight, result.commands
        for frame in frames:
            requested_at = None
            if any(cmd == frame.cmd for cmd, _ in in_flight):
                while True:
                    cmd, sent_at = in_flight.popleft()
                    if cmd == frame.cmd:
                        requested_at = sent_at
                        break
                    stats[cmd].lost += 1  # overtaken: the FC never answered it
            command = stats.get(frame.cmd)
            if command is None or requested_at is None:
                result.stray_replies += 1
            else:
                command.replies += 1
                command.error_replies += frame.error
                command.latencies_s.append(t - requested_at)
            if observer is not None:
                observer.reply(MspReply(frame.cmd, frame.payload, t, frame.error, requested_at))
