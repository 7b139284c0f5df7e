"""Recording a run and replaying it: same summary, readable files, damage reported."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from mcap.reader import make_reader

from tests.fsp.test_twoway import RC
from tests.recording.data.make_recordings import (
    RECORDINGS,
    STATUS_V1_RECORDING,
    UPLINK_RECORDING,
    events,
    run,
    uplink_events,
)
from tests.verify.test_monitor import feed_steady, feed_two_way
from wftool.errors import UsageError
from wftool.recording.events import Event, run_metadata
from wftool.recording.reader import RecordingReader, recording_columns, recording_topics
from wftool.recording.recorder import FRAME_TOPIC, Recorder
from wftool.verify.monitor import StreamMonitor
from wftool.verify.session import replay_recording

DATA = Path(__file__).parent / "data"


class RecordingMonitor(StreamMonitor):
    """Sends every event to a recorder as well, the way the live loop does."""

    def __init__(self, recorder: Recorder) -> None:
        super().__init__("socket://sim:5762")
        self.recorder = recorder

    def connected(self, t):
        super().connected(t)
        self.recorder.event(Event("connected", t))

    def disconnected(self, t):
        super().disconnected(t)
        self.recorder.event(Event("disconnected", t))

    def feed(self, data, t):
        self.recorder.event(Event("bytes", t, data))
        packets = super().feed(data, t)
        self.recorder.packets(packets)
        return packets


def record_two_connections(
    mcap: Path, table: Path | None, *, reboot: bool = False
) -> RecordingMonitor:
    """Record a run of 300 packets, a reconnect, a chunk of garbage and 100 packets more;
    with `reboot`, the FC then restarts and sends 50 packets from its boot time again."""
    with Recorder(mcap, table, {"port": "socket://sim:5762"}, record_format="json") as recorder:
        live = RecordingMonitor(recorder)
        live.connected(0.0)
        t = feed_steady(live, range(300), 0.0)
        live.disconnected(t)
        live.connected(t + 0.5)
        live.feed(b"garbage\x00", t + 0.6)
        t = feed_steady(live, range(300, 400), t + 0.6)
        if reboot:
            t = feed_steady(live, range(50), t + 2.0)
        live.disconnected(t)
    return live


def test_replay_gives_the_same_summary(tmp_path: Path):
    mcap, table = tmp_path / "run.mcap", tmp_path / "run.csv"
    live = record_two_connections(mcap, table)
    replayed = replay_recording(mcap).summary()
    assert replayed == live.summary()
    assert replayed.reconnects == 1 and replayed.frames == 800

    with open(mcap, "rb") as handle:
        frames = [
            json.loads(m.data)
            for _, _, m in make_reader(handle).iter_messages(topics=[FRAME_TOPIC])
        ]
    assert len(frames) == 800 and frames[0]["fc_time_us"] == 1_000_000
    rows = list(csv.DictReader(table.open()))
    assert len(rows) == 800 and rows[-1]["seq"] == "399"


def test_unfinished_or_foreign_file_is_a_clear_error(tmp_path: Path):
    bogus = tmp_path / "bogus.mcap"
    bogus.write_bytes(b"not an mcap file at all")
    with pytest.raises(UsageError, match="cannot read recording"):
        replay_recording(bogus)


def test_unwritable_path_is_a_usage_error(tmp_path: Path):
    with pytest.raises(UsageError, match="cannot write the recording"):
        Recorder(tmp_path / "missing-dir" / "run.mcap", None, {}, record_format="json")


@pytest.mark.parametrize("record_format", ["ros2", "json"])
def test_replay_pairs_time_replies_with_the_recorded_commands(tmp_path: Path, record_format: str):
    """A command event is the packet the live loop sent (seq counting from the connection,
    stamped with the event's time): a replay pairs the FC's time replies as the run did."""
    path = tmp_path / "run"
    metadata = run_metadata("socket://sim:5762", 2_000_000, None, None, "twoway")
    with Recorder(path, None, metadata, record_format=record_format) as recorder:
        live = StreamMonitor("socket://sim:5762", clock="twoway")

        def record(kind, t, payload):
            if kind == "send":
                recorder.event(Event("command", t, rc=RC))
            else:
                recorder.event(Event("bytes", t, payload))

        recorder.event(Event("connected", 0.0))
        feed_two_way(live, 6.0, record)
    replayed = replay_recording(path).summary()
    assert replayed.round_trip is not None and replayed.round_trip.count > 200
    assert replayed.two_way == live.summary().two_way
    assert replayed.round_trip == live.summary().round_trip


@pytest.mark.parametrize("name", sorted(RECORDINGS))
def test_recordings_in_an_earlier_layout_still_read(name: str):
    """Files as wftool 3cce0e6 wrote them (tests/recording/data/make_recordings.py): one ROS 2
    `StreamEvent` per event in the frames' chunks, or JSON. Every event comes back, replay
    gives what the live run gave, and the columns what the decoder fed those reads gives."""
    path = DATA / name
    expected = events()
    assert list(RecordingReader(path).events()) == expected
    assert replay_recording(path).summary() == run().summary()
    pytest.importorskip("numpy", reason="columns need wftool[analysis]")
    from tests.fsp.test_columns import assert_agree, reference

    reads = [e for e in expected if e.kind == "bytes"]
    sizes, times = [len(e.data) for e in reads], [e.t for e in reads]
    assert_agree(recording_columns(path), *reference(b"".join(e.data for e in reads), sizes,
                                                      times, connections=[20]))  # fmt: skip


def test_a_recording_from_before_the_uplink_status_topic_still_shows_the_fcs_reports():
    """A file as wftool e1f7f62 wrote it (make_recordings.py): the FC sent uplink statuses,
    the recording has no topic for them. Replay decodes them from the recorded bytes, as
    the live run of today would show them."""
    path = DATA / UPLINK_RECORDING
    assert "/fsp/uplink_status" not in recording_topics(path)
    assert list(RecordingReader(path).events()) == uplink_events()
    replayed = replay_recording(path).summary()
    assert replayed == run(events=uplink_events).summary()
    assert replayed.fc_uplink is not None and replayed.fc_uplink.status.accepted == 62


def test_a_recording_of_the_uplink_status_before_it_said_who_flies_still_reads():
    """A file as wftool 301153b wrote it (make_recordings.py): `/fsp/uplink_status` in the
    older `UplinkStatus`, which the file embeds. An independent reader decodes it by that
    schema; the events, replay and the FC's reports are today's."""
    from tests.recording.test_rosbag import read_bag

    path = DATA / STATUS_V1_RECORDING
    statuses = [message for _, message in read_bag(path)["/fsp/uplink_status"]]
    assert statuses and not hasattr(statuses[0], "authority")
    assert statuses[-1].accepted == 62 and statuses[-1].live
    assert list(RecordingReader(path).events()) == uplink_events()
    replayed = replay_recording(path).summary()
    assert replayed == run(events=uplink_events).summary()
    assert replayed.fc_uplink is not None and replayed.fc_uplink.status.authority is None
