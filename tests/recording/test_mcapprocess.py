"""The recording's writer process: the caller's thread does no chunk work, the file holds
what was added (read back by the `mcap` reader), failures come back once."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from types import FrameType

import pytest
from mcap.reader import make_reader

from tests.recording.test_rosbag import file_size_limit
from wftool.errors import RecordingError, UsageError
from wftool.recording import mcapprocess
from wftool.recording.mcapfile import CHUNK_SIZE
from wftool.recording.mcapprocess import McapProcess

BATCHING_CALLS = (
    "Struct.pack",
    "monotonic",
    "len",
    "BufferedWriter.fileno",
    "write",
    "memoryview.__exit__",
    "bytearray.clear",
    "setprofile",
)
"""The C functions add_message calls on the caller's thread: packing, the clock, the pipe
write (and the profile's own switch-off)."""


def open_writer(path: Path) -> tuple[McapProcess, int]:
    writer = McapProcess(path, "", "test")
    schema = writer.register_schema("test.Message", "jsonschema", b"{}")
    return writer, writer.register_channel("/test", "json", schema)


def message(index: int) -> bytes:
    return b'{"index": %d, "pad": "%s"}' % (index, b"x" * (index % 200))


def test_the_adding_thread_runs_no_chunk_work(tmp_path: Path):
    """Messages added in reads, as a reading loop adds them, through several chunks: on the
    caller's thread add_message runs only its own batching, a pack per message and a pipe
    write per batch; a chunk's work (6-13 ms of CPU in the `mcap` writer) runs in the writer
    process. (What runs, not its CPU time: with interrupts and the VM host charged to
    whichever thread runs, a thread's CPU time has millisecond outliers that are no work of
    its own; the stalls a chunk gives are measured in `wftool bench record`.)"""
    writer, channel = open_writer(tmp_path / "run.mcap")
    ran: set[tuple[str, str]] = set()

    def profile(frame: FrameType, event: str, arg: object) -> None:
        if event == "call":
            ran.add((frame.f_code.co_filename, frame.f_code.co_qualname))
        elif event == "c_call":
            ran.add(("C", getattr(arg, "__qualname__", "")))

    added = 0
    while added * 150 < 5 * CHUNK_SIZE:
        for _ in range(20):
            data = message(added)
            sys.setprofile(profile)  # this thread's alone
            writer.add_message(channel, added, data)
            sys.setprofile(None)
            added += 1
        time.sleep(0.0005)
    writer.finish()
    with open(tmp_path / "run.mcap", "rb") as handle:
        summary = make_reader(handle).get_summary()
    assert len(summary.chunk_indexes) >= 4
    assert summary.statistics.message_count == added == writer.message_counts[channel]
    own = {(mcapprocess.__file__, f"McapProcess.{name}") for name in ("add_message", "_flush")}
    batching = {("C", name) for name in BATCHING_CALLS}
    assert ran - own - batching == set()
    assert ("C", "write") in ran  # the batches went


def test_the_file_holds_every_message_and_says_so(tmp_path: Path):
    path = tmp_path / "run.mcap"
    writer, channel = open_writer(path)
    writer.add_metadata("run", {"port": "test"})
    for index in range(3000):
        writer.add_message(channel, 1000 + index, message(index), publish_time=7)
    writer.finish()
    with open(path, "rb") as handle:
        reader = make_reader(handle)
        messages = [m for _, _, m in reader.iter_messages()]
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert [m.data for m in messages] == [message(index) for index in range(3000)]
    assert {m.publish_time for m in messages} == {7}
    assert metadata == {"run": {"port": "test"}}
    assert (dict(writer.message_counts), writer.time_range) == ({channel: 3000}, (1000, 3999))


def test_a_taken_or_unwritable_path_fails_in_the_constructor(tmp_path: Path):
    taken = tmp_path / "taken.mcap"
    taken.write_bytes(b"keep me")
    with pytest.raises(UsageError, match="already exists"):
        McapProcess(taken, "", "test")
    assert taken.read_bytes() == b"keep me"
    with pytest.raises(UsageError, match="cannot write the recording"):
        McapProcess(tmp_path / "no-such-directory" / "run.mcap", "", "test")


def test_a_full_disk_is_raised_once_and_the_file_is_readable(tmp_path: Path):
    path = tmp_path / "run.mcap"
    with file_size_limit(300_000):
        writer, channel = open_writer(path)
    raised = []
    for index in range(60_000):
        try:
            writer.add_message(channel, index, message(index))
        except RecordingError as exc:
            raised.append((index, str(exc)))
    writer.finish()  # nothing more to say
    assert len(raised) == 1 and "finished and readable" in raised[0][1]
    with open(path, "rb") as handle:
        read = [m.log_time for _, _, m in make_reader(handle).iter_messages()]
    assert 0 < len(read) == sum(writer.message_counts.values()) < raised[0][0]
    assert read == list(range(len(read)))


def test_discard_leaves_nothing(tmp_path: Path):
    path = tmp_path / "run.mcap"
    writer, channel = open_writer(path)
    writer.add_message(channel, 1, b"{}")
    writer.discard()
    assert not path.exists()
