"""A recording cut short made readable by any tool again: its metadata.yaml rebuilt from its
MCAP file, as `ros2 bag reindex` does, and an MCAP file without its ending written again
with one (the file as found is kept beside it). What was recorded is never changed.

    repaired = repair(Path("run"))   # a bag directory, or one MCAP file
    print(repaired.describe())
"""

from __future__ import annotations

import os
import re
import struct
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Header, Message, Metadata, Schema
from mcap.writer import Writer

from wftool import __version__
from wftool.errors import UsageError
from wftool.recording.mcapfile import LinearReader, being_written, ends_whole
from wftool.recording.reader import closed_in, planned_in
from wftool.recording.rosbag import bag_file, metadata_yaml, write_metadata

KEPT_SUFFIX = ".cut"
"""An MCAP file without its ending, as found, is kept under its name + this."""
_RUN_METADATA = "wftool."
"""The metadata records of a wftool recording's run start with this ("wftool.verify",
"wftool.msp"); the last of them is what the run said, and goes to metadata.yaml."""
_LISTED = re.compile(r"^  message_count: (\d+)$", re.MULTILINE)


@dataclass
class _Contents:
    """What an MCAP file holds, read from it."""

    types: dict[str, str] = field(default_factory=dict)
    """Type name per topic."""
    counts: Counter[str] = field(default_factory=Counter)
    """Messages per topic."""
    first_ns: int | None = None
    last_ns: int | None = None
    run: dict[str, str] = field(default_factory=dict)
    """The run's own metadata record (`_RUN_METADATA`)."""

    @property
    def messages(self) -> int:
        return sum(self.counts.values())

    @property
    def span_ns(self) -> int:
        first, last = self.first_ns, self.last_ns
        return last - first if first is not None and last is not None else 0


@dataclass(frozen=True)
class Repair:
    """What `repair` found and did."""

    mcap_path: Path
    messages: int
    span_s: float
    """From the first message's log time to the last's."""
    kept: Path | None
    """The MCAP file as found, when it had no ending and was written again."""
    metadata_path: Path | None
    """The metadata.yaml rebuilt (a bag directory); None for an MCAP file alone."""
    listed: int | None
    """The messages metadata.yaml listed before (None: it had none, or no count)."""
    closed: bool | None
    """Whether the run closed its recording (None: recorded before recordings said so)."""
    planned_s: float | None
    """How long the run was to last."""

    def describe(self) -> list[str]:
        """What was done, a line each."""
        lines = []
        if self.kept is not None:
            lines.append(
                f"{self.mcap_path.name} had no ending (its writer was stopped hard): written "
                f"again with one, every message that could be read; the file as found is "
                f"{self.kept.name}"
            )
        held = f"{self.messages:,} messages over {self.span_s:.1f} s"
        if self.metadata_path is not None:
            before = "" if self.listed is None else f" (it listed {self.listed:,})"
            lines.append(
                f"{self.metadata_path.parent.name}/{self.metadata_path.name} rebuilt from "
                f"{self.mcap_path.name}: {held}{before}"
            )
        else:
            lines.append(f"{self.mcap_path.name}: {held}")
        if self.closed is False:
            planned = "" if self.planned_s is None else f" (of {self.planned_s:g} planned)"
            lines.append(
                f"the run never closed it: cut short at {self.span_s:.1f} s{planned}; "
                "replay reads what it holds"
            )
        return lines


def repair(path: Path) -> Repair:
    """Repair the recording at `path` (a bag directory or an MCAP file): its MCAP file given
    an ending if it has none, then a bag's metadata.yaml written from what the file holds.
    A recording still being written, or that is no MCAP file, is a `UsageError`."""
    mcap_path = bag_file(path)
    try:
        with open(mcap_path, "rb") as handle:
            if being_written(handle):
                raise UsageError(
                    f"{mcap_path} is being written (a run is recording to it): repair it "
                    "once that run has ended"
                )
            whole = ends_whole(handle)
            kept = None if whole else _end_again(mcap_path, handle)
        with open(mcap_path, "rb") as handle:
            contents = _contents(handle)
    except OSError as exc:
        raise UsageError(f"cannot repair {mcap_path}: {exc.strerror or exc}") from None
    except (McapError, ValueError, KeyError, EOFError, struct.error) as exc:
        reason = str(exc) or type(exc).__name__
        raise UsageError(f"cannot repair {mcap_path}: it is damaged: {reason}") from None
    metadata_path, listed = None, None
    if path.is_dir():
        metadata_path = path / "metadata.yaml"
        listed = _listed(metadata_path)
        custom = {**contents.run, "repaired": f"wftool {__version__}"}
        counts = {topic: contents.counts[topic] for topic in contents.types}
        text = metadata_yaml(
            mcap_path.name, contents.types, counts, contents.first_ns or 0, contents.span_ns,
            custom,
        )  # fmt: skip
        try:
            write_metadata(metadata_path, text)
        except OSError as exc:
            raise UsageError(f"cannot write {metadata_path}: {exc.strerror or exc}") from None
    return Repair(
        mcap_path,
        contents.messages,
        contents.span_ns / 1e9,
        kept,
        metadata_path,
        listed,
        closed_in(contents.run),
        planned_in(contents.run),
    )


