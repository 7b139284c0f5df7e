"""COBS framing of FSP packets (spec §1) and the checks every received chunk goes through.

The stream is split on 0x00; each chunk is COBS-decoded, then checked for length, version
and CRC, cheapest first. Every rejection is counted under its cause and nothing is raised:
a receiver must survive any byte sequence.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping

from cobs import cobs

from wftool.fsp.packets import (
    ARMING_REQUEST_LENGTH,
    COMMAND_LENGTH,
    COMMAND_REPORT_LENGTH,
    STATE_LENGTH,
    STATE_TUNNEL_LENGTH,
    TIME_REPLY_LENGTH,
    TIMED_COMMAND_LENGTH,
    UPLINK_STATUS_LENGTHS,
    VERSION_BASE,
    VERSION_TUNNEL,
)
from wftool.link.crc import crc8_residues

DELIMITER = b"\x00"


class Rejection(str, enum.Enum):
    """Why a chunk between two delimiters did not become a packet."""

    COBS = "cobs"
    LENGTH = "length"
    VERSION = "version"
    CRC = "crc"


STATE_VERSIONS: Mapping[int, int] = {
    STATE_LENGTH: VERSION_BASE,
    STATE_TUNNEL_LENGTH: VERSION_TUNNEL,
}
"""Payload length → the version byte a state packet of that length must carry."""
UPLINK_STATUS_VERSIONS: Mapping[int, int] = dict.fromkeys(UPLINK_STATUS_LENGTHS, VERSION_BASE)
"""E3 uplink statuses (spec §12): 64 bytes, or 36 of firmware before the authority fields."""
STREAM_VERSIONS: Mapping[int, int] = {
    **STATE_VERSIONS,
    **UPLINK_STATUS_VERSIONS,
    COMMAND_REPORT_LENGTH: VERSION_BASE,
}
"""The FC → OBC stream: state packets, E3 uplink statuses (spec §12) and E4 command reports
(§13), told apart by their length."""
STATE_E2_VERSIONS: Mapping[int, int] = {**STREAM_VERSIONS, TIME_REPLY_LENGTH: VERSION_BASE}
"""The FC → OBC stream with E2 time replies (spec §10) too."""
COMMAND_VERSIONS: Mapping[int, int] = {
    COMMAND_LENGTH: VERSION_BASE,
    TIMED_COMMAND_LENGTH: VERSION_BASE,
    ARMING_REQUEST_LENGTH: VERSION_BASE,
}
"""The OBC → FC uplink: commands, E4 timed commands (spec §13), E5 arming requests (§14)."""
IMMEDIATE_COMMAND_VERSIONS: Mapping[int, int] = {COMMAND_LENGTH: VERSION_BASE}
"""The uplink as an FC without E4 and E5 reads it: a timed command or an arming request is a
chunk of bad length."""


def longest_chunk(versions: Mapping[int, int]) -> int:
    """The longest chunk between delimiters that a packet of `versions` can make: COBS adds
    one byte per 254 started. A longer chunk is rejected (LENGTH) without decoding it."""
    longest = max(versions)
    return longest + 1 + longest // 254


def encode_frame(payload: bytes) -> bytes:
    """`payload` as it goes on the wire: COBS-encoded and delimited."""
    return cobs.encode(payload) + DELIMITER


class Deframer:
    """Turns a byte stream into validated packet payloads, counting what it rejects.

    `versions` maps each acceptable payload length to its version byte. Chunks longer than
    any valid packet are dropped as soon as they are seen, so garbage without a delimiter
    cannot grow the buffer.
    """

    def __init__(self, versions: Mapping[int, int]) -> None:
        self._versions = dict(versions)
        self._max_chunk = longest_chunk(self._versions)
        self._tail = b""
        self._discarding = False
        self.rejected: dict[Rejection, int] = dict.fromkeys(Rejection, 0)
        self.joined: dict[Rejection, int] = dict.fromkeys(Rejection, 0)
        """Of `rejected`: the chunks that began before the stream was joined (`join`)."""
        self._joining = True

    def join(self) -> None:
        """The stream is joined mid-way (a connection opens): the bytes up to the next
        delimiter end a chunk whose start was never seen. A new deframer is joining."""
        self._joining = True

    def resync(self) -> None:
        """The byte stream broke off (a reconnect): forget the partial chunk; what comes
        next starts a chunk of its own, joined mid-way."""
        self._tail = b""
        self._discarding = False
        self._joining = True

    def feed(self, data: bytes) -> list[bytes]:
        """Payloads of every packet completed by `data`, in stream order."""
        if self._joining:
            return self._join(data)
        return self._feed(data)

    def _join(self, data: bytes) -> list[bytes]:
        """`feed`, counting what the chunk cut by joining is rejected for in `joined` too."""
        head, delimiter, rest = data.partition(DELIMITER)
        before = dict(self.rejected)
        payloads = self._feed(head + delimiter)
        for cause, count in self.rejected.items():
            self.joined[cause] += count - before[cause]
        self._joining = not delimiter
        return payloads + self._feed(rest) if rest else payloads

    def _feed(self, data: bytes) -> list[bytes]:
        chunks = (self._tail + data).split(DELIMITER) if self._tail else data.split(DELIMITER)
        tail = chunks.pop()
        if self._discarding and chunks:
            chunks[0] = b""  # the rest of an oversized chunk, already counted
            self._discarding = False
        if len(tail) > self._max_chunk:
            if not self._discarding:
                self.rejected[Rejection.LENGTH] += 1
            self._discarding = True
            tail = b""
        self._tail = tail

        versions = self._versions
        rejected = self.rejected
        decode = cobs.decode
        candidates: list[bytes] = []
        for chunk in chunks:
            if not chunk:
                continue  # back-to-back delimiters carry nothing; not a fault
            try:
                payload = decode(chunk)
            except cobs.DecodeError:
                rejected[Rejection.COBS] += 1
                continue
            expected = versions.get(len(payload))
            if expected is None:
                rejected[Rejection.LENGTH] += 1
            elif payload[0] != expected:
                rejected[Rejection.VERSION] += 1
            else:
                candidates.append(payload)
        return self._check_crc(candidates)

    def _check_crc(self, candidates: list[bytes]) -> list[bytes]:
        lengths = {len(p) for p in candidates}
        if len(lengths) > 1:  # a stream that mixes variants: check each length on its own
            passing: set[bytes] = set()
            for length in lengths:
                same = [p for p in candidates if len(p) == length]
                passing.update(p for p, r in zip(same, crc8_residues(same, length)) if r == 0)
            accepted = [p for p in candidates if p in passing]
        elif lengths:
            residues = crc8_residues(candidates, lengths.pop())
            accepted = [p for p, r in zip(candidates, residues) if r == 0]
        else:
            return []
        self.rejected[Rejection.CRC] += len(candidates) - len(accepted)
        return accepted
