"""Recording a run and replaying it: same summary, readable files, damage reported."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from mcap.reader import make_reader

from tests.verify.test_monitor import feed_steady
from wftool.errors import UsageError
from wftool.verify.monitor import StreamMonitor
from wftool.verify.recording import FRAME_TOPIC, Event, Recorder, replay_recording


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
