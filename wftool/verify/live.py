"""The live verify loop: read a port, feed the monitor, record, drive the uplink, reconnect.

Runs until `duration_s` passes or `stop` is set. A port that cannot be opened at the start
is a `PortError` (the caller's connection error); one that goes away later is shown,
counted, and reopened with backoff — a rebooting FC or a restarted SITL is survived.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from wftool.errors import PortError, UsageError
from wftool.fsp import FspPort, StatePacket
from wftool.recording.events import Event
from wftool.recording.recorder import Recorder
from wftool.verify.monitor import HealthSampler, StreamMonitor, StreamSummary
from wftool.verify.uplink import pattern_command

if TYPE_CHECKING:
    from wftool.verify.foxglove import FoxgloveLive

REFRESH_S = 0.25
READ_TIMEOUT_S = 0.05
BACKOFF_FIRST_S = 0.1
BACKOFF_MAX_S = 2.0


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

    def __post_init__(self) -> None:
        check_duration(self.duration_s)


def run_live(
    options: LiveOptions,
    monitor: StreamMonitor,
    recorder: Recorder | None = None,
    on_refresh: Callable[[StreamSummary], None] | None = None,
    stop: threading.Event | None = None,
    now: Callable[[], float] = time.monotonic,
    on_packets: Callable[[Sequence[StatePacket], float], None] | None = None,
    live_view: FoxgloveLive | None = None,
) -> StreamSummary:
    """Verify the stream on `options.url` until the duration is up; the final summary.

    The port is only read here; the monitor decodes (one decoder per connection). Each
    read's packets go to `recorder` and `live_view` with a health snapshot (at most 10 Hz);
    `on_packets` gets them and their arrival time, after the monitor has them.
    """
    start = now()
    end = start + options.duration_s if options.duration_s is not None else float("inf")
    reader: FspPort | None = None
    backoff = BACKOFF_FIRST_S
    retry_at = start
    command_index = 0
    period = 1.0 / options.uplink_rate_hz if options.uplink_rate_hz else None
    next_command = start
    next_refresh = start
    connected_once = False
    health = HealthSampler(monitor)

    def record(event: Event) -> None:
        if recorder is not None:
            recorder.event(event)

    def drop(t: float) -> None:
        nonlocal reader, retry_at
        if reader is not None:
            reader.close()
            reader = None
        monitor.disconnected(t)
        record(Event("disconnected", t))
        retry_at = t + backoff

    try:
        while True:
            t = now()
            if t >= end or (stop is not None and stop.is_set()):
                break
            if reader is None:
                if t < retry_at:
                    time.sleep(min(retry_at - t, end - t, READ_TIMEOUT_S))
                    continue
                try:
                    reader = FspPort(options.url, options.baudrate).open()
                except PortError:
                    if not connected_once:
                        raise  # the caller's connection error, not a dropout
                    backoff = min(2 * backoff, BACKOFF_MAX_S)
                    retry_at = t + backoff
                    continue
                t = now()
                connected_once = True
                monitor.connected(t)
                record(Event("connected", t))
                backoff = BACKOFF_FIRST_S
            wait = READ_TIMEOUT_S
            if period is not None:
                wait = max(0.0, min(wait, next_command - t))
            try:
                data = reader.read_bytes(wait)
                t = now()
                if data:
                    record(Event("bytes", t, data))
                    packets = monitor.feed(data, t)
                    if recorder is not None or live_view is not None:
                        snapshot = health.sample(packets, t)
                        if recorder is not None:
                            recorder.packets(packets, snapshot)
                        if live_view is not None:
                            live_view.packets(packets, snapshot)
                    if on_packets is not None and packets:
                        on_packets(packets, t)
                if period is not None and t >= next_command:
                    rc = pattern_command(command_index, options.uplink_rate_hz)
                    command = reader.send_command(rc, now=t)
                    monitor.command_sent(rc, t, command)
                    record(Event("command", t, rc=rc))
                    command_index += 1
                    next_command = max(next_command + period, t - period)
            except PortError:
                drop(now())
            if on_refresh is not None and t >= next_refresh:
                on_refresh(monitor.summary(t))
                next_refresh = t + REFRESH_S
    finally:
        t = now()
        if reader is not None:
            reader.close()
            monitor.disconnected(t)
            record(Event("disconnected", t))
    return monitor.summary(t)
