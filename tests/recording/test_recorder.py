"""The recorder: what a run hands it ends up in the file, however the frames were timed."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader

from tests.fsp.test_decoder import stream
from wftool.fsp import StateDecoder
from wftool.recording.recorder import FRAME_TOPIC, Recorder


@pytest.mark.parametrize("record_format", ["ros2", "json"])
def test_frames_decoded_without_arrival_times_are_recorded(tmp_path: Path, record_format):
    """A capture decoded without arrival times has no OBC times: its frames are logged at
    the time they are recorded, in either format, not refused."""
    path = tmp_path / "run.mcap"
    packets = StateDecoder().feed(stream(range(10), e1=True))
    assert packets and packets[0].arrival_time is None
    with Recorder(path, None, {}, record_format=record_format) as recorder:
        recorder.packets(packets, None)
    with open(path, "rb") as handle:
        topics = [channel.topic for _, channel, _ in make_reader(handle).iter_messages()]
    assert len(topics) >= 20  # 2 frames a packet
    if record_format == "json":
        with open(path, "rb") as handle:
            frames = [json.loads(m.data) for _, _, m in make_reader(handle).iter_messages()]
        assert topics == [FRAME_TOPIC] * 20 and frames[0]["obc_time"] is None