def _contents(handle: IO[bytes]) -> _Contents:
    """Topics, counts, times and the run's metadata of a finished MCAP file: from its
    summary if it has one, else by reading it through."""
    contents = _Contents()
    summary = make_reader(handle).get_summary()
    statistics = summary.statistics if summary is not None else None
    if summary is None or statistics is None:
        handle.seek(0)
        return _scanned(handle)
    for channel in summary.channels.values():
        schema = summary.schemas.get(channel.schema_id)
        contents.types[channel.topic] = schema.name if schema is not None else ""
        contents.counts[channel.topic] += statistics.channel_message_counts.get(channel.id, 0)
    if statistics.message_count:
        contents.first_ns = statistics.message_start_time
        contents.last_ns = statistics.message_end_time
    handle.seek(0)
    for record in make_reader(handle).iter_metadata():
        if record.name.startswith(_RUN_METADATA):
            contents.run = dict(record.metadata)
    return contents


def _scanned(handle: IO[bytes]) -> _Contents:
    contents = _Contents()
    schemas: dict[int, str] = {}
    topics: dict[int, str] = {}
    for record in LinearReader(handle).records():
        if isinstance(record, Schema):
            schemas[record.id] = record.name
        elif isinstance(record, Channel):
            topics[record.id] = record.topic
            contents.types[record.topic] = schemas.get(record.schema_id, "")
        elif isinstance(record, Message):
            contents.counts[topics[record.channel_id]] += 1
            first = contents.first_ns
            contents.first_ns = record.log_time if first is None else min(first, record.log_time)
            last = contents.last_ns
            contents.last_ns = record.log_time if last is None else max(last, record.log_time)
        elif isinstance(record, Metadata) and record.name.startswith(_RUN_METADATA):
            contents.run = dict(record.metadata)
    return contents


def _end_again(mcap_path: Path, handle: IO[bytes]) -> Path:
    """Write every record of `mcap_path` that can be read (`LinearReader`) into a new file
    with an ending, which takes its place; the file as found is kept, and returned."""
    kept = mcap_path.with_name(mcap_path.name + KEPT_SUFFIX)
    fresh = mcap_path.with_name(mcap_path.name + ".repairing")
    if kept.exists():
        raise UsageError(f"cannot repair {mcap_path}: {kept.name} exists (a repair before?)")
    with open(fresh, "xb") as out:
        try:
            _copy(LinearReader(handle), out)
        except BaseException:
            fresh.unlink(missing_ok=True)
            raise
    os.link(mcap_path, kept)  # fails if kept appeared meanwhile: nothing is overwritten
    os.replace(fresh, mcap_path)
    return kept


def _copy(records: LinearReader, out: IO[bytes]) -> None:
    writer = Writer(out)
    schemas: dict[int, int] = {}
    channels: dict[int, int] = {}
    started = False
    for record in records.records():
        if isinstance(record, Header):
            writer.start(profile=record.profile, library=record.library)
            started = True
            continue
        if not started:
            raise ValueError("no MCAP header")
        if isinstance(record, Schema):
            schemas[record.id] = writer.register_schema(record.name, record.encoding, record.data)
        elif isinstance(record, Channel):
            channels[record.id] = writer.register_channel(
                record.topic, record.message_encoding, schemas.get(record.schema_id, 0),
                dict(record.metadata),
            )  # fmt: skip
        elif isinstance(record, Message):
            writer.add_message(
                channels[record.channel_id], record.log_time, record.data, record.publish_time,
                record.sequence,
            )  # fmt: skip
        elif isinstance(record, Metadata):
            writer.add_metadata(record.name, dict(record.metadata))
    writer.finish()


def _listed(metadata_path: Path) -> int | None:
    """The message count an existing metadata.yaml lists, if it can be read."""
    try:
        found = _LISTED.search(metadata_path.read_text())
    except (OSError, UnicodeDecodeError):
        return None
    return int(found.group(1)) if found else None
