"""The live verify loop: read a port, hand each event to the monitor and the sinks, send the
commands (the uplink pattern, or a commander's), reconnect.

    summary = run_live(LiveOptions("socket://127.0.0.1:5762", 2_000_000, 10.0), monitor,
                       sinks=[recorder])

A port that cannot be opened at the start is a `PortError` (the caller's connection error);
one that goes away later is counted and reopened with backoff, so a rebooting FC or a
restarted SITL is survived.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

from wftool.errors import ClockError, PortError, UsageError
from wftool.fsp import ArmingAction, CommandPacket, FspPort, StatePacket
from wftool.recording.events import Event, Sink
from wftool.verify.monitor import HealthSampler, StreamMonitor, StreamSummary
from wftool.verify.uplink import UplinkPattern

REFRESH_S = 0.25
READ_TIMEOUT_S = 0.05
BACKOFF_FIRST_S = 0.1
BACKOFF_MAX_S = 2.0
LEAD_MAX_S = 0.15
"""`fsp_cmd_timeout_ms`'s maximum: a timed command further ahead is refused by any FC."""


def check_duration(seconds: float | None, name: str = "the duration") -> float | None:
    """`seconds`, if it can be the length of a run: None (until stopped), or finite and
    positive; else a `UsageError` naming it as `name`."""
    if seconds is not None and not (math.isfinite(seconds) and seconds > 0):
        raise UsageError(f"{name} must be a positive number of seconds, not {seconds:g}")
    return seconds


@dataclass(frozen=True)
class LiveOptions:
    url: str
    baudrate: int
    duration_s: float | None = None
    uplink_rate_hz: float | None = None
    """Send the uplink pattern at this rate; None sends nothing."""
    uplink_lead_s: float | None = None
    """Send the pattern as timed commands (E4, spec §13), each for this long after it is
    sent, mapped to FC time by the run's clock; None: immediate. Immediate until the clock
    locks and the FC has reported its command timeout (E3): a lead of that timeout or more
    stops the run (`UsageError`), as the FC would refuse every command."""

    def __post_init__(self) -> None:
        check_duration(self.duration_s)
        check_uplink_lead(self.uplink_lead_s)
        if self.uplink_lead_s is not None and not self.uplink_rate_hz:
            raise UsageError("a lead times the uplink pattern's commands: send the pattern too")


def check_uplink_lead(lead_s: float | None, name: str = "the uplink lead") -> float | None:
    """`lead_s`, if timed commands can be sent that far ahead: None, or 0 to 0.15 s (the
    longest command timeout, past which the FC refuses any); else a `UsageError`."""
    if lead_s is not None and not (math.isfinite(lead_s) and 0 <= lead_s <= LEAD_MAX_S):
        raise UsageError(
            f"{name} must be 0 to {LEAD_MAX_S * 1e3:g} ms (the FC refuses a timed command "
            f"due its command timeout or more ahead), not {lead_s * 1e3:g} ms"
        )
    return lead_s


def check_lead_against_timeout(
    lead_s: float, timeout_ms: int, name: str = "the uplink lead"
) -> float:
    """`lead_s`, if an FC whose command timeout is `timeout_ms` (E3) takes timed commands
    sent that far ahead; else a one-line `UsageError`: it refuses every one (spec §13)."""
    if lead_s * 1e3 >= timeout_ms:
        raise UsageError(
            f"{name} of {lead_s * 1e3:g} ms is at least the FC's command timeout "
            f"({timeout_ms} ms, fsp_cmd_timeout_ms): the FC refuses every timed command "
            f"due that far ahead; lead by less than {timeout_ms} ms"
        )
    return lead_s


class Commander(Protocol):
    """What decides the commands a live run sends (the uplink pattern, a ROS 2 node): the loop
    asks at `due` (math.inf: only when a read returns anyway) for `command(t)`, the command
    to send at `t` (None: nothing), tells `sent(t)` once the port took it, and then sends
    the arming request (spec §14) `arming(t)` asks for with it, if any."""

    @property
    def due(self) -> float: ...

    def command(self, t: float) -> Sequence[int] | None: ...

    def sent(self, t: float) -> None: ...

    def arming(self, t: float) -> ArmingAction | None: ...


def run_live(
    options: LiveOptions,
    monitor: StreamMonitor,
    sinks: Sequence[Sink] = (),
    on_refresh: Callable[[StreamSummary], None] | None = None,
    stop: threading.Event | None = None,
    now: Callable[[], float] = time.monotonic,
    commander: Commander | None = None,
) -> StreamSummary:
    """Verify the stream on `options.url` until the duration is up or `stop` is set; the
    final summary. The monitor decodes (one decoder for the whole run); each sink gets
    every event, then each read's packets with a health snapshot (at most 10 Hz);
    `on_refresh` gets a summary four times a second. Commands come from the uplink pattern
    (`options.uplink_rate_hz`) or from `commander`, never both."""
    if commander is not None and options.uplink_rate_hz:
        raise UsageError("the uplink pattern and another commander cannot both send commands")
    return _LiveRun(options, monitor, sinks, now, commander).run(on_refresh, stop)


