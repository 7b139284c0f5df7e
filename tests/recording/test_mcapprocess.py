"""The recording's writer process: the caller's thread does no chunk work, the file holds
what was added (read back by the `mcap` reader), failures come back once."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from tests.recording.test_rosbag import file_size_limit
from wftool.errors import RecordingError, UsageError
from wftool.recording.mcapfile import CHUNK_SIZE
from wftool.recording.mcapprocess import McapProcess


def open_writer(path: Path) -> tuple[McapProcess, int]:
    writer = McapProcess(path, "", "test")
    schema = writer.register_schema("test.Message", "jsonschema", b"{}")
    return writer, writer.register_channel("/test", "json", schema)


def message(index: int) -> bytes:
    return b'{"index": %d, "pad": "%s"}' % (index, b"x" * (index % 200))


def test_chunk_writes_cost_the_adding_thread_no_cpu(tmp_path: Path):
    """Messages added in reads, as a reading loop adds them, through several chunks: no
    add_message call spends a chunk's work (6-13 ms of CPU in the `mcap` writer) on the
    caller's thread. (CPU, not wall time: what the machine does meanwhile does not count.)"""
    writer, channel = open_writer(tmp_path / "run.mcap")
    costs = []
    added = 0
    while added * 150 < 5 * CHUNK_SIZE:
        for _ in range(20):
            started = time.thread_time()
            writer.add_message(channel, added, message(added))
            costs.append(time.thread_time() - started)
            added += 1
        time.sleep(0.0005)
    writer.finish()
    with open(tmp_path / "run.mcap", "rb") as handle:
        summary = make_reader(handle).get_summary()
    assert len(summary.chunk_indexes) >= 4
    assert summary.statistics.message_count == added == writer.message_counts[channel]
    assert max(costs) < 0.002, max(costs)


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
