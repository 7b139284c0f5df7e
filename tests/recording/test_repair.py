"""`repair`: a recording cut short made readable by any tool again, checked with rosbags (an
independent rosbag2/MCAP reader); never a file still being written, never what was recorded.
A run killed for real (SIGKILL) is in tests/cli/test_verify.py."""

from __future__ import annotations

from pathlib import Path

import pytest
from rosbags.rosbag2 import Reader

from tests.recording.test_rosbag import flight
from wftool.errors import UsageError
from wftool.recording.events import Event, run_metadata
from wftool.recording.mcapfile import McapFile
from wftool.recording.reader import RecordingReader
from wftool.recording.recorder import Recorder
from wftool.recording.repair import repair


def record(path: Path, reads: int = 600) -> None:
    """A ROS 2 recording of `reads` reads of a flight, planned for 20 s, closed."""
    metadata = run_metadata("socket://sim:5762", 2_000_000, None, None, duration_s=20.0)
    with Recorder(path, None, metadata) as recorder:
        recorder.event(Event("connected", 1.0))
        for index, data in enumerate(flight(reads)):
            recorder.event(Event("bytes", 1.0 + index * 0.0057, data))
        recorder.event(Event("disconnected", 1.0 + reads * 0.0057))


def rosbags_view(bag: Path) -> tuple[int, dict[str, int], dict[str, str]]:
    with Reader(bag) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert sum(1 for _ in reader.messages()) == reader.message_count
        return reader.message_count, counts, dict(reader.storage.metadata.custom)


def test_a_closed_recording_says_so_and_repairs_to_the_same_metadata(tmp_path: Path) -> None:
    bag = tmp_path / "run"
    record(bag)
    recording = RecordingReader(bag)
    assert recording.closed is True and recording.planned_s == 20.0
    assert recording.cut_short(3.4) is None
    before = rosbags_view(bag)
    assert before[2]["closed"] == "true"
    repaired = repair(bag)
    assert repaired.closed is True and repaired.listed == before[0] == repaired.messages
    after = rosbags_view(bag)
    assert after[:2] == before[:2] and after[2] == before[2] | {"repaired": after[2]["repaired"]}


def test_a_recording_still_being_written_is_not_repaired(tmp_path: Path) -> None:
    path = tmp_path / "live.mcap"
    writing = McapFile(path, "ros2", "test")
    try:
        with pytest.raises(UsageError, match=r"is being written .* once that run has ended"):
            repair(path)
    finally:
        writing.finish()
    assert repair(path).messages == 0


def test_what_is_no_mcap_file_is_a_one_line_error(tmp_path: Path) -> None:
    path = tmp_path / "notes.mcap"
    path.write_text("not a recording\n")
    with pytest.raises(UsageError, match=r"^cannot repair .*notes.mcap: it is damaged: "):
        repair(path)


def test_an_mcap_file_without_its_ending_is_written_again_and_kept(tmp_path: Path) -> None:
    whole = tmp_path / "whole.mcap"
    record(whole, reads=2000)
    cut = tmp_path / "cut.mcap"
    data = whole.read_bytes()[: int(whole.stat().st_size * 0.7)]
    cut.write_bytes(data)
    events = sum(1 for _ in RecordingReader(cut).events())
    repaired = repair(cut)
    assert repaired.kept == tmp_path / "cut.mcap.cut" and repaired.kept.read_bytes() == data
    assert repaired.metadata_path is None and repaired.closed is False
    assert any("had no ending" in line for line in repaired.describe())
    again = RecordingReader(cut)
    assert sum(1 for _ in again.events()) == events  # every event the cut file held
    assert again.cut is None and again.cut_short(1.5) == (
        "cut short at 1.5 s (of 20 planned): it was never closed (its run was killed, or its "
        "writer failed); read as far as it goes (`wftool record repair` rebuilds a bag's "
        "metadata.yaml from it)"
    )
    with Reader(cut) as reader:  # rosbags reads the file alone as a bag of one file
        assert reader.message_count == repaired.messages > 0