class Dispatcher:
    """What a run does with each thing it sees: the event to every sink, then to the
    monitor; a read's packets to every sink, with the latest health snapshot."""

    def __init__(self, monitor: StreamMonitor, sinks: Sequence[Sink] = ()) -> None:
        self.monitor = monitor
        self.sinks = tuple(sinks)
        self._health = HealthSampler(monitor)

    def event(self, event: Event, command: CommandPacket | None = None) -> list[StatePacket]:
        """Dispatch `event` (`command`: the packet a command event sent); the packets a
        read completed, which the sinks have then been given too."""
        for sink in self.sinks:
            sink.event(event)
        packets = self.monitor.apply(event, command)
        if event.kind == "bytes" and self.sinks:
            health = self._health.sample(packets, event.t)
            for sink in self.sinks:
                sink.packets(packets, health)
        return packets


class _LiveRun:
    def __init__(
        self,
        options: LiveOptions,
        monitor: StreamMonitor,
        sinks: Sequence[Sink],
        now: Callable[[], float],
        commander: Commander | None = None,
    ) -> None:
        self._options = options
        self._monitor = monitor
        self._emit = Dispatcher(monitor, sinks).event
        self._now = now
        self._port: FspPort | None = None
        self._connected_once = False
        self._backoff = BACKOFF_FIRST_S
        self._retry_at = 0.0
        self._commander = commander

    def run(
        self, on_refresh: Callable[[StreamSummary], None] | None, stop: threading.Event | None
    ) -> StreamSummary:
        start = self._now()
        duration_s, uplink_rate_hz = self._options.duration_s, self._options.uplink_rate_hz
        end = start + duration_s if duration_s is not None else math.inf
        self._retry_at = next_refresh = start
        if uplink_rate_hz:
            self._commander = UplinkPattern(uplink_rate_hz, start)
        try:
            while True:
                t = self._now()
                if t >= end or (stop is not None and stop.is_set()):
                    break
                port = self._port
                if port is None:
                    connected = self._connect(t, end)
                    if connected is None:
                        continue
                    t, port = connected
                t = self._exchange(port, t)
                if on_refresh is not None and t >= next_refresh:
                    on_refresh(self._monitor.summary(t))
                    next_refresh = t + REFRESH_S
        finally:
            t = self._now()
            if self._port is not None:
                self._drop(t)
        return self._monitor.summary(t)

    def _connect(self, t: float, end: float) -> tuple[float, FspPort] | None:
        """Open the port if its retry is due: the time it opened, and it; None while it
        cannot be."""
        if t < self._retry_at:
            time.sleep(min(self._retry_at - t, end - t, READ_TIMEOUT_S))
            return None
        try:
            port = FspPort(self._options.url, self._options.baudrate).open()
        except PortError:
            if not self._connected_once:
                raise  # the caller's connection error, not a dropout
            self._backoff = min(2 * self._backoff, BACKOFF_MAX_S)  # a rebooting FC takes seconds
            self._retry_at = t + self._backoff
            return None
        self._port = port
        self._connected_once = True
        t = self._now()
        self._emit(Event("connected", t))
        self._backoff = BACKOFF_FIRST_S
        return t, port

    def _exchange(self, port: FspPort, t: float) -> float:
        """One read, and the command that is due; the time the read returned, or the command
        was sent (`t` if the port went away, which drops it)."""
        commander = self._commander
        # A read returns at once when bytes come; else it waits no longer than the next command.
        wait = READ_TIMEOUT_S
        if commander is not None:
            wait = max(0.0, min(wait, commander.due - t))
        try:
            data = port.read_bytes(wait)
            t = self._now()
            if data:
                self._emit(Event("bytes", t, data))
            if commander is not None and t >= commander.due:
                rc = commander.command(t)
                if rc is not None:
                    rc = tuple(rc)
                    # Its own time, after the read's bytes were dispatched (decoded, recorded):
                    # a timed command's lead counts from when it leaves, not from the read.
                    t = self._now()
                    command = self._send(port, rc, t)
                    self._emit(Event("command", t, rc=rc), command)
                    commander.sent(t)
                    action = commander.arming(t)
                    if action is not None:
                        port.send_arming(action, now=t)
        except PortError:
            self._drop(self._now())
        return t

    def _send(self, port: FspPort, rc: tuple[int, ...], t: float) -> CommandPacket:
        """Send `rc`; a `UsageError` if it holds a value the FC's pulse range leaves out (spec
        §5: the FC would refuse it whole), nothing sent."""
        lead = self._options.uplink_lead_s
        decoder = self._monitor.decoder
        status = decoder.uplink_status
        try:
            # Until the FC says its command timeout, and the run's clock locks, the pattern
            # goes out as immediate commands.
            if lead is not None and status is not None:
                check_lead_against_timeout(lead, status.timeout_ms)
                try:
                    return port.send_command(rc, now=t, at=t + lead, decoder=decoder)
                except ClockError:
                    pass
            return port.send_command(rc, now=t)
        except ValueError as exc:
            raise UsageError(f"cannot send the command {rc}: {exc}") from None

    def _drop(self, t: float) -> None:
        """The port is gone (or the run is over): close it, and retry after the backoff."""
        port, self._port = self._port, None
        if port is not None:
            port.close()
        self._emit(Event("disconnected", t))
        self._retry_at = t + self._backoff
