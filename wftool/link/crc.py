"""CRC-8 with polynomial 0xD5, MSB-first, no final XOR: FSP's (spec §1, init 0xFF) and MSP v2's
(CRC-8/DVB-S2, init 0x00). `crc8` is the plain form (a packet's worth of bytes as eight
parities); `crc8_residues` and `crc8_check_words` check many packets at once (docs/design.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache, reduce
from operator import or_
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

POLY = 0xD5
INIT = 0xFF
"""FSP's initial value."""
DVB_S2_INIT = 0x00
"""CRC-8/DVB-S2's initial value (MSP v2)."""

_BATCH_MIN = 6
"""Below this many packets the per-position fixed cost exceeds the plain loop."""
_PARITY_MIN = 40
"""From this many bytes on, `crc8` takes the parity form (at 117 bytes, a state packet's,
it is ~2.4x faster than the byte loop; at 38 they are even)."""


def _make_table(poly: int) -> bytes:
    table = bytearray(256)
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table[byte] = crc
    return bytes(table)


TABLE = _make_table(POLY)


def crc8(data: bytes | bytearray | memoryview, init: int = INIT) -> int:
    """CRC-8 of `data`, starting from `init` (or continuing from a previous result)."""
    length = len(data)
    if length < _PARITY_MIN:
        crc = init
        table = TABLE
        for byte in data:
            crc = table[crc ^ byte]
        return crc
    m0, m1, m2, m3, m4, m5, m6, m7 = _parity_masks(length)
    value = int.from_bytes(data, "big")
    return _init_term(init, length) ^ (
        (value & m0).bit_count() & 1
        | ((value & m1).bit_count() & 1) << 1
        | ((value & m2).bit_count() & 1) << 2
        | ((value & m3).bit_count() & 1) << 3
        | ((value & m4).bit_count() & 1) << 4
        | ((value & m5).bit_count() & 1) << 5
        | ((value & m6).bit_count() & 1) << 6
        | ((value & m7).bit_count() & 1) << 7
    )


@lru_cache(maxsize=64)
def _bit_to(bit: int, to: int) -> bytes:
    """A translate table: each byte to its bit `bit`, moved to bit `to`."""
    return bytes(((byte >> bit) & 1) << to for byte in range(256))


@lru_cache(maxsize=16)
def _parity_masks(length: int) -> tuple[int, ...]:
    """For `length`-byte data read as one big-endian integer, the bits whose parity is each
    bit of the register (from init 0): the CRC is linear, so register bit k is the XOR of
    the data bits that reach it, which `(value & mask_k).bit_count() & 1` counts in C."""
    tables = _position_tables(length)
    # reach[b][i]: what bit b of byte i adds to the register (every bit of it).
    reach = [bytes(table[1 << b] for table in tables) for b in range(8)]
    return tuple(
        reduce(or_, (int.from_bytes(reach[b].translate(_bit_to(k, b)), "big") for b in range(8)))
        for k in range(8)
    )


@lru_cache(maxsize=64)
def _init_term(init: int, length: int) -> int:
    """What `init` leaves in the register after `length` bytes (of zeros, the linear part
    being apart)."""
    term = init
    for _ in range(length):
        term = TABLE[term]
    return term


@lru_cache(maxsize=8)
def _position_tables(length: int) -> tuple[bytes, ...]:
    """Per byte position, what that byte adds to the final register (what INIT adds:
    `_init_term`).

    A byte at position i passes through the table once per remaining byte, so the last
    position's table is TABLE and each earlier one is the next one passed through TABLE
    again (the register update on a zero byte).
    """
    tables = [TABLE] * length
    for position in range(length - 2, -1, -1):
        tables[position] = tables[position + 1].translate(TABLE)
    return tuple(tables)


def crc8_residues(packets: Sequence[bytes], length: int) -> list[int]:
    """The CRC register after running over each whole packet, its CRC byte included.

    The CRC has no final XOR, so a packet whose last byte is the CRC of the bytes before it
    leaves 0: `residues[i] == 0` means packet i passes. Every packet must be `length` bytes.
    """
    count = len(packets)
    if count < _BATCH_MIN:
        return [crc8(packet) for packet in packets]
    tables, init_term = _position_tables(length), _init_term(INIT, length)
    joined = b"".join(packets)
    # Column i holds byte i of every packet; XOR-fold the translated columns into one.
    columns = b"".join([joined[i::length].translate(tables[i]) for i in range(length)])
    folded = int.from_bytes(columns, "little")
    bits, remaining = 8 * count, length
    while remaining > 1:
        keep = (remaining + 1) // 2
        folded = (folded & ((1 << (bits * keep)) - 1)) ^ (folded >> (bits * keep))
        remaining = keep
    return [term ^ init_term for term in folded.to_bytes(count, "little")]


@lru_cache(maxsize=1)
def _table_powers() -> tuple[bytes, ...]:
    """TABLE applied 0..8 times: what a byte adds to the register k positions before the end."""
    powers = [bytes(range(256))]
    for _ in range(8):
        powers.append(powers[-1].translate(TABLE))
    return tuple(powers)


def crc8_check_words(words: np.ndarray) -> np.ndarray:
    """Whether each row's CRC checks: rows of a k × m little-endian uint64 array, each a
    packet (CRC byte included) followed by zero bytes up to 8·m.

    The zero padding passes the register through TABLE once per byte, which is one-to-one,
    so it ends at 0 exactly when the packet's does. The register is Horner's scheme over the
    words: advance the 8-byte state by eight positions (one `translate` of every byte), XOR
    in the next word, and at the end fold the eight lanes with their remaining distance.
    That is one table lookup per byte without a Python loop over packets or bytes.
    """
    import numpy as np

    count, width = words.shape
    powers = _table_powers()
    state = words[:, 0].copy()
    for column in range(1, width):
        advanced = np.frombuffer(state.tobytes().translate(powers[8]), "<u8")
        state = advanced ^ words[:, column]
    lanes = state.view(np.uint8).reshape(count, 8)
    register = np.full(count, _init_term(INIT, 8 * width), np.uint8)
    for lane in range(8):
        register ^= np.frombuffer(lanes[:, lane].tobytes().translate(powers[8 - lane]), np.uint8)
    return register == 0
