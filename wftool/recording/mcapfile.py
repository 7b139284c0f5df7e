"""An MCAP file that stays readable when the disk fills up mid-run (`McapFile`), and one cut
short read as far as it goes (`LinearReader`, `Cut`); docs/recording.md says how.
"""

from __future__ import annotations

import io
import os
import struct
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, cast

import lz4.frame
import zstandard
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Message,
    MessageIndex,
    Metadata,
    Schema,
)
from mcap.stream_reader import breakup_chunk, get_chunk_data_stream
from mcap.summary import Summary
from mcap.writer import MCAP0_MAGIC, CompressionType, Writer

from wftool.errors import RecordingError, UsageError

try:
    import fcntl
except ImportError:  # not POSIX
    fcntl = None  # type: ignore[assignment]

CHUNK_SIZE = 1024 * 1024
"""Uncompressed bytes per chunk (the `mcap` default): what a full disk can cost."""
APART_SPAN_NS = 1_000_000_000
"""Apart messages (`McapFile.add_message`) are written at least this often (log time), so
that a file cut short loses about a second of them, however few the others are."""


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
    """An MCAP writer creating `path` (never replacing a file); `finish()` ends it.

    Opening failures are `UsageError` (nothing was recorded yet); write failures later are
    `RecordingError`, raised after the file has been finished up to its last chunk.
    """

    def __init__(self, path: Path, profile: str, library: str) -> None:
        self.path = path
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
        try:
            fd = os.open(path, flags, 0o666)
        except FileExistsError:
            raise UsageError(f"cannot write the recording: {path} already exists") from None
        except OSError as exc:
            raise UsageError(f"cannot write the recording: {exc}") from None
        if fcntl is not None:  # held until the file is closed, or this process ends
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # new: nobody else holds it
        self._file = _TrackedFile(fd)
        # Chunks are cut here (`_write_chunks`), never by the writer on its own.
        writes_to = cast(IO[bytes], self._file)  # all a Writer uses: write, tell, flush
        self._writer = Writer(writes_to, chunk_size=2**62, compression=CompressionType.ZSTD)
        self._safe_end = 0
        """File size at the end of the last complete write: where a failed file is cut."""
        self.failure: OSError | None = None
        self._pending: Counter[int] = Counter()
        self._pending_times: tuple[int, int] | None = None
        self._held: list[tuple[int, int, bytes, int]] = []
        """Messages queued for the next chunk: (channel, log time, data, publish time)."""
        self._held_bytes = 0
        self._apart: list[tuple[int, int, bytes, int]] = []
        """... and for the next chunk of apart messages."""
        self._apart_bytes = 0
        self._latest = 0
        """The latest log time of the messages written."""
        self.defer_cuts = False
        """True: chunks are cut only by `cut_if_due`, at points where the caller knows the
        apart messages and the others agree (the writer process: its cut points)."""
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
        """A metadata record, after every message queued before it: a record that says the
        recording was closed is written only once all it closes is."""
        if self.failure is not None:
            return
        self._write_chunks()
        self._guarded(self._writer.add_metadata, name, data)

    def add_message(
        self,
        channel_id: int,
        log_time: int,
        data: bytes,
        publish_time: int | None = None,
        *,
        apart: bool = False,
    ) -> None:
        """Queue a message; once a chunk's worth is queued it is written as one.

        `apart` messages go into chunks of their own, written before the chunk of the
        others queued meanwhile: a reader after one channel (the raw bytes) then
        decompresses its chunks alone, and the file never holds messages of the others
        without the apart ones that came with them. An apart message's log time moves
        to lie between the messages written before and after it, if it does not (its
        publish time stays): a file without its index is read in log-time order, and
        some readers (rosbags) require that order. After a failure (raised once, as
        `RecordingError`) messages are dropped.
        """
        if self.failure is not None:
            return
        message = (channel_id, log_time, data, log_time if publish_time is None else publish_time)
        size = len(data) + _MESSAGE_HEAD.size
        if apart:
            self._apart.append(message)
            self._apart_bytes += size
        else:
            self._held.append(message)
            self._held_bytes += size
        if not self.defer_cuts:
            self.cut_if_due()

    def cut_if_due(self) -> None:
        """Write what is queued if a chunk's worth is (or the apart messages span
        `APART_SPAN_NS`)."""
        apart = self._apart
        if (
            self._held_bytes > CHUNK_SIZE
            or self._apart_bytes > CHUNK_SIZE
            or (apart and apart[-1][1] - apart[0][1] > APART_SPAN_NS)
        ):
            self._write_chunks()

    def _write_chunks(self) -> None:
        """What is queued, as chunks: the apart messages, then the others."""
        apart, held = self._apart, self._held
        self._apart, self._held, self._apart_bytes, self._held_bytes = [], [], 0, 0
        if apart:
            # Between the latest message written and the first of those held.
            low = self._latest
            high = min((m[1] for m in held), default=None)
            for channel_id, log_time, data, publish_time in apart:
                log_time = max(log_time, low) if high is None else min(max(log_time, low), high)
                self._add(channel_id, log_time, data, publish_time)
            self._flush()
        if held:
            for message in held:
                self._add(*message)
            self._flush()
        self._commit()  # both or neither: a failure cuts the file back to before the two

    def _flush(self) -> None:
        try:
            self._writer.flush()
        except OSError as exc:
            self._salvage(exc)

    def _add(self, channel_id: int, log_time: int, data: bytes, publish_time: int) -> None:
        try:
            self._writer.add_message(channel_id, log_time, data, publish_time)
        except OSError as exc:
            self._salvage(exc)
        self._pending[channel_id] += 1
        if log_time > self._latest:
            self._latest = log_time
        times = self._pending_times
        if times is None:
            self._pending_times = (log_time, log_time)
        elif log_time < times[0] or log_time > times[1]:
            self._pending_times = (min(times[0], log_time), max(times[1], log_time))

    def finish(self) -> None:
        """Write the last chunks and the summary, and close the file (also after a failure)."""
        if self._file.fd < 0:
            return
        if self.failure is None:
            self._write_chunks()
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
) -> tuple[Channel, Iterator[bytes]] | None:
    """(`topic`'s channel, the data of its messages in written order), read through
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
    return channel, _indexed(handle, chunk_indexes, channel.id)


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


def ends_whole(handle: IO[bytes]) -> bool:
    """Whether the MCAP file `handle` ends as a finished one does (else it is read
    linearly); ValueError if it is empty or no MCAP file."""
    handle.seek(0, os.SEEK_END)
    size = handle.tell()
    if size == 0:
        raise ValueError("the file is empty")
    handle.seek(0)
    if handle.read(len(MCAP0_MAGIC)) != MCAP0_MAGIC:
        raise ValueError("not an MCAP file")
    handle.seek(max(0, size - len(MCAP0_MAGIC)))
    whole = size >= 2 * len(MCAP0_MAGIC) and handle.read() == MCAP0_MAGIC
    handle.seek(0)
    return whole


def being_written(handle: IO[bytes]) -> bool:
    """Whether an `McapFile` is writing the file `handle` now: it holds the file's lock
    while it does (and loses it when it ends, however it ends)."""
    if fcntl is None:  # not POSIX: no lock to ask
        return False
    try:
        fcntl.flock(handle.fileno(), fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    fcntl.flock(handle.fileno(), fcntl.LOCK_UN)
    return False


# -- reading a file that has no ending --------------------------------------------------------


@dataclass(frozen=True)
class Cut:
    """Where a file without its ending stops (its writer was killed, the machine went down):
    what it still held and what was lost with it."""

    size: int
    """Bytes in the file."""
    whole: int
    """Bytes in whole records, from the start: all that could be read as written."""
    messages: int
    """Messages read, those of a chunk cut short included."""
    log_times: tuple[int, int] | None
    """(first, last) log time (ns) of the messages read, if any."""
    cut_chunk: tuple[int, int] | None = None
    """(first, last) log time (ns) of the messages of a chunk cut short, if the file ends
    inside one: those after the last read were lost."""
    data_end: bool = False
    """The data section was whole (its Data End record was read): only indexes are lost."""

    def describe(self) -> str:
        """What was read and what was lost, in seconds from the first message."""
        said = f"not finished (its writer was stopped hard), read to byte {self.whole:,} of "
        said += f"{self.size:,}: {self.messages:,} messages"
        if self.log_times is not None:
            said += f", {self._at(self.log_times[1])} of the run"
        if self.data_end:
            return said + "; no message lost, only the file's index"
        said += "; lost: "
        if self.cut_chunk is not None:
            said += f"the rest of a chunk cut short (up to {self._at(self.cut_chunk[1])}) and "
        return said + "what the writer still held (up to a chunk, about a second)"

    def _at(self, log_time: int) -> str:
        first = self.log_times[0] if self.log_times is not None else log_time
        return f"{(log_time - first) / 1e9:.1f} s"


class LinearReader:
    """Every record of an MCAP file in file order, chunks opened, read to its Footer or to
    where the file stops: `cut` then says where (None for a finished file). Of a chunk cut
    short, what its compressed part that reached the file decodes to is read too.

    A file written by `McapFile` or any `mcap` writer ends with a Footer; one whose writer
    was killed (SIGKILL, a power cut) ends after its last whole chunk, or inside one.
    """

    def __init__(self, handle: IO[bytes]) -> None:
        self._handle = handle
        self.cut: Cut | None = None

    def records(self) -> Iterator[object]:
        handle = self._handle
        handle.seek(0, os.SEEK_END)
        size = handle.tell()
        handle.seek(0)
        if handle.read(len(MCAP0_MAGIC)) != MCAP0_MAGIC:
            raise McapError("not an MCAP file")
        position, messages, log_times = len(MCAP0_MAGIC), 0, None
        cut_chunk, data_end = None, False
        while True:
            head = handle.read(_RECORD_HEAD.size)
            if len(head) < _RECORD_HEAD.size:
                break
            opcode, length = _RECORD_HEAD.unpack(head)
            whole = length <= size - position - _RECORD_HEAD.size  # else the file stops in it
            records: Sequence[object] = ()
            if whole:
                record = _record(opcode, handle.read(length), length)
                position += _RECORD_HEAD.size + length
                if isinstance(record, Footer):
                    return
                data_end = data_end or isinstance(record, DataEnd)
                records = breakup_chunk(record) if isinstance(record, Chunk) else [record]
            elif opcode == Opcode.CHUNK:
                cut_chunk, records = _cut_chunk(handle.read())
            for record in records:
                if isinstance(record, Message):
                    messages += 1
                    first = log_times[0] if log_times is not None else record.log_time
                    log_times = (first, record.log_time)
                yield record
            if not whole:
                break
        self.cut = Cut(size, position, messages, log_times, cut_chunk, data_end)


_RECORD_HEAD = struct.Struct("<BQ")
_CHUNK_HEAD = struct.Struct("<QQQII")
"""A Chunk's start and end log time, uncompressed size and CRC, compression name length."""
_RECORDS: dict[int, Callable[[ReadDataStream], McapRecord]] = {
    Opcode.HEADER: Header.read, Opcode.FOOTER: Footer.read, Opcode.SCHEMA: Schema.read,
    Opcode.CHANNEL: Channel.read, Opcode.CHUNK: Chunk.read, Opcode.METADATA: Metadata.read,
    Opcode.DATA_END: DataEnd.read,
}  # fmt: skip
"""The records a recording is read by; the others (indexes, statistics) are skipped."""


