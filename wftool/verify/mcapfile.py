"""An MCAP file that stays readable when the disk fills up mid-run.

The `mcap` writer keeps messages in a chunk in memory and writes each chunk (compressed,
with its message index) in one go. When such a write fails (ENOSPC, EFBIG, EIO), the file
is cut back to the end of the last complete chunk and closed with a Data End record and a
Footer without a summary section: a valid MCAP that every reader scans (the `mcap`
Python and C++ readers, rosbags, rosbag2 and Foxglove fall back to a linear scan). The
messages of the chunk that failed (up to one chunk, about a second at 1 kHz) are lost;
everything before is kept. The failure is raised once, as `RecordingError`; messages after
it are dropped.

The failed write's partial data is what frees the space the ~50-byte ending needs; only a
disk that another process filled to the last block can leave the file without an ending.
"""

from __future__ import annotations

import os
import struct
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO

from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Chunk, ChunkIndex, DataEnd, Footer, MessageIndex
from mcap.stream_reader import get_chunk_data_stream
from mcap.summary import Summary
from mcap.writer import MCAP0_MAGIC, CompressionType, Writer

from wftool.errors import RecordingError, UsageError

CHUNK_SIZE = 1024 * 1024
"""Uncompressed bytes per chunk (the `mcap` default): what a full disk can cost."""


