"""Makes the recordings here as an earlier wftool wrote them; tests read them with today's.

Run from an export of the commit that writes the layout to keep, with the export's `wftool`
first on PYTHONPATH (these tests' helpers from this checkout):
`python tests/recording/data/make_recordings.py tests/recording/data NAME...`. RECORDINGS:
3cce0e6, one ROS 2 `StreamEvent` message per event, in the chunks of the frames;
UPLINK_RECORDING: e1f7f62, before the FC's uplink statuses had a topic of their own, of an
FC that sends them; STATUS_V1_RECORDING: 301153b, the `UplinkStatus` message before it said
who flies (spec §15), of an FC that sends 36-byte statuses.
"""

from __future__ import annotations

import sys
from pathlib import Path

from tests.recording.test_rosbag import flight
from wftool.recording.events import Event
from wftool.recording.recorder import Recorder
from wftool.verify.monitor import HealthSampler, StreamMonitor

RECORDINGS = {"ros2-streamevent.mcap": "ros2", "json.mcap": "json"}
UPLINK_RECORDING = "ros2-no-uplink-topic.mcap"
STATUS_V1_RECORDING = "ros2-uplink-status-before-authority.mcap"
PORT = "socket://sim:5762"


def events() -> list[Event]:
    """A run with a command, a reconnect that cuts a read short, and a last disconnect."""
    reads = flight(90, seed=7)
    t, out = 100.0, [Event("connected", 100.0)]
    for index, data in enumerate(reads):
        t += 0.0057
        if index == 10:
            out.append(Event("command", t, rc=(1100, 1500, 1500, 1000, 1000, 1000)))
        if index == 20:
            out += [Event("disconnected", t), Event("connected", t + 0.5)]
            t += 0.5
        out.append(Event("bytes", t, data[: len(data) - 5] if index == 19 else data))
    return [*out, Event("disconnected", t)]


def uplink_events() -> list[Event]:
    """A run of an FC that reports on its uplink (E3): its statuses among the packets."""
    t, out = 100.0, [Event("connected", 100.0)]
    for data in flight(160, seed=7, statuses=True):
        t += 0.0057
        out.append(Event("bytes", t, data))
    return [*out, Event("disconnected", t)]


def run(recorder: Recorder | None = None, events=events) -> StreamMonitor:
    """The run of `events()` as its live loop saw it, recorded by `recorder` if given."""
    monitor = StreamMonitor(PORT)
    sampler = HealthSampler(monitor)
    for event in events():
        if recorder is not None:
            recorder.event(event)
        if event.kind == "connected":
            monitor.connected(event.t)
        elif event.kind == "disconnected":
            monitor.disconnected(event.t)
        elif event.kind == "bytes":
            packets = monitor.feed(event.data, event.t)
            if recorder is not None:
                recorder.packets(packets, sampler.sample(packets, event.t))
    return monitor


def main(directory: Path, names: list[str]) -> None:
    metadata = {"port": PORT, "clock": "envelope"}
    for name in names:
        record_format = RECORDINGS.get(name, "ros2")
        with Recorder(directory / name, None, metadata, record_format=record_format) as recorder:
            uplink = name in (UPLINK_RECORDING, STATUS_V1_RECORDING)
            run(recorder, uplink_events if uplink else events)


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2:])