def _record(opcode: int, body: bytes, length: int) -> object:
    stream = ReadDataStream(io.BytesIO(body))
    if opcode == Opcode.MESSAGE:
        return Message.read(stream, length)
    read = _RECORDS.get(opcode)
    return read(stream) if read is not None else None


def _cut_chunk(rest: bytes) -> tuple[tuple[int, int] | None, list[object]]:
    """(the log time range, the records that decode) of a chunk the file stops inside."""
    if len(rest) < _CHUNK_HEAD.size:
        return None, []
    start, end, _, _, name_length = _CHUNK_HEAD.unpack_from(rest)
    compression = rest[_CHUNK_HEAD.size : _CHUNK_HEAD.size + name_length]
    data = rest[_CHUNK_HEAD.size + name_length + 8 :]  # past the data's length
    try:
        if compression == b"zstd":
            data = zstandard.ZstdDecompressor().decompressobj().decompress(data)
        elif compression == b"lz4":
            data = lz4.frame.LZ4FrameDecompressor().decompress(data)
    except (zstandard.ZstdError, RuntimeError):
        data = b""
    records = []
    position = 0
    while position + _RECORD_HEAD.size <= len(data):
        opcode, length = _RECORD_HEAD.unpack_from(data, position)
        body_at = position + _RECORD_HEAD.size
        if length > len(data) - body_at:
            break
        if opcode in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE):
            records.append(_record(opcode, data[body_at : body_at + length], length))
        position = body_at + length
    return (start, end), records