class _TrackedFile:
    """A write-only file that knows its position; the writer's stream."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.position = 0

    def write(self, data: bytes) -> int:
        view = memoryview(data)
        while view:
            written = os.write(self.fd, view)
            self.position += written
            view = view[written:]
        return len(data)

    def tell(self) -> int:
        return self.position

    def flush(self) -> None:
        pass


class McapFile:
    """An MCAP writer over `path` (created, or replaced if `replace`); `finish()` ends it.

    Opening failures are `UsageError` (nothing was recorded yet); write failures later are
    `RecordingError`, raised after the file has been finished up to its last chunk.
    """

    def __init__(self, path: Path, profile: str, library: str, *, replace: bool = True) -> None:
        self.path = path
        flags = os.O_WRONLY | os.O_CREAT | (os.O_TRUNC if replace else os.O_EXCL)
        try:
            fd = os.open(path, flags | getattr(os, "O_BINARY", 0), 0o666)
        except OSError as exc:
            raise UsageError(f"cannot write the recording: {exc}") from None
        self._file = _TrackedFile(fd)
        self._writer = Writer(self._file, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
        self._safe_end = 0
        """File size at the end of the last complete write: where a failed file is cut."""
        self.failure: OSError | None = None
        self._pending: Counter[int] = Counter()
        self._pending_times: tuple[int, int] | None = None
        self.message_counts: Counter[int] = Counter()
        """Messages per channel id that are in the file (their chunk is written)."""
        self.time_range: tuple[int, int] | None = None
        """(first, last) log time of the messages in the file, ns."""
        try:
            self._writer.start(profile=profile, library=library)
        except OSError as exc:
            self._abandon()
            path.unlink(missing_ok=True)
            raise UsageError(f"cannot write the recording: {exc}") from None
        self._safe_end = self._file.position

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        return self._writer.register_schema(name=name, encoding=encoding, data=data)

    def register_channel(self, topic: str, message_encoding: str, schema_id: int) -> int:
        return self._writer.register_channel(
            topic, message_encoding=message_encoding, schema_id=schema_id
        )

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        self._guarded(self._writer.add_metadata, name, data)

    def add_message(
        self, channel_id: int, log_time: int, data: bytes, publish_time: int | None = None
    ) -> None:
        """Queue a message; the chunk it completes is written now (the writer's `add_message`).

        After a failure (raised once, as `RecordingError`) messages are dropped.
        """
        if self.failure is not None:
            return
        position = self._file.position
        try:
            self._writer.add_message(
                channel_id, log_time, data, log_time if publish_time is None else publish_time
            )
        except OSError as exc:
            self._salvage(exc)
        self._pending[channel_id] += 1
        times = self._pending_times
        if times is None:
            self._pending_times = (log_time, log_time)
        elif log_time < times[0] or log_time > times[1]:
            self._pending_times = (min(times[0], log_time), max(times[1], log_time))
        if self._file.position != position:  # a chunk, this message included, is in the file
            self._commit()

    def finish(self) -> None:
        """Write the last chunk and the summary, and close the file (also after a failure)."""
        if self._file.fd < 0:
            return
        if self.failure is None:
            self._guarded(self._writer.finish)
            self._commit()
        self._abandon()

    def discard(self) -> None:
        """Close and delete the file: the recording never started."""
        self._abandon()
        self.path.unlink(missing_ok=True)

    def _guarded(self, write: Callable[..., object], *args: object) -> None:
        try:
            write(*args)
        except OSError as exc:
            self._salvage(exc)
        self._safe_end = self._file.position

    def _commit(self) -> None:
        self._safe_end = self._file.position
        self.message_counts.update(self._pending)
        self._pending.clear()
        if self._pending_times is not None:
            first, last = self._pending_times
            if self.time_range is not None:
                first, last = min(first, self.time_range[0]), max(last, self.time_range[1])
            self.time_range = (first, last)
            self._pending_times = None

    def _salvage(self, exc: OSError) -> None:
        """Cut the file back to its last complete chunk, end it there, and raise."""
        self.failure = exc
        self._pending.clear()
        ending = RecordBuilder()
        DataEnd(data_section_crc=0).write(ending)
        Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(ending)
        tail = ending.end() + MCAP0_MAGIC
        fd = self._file.fd
        try:
            os.ftruncate(fd, self._safe_end)
            written = os.pwrite(fd, tail, self._safe_end)
            finished = written == len(tail)
        except OSError:
            finished = False
        self._abandon()
        if finished:
            raise RecordingError(
                f"recording stopped, {exc.strerror or exc}: {self.path} is finished and "
                "readable up to its last complete chunk"
            ) from None
        raise RecordingError(
            f"recording stopped, {exc.strerror or exc}: {self.path} could not be finished "
            "(no room for its last 50 bytes); `mcap recover` can rebuild it"
        ) from None

    def _abandon(self) -> None:
        if self._file.fd >= 0:
            os.close(self._file.fd)
            self._file.fd = -1


_MESSAGE_HEAD = struct.Struct("<BQHIQQ")
"""A Message record's opcode, length, channel id, sequence, log and publish time."""


def indexed_messages(
    handle: IO[bytes], summary: Summary | None, topic: str
) -> tuple[str, Iterator[bytes]] | None:
    """(message encoding, the data of `topic`'s messages in written order), read through
    the file's chunk and message indexes; None when the file has no such index (say, one
    cut short by a full disk) or no such topic: read it in full then.

    The `mcap` reader walks every record of every chunk to pick a topic's messages; a ROS 2
    recording holds five messages per packet besides its raw-byte event. The indexes say
    where each event is, so only those are parsed: several times faster.
    """
    if summary is None or not summary.chunk_indexes:
        return None
    channels = [c for c in summary.channels.values() if c.topic == topic]
    if len(channels) != 1:
        return None
    channel = channels[0]
    chunk_indexes = sorted(summary.chunk_indexes, key=lambda index: index.chunk_start_offset)
    if not any(index.message_index_offsets for index in chunk_indexes):
        return None  # written without message indexes
    return channel.message_encoding, _indexed(handle, chunk_indexes, channel.id)


def _indexed(stream: IO[bytes], chunk_indexes: list[ChunkIndex], channel: int) -> Iterator[bytes]:
    head = _MESSAGE_HEAD
    for index in chunk_indexes:
        offset = index.message_index_offsets.get(channel)
        if offset is None:
            continue
        stream.seek(offset + 9)  # past the MessageIndex record's opcode and length
        message_index = MessageIndex.read(ReadDataStream(stream))
        stream.seek(index.chunk_start_offset + 9)
        records = get_chunk_data_stream(Chunk.read(ReadDataStream(stream)))[0].read(
            index.uncompressed_size
        )
        for _, at in sorted(message_index.records, key=lambda entry: entry[1]):
            opcode, length, channel_id, *_ = head.unpack_from(records, at)
            if opcode != Opcode.MESSAGE or channel_id != channel:
                raise McapError(f"the message index points at no message of channel {channel}")
            yield records[at + head.size : at + 9 + length]
