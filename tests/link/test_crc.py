"""`wftool.link.crc`: every form of the CRC against a bit-at-a-time reference."""

from __future__ import annotations

from hypothesis import example, given, settings
from hypothesis import strategies as st

from tests.tiers import examples
from wftool.link.crc import DVB_S2_INIT, INIT, POLY, crc8, crc8_residues


def bitwise(data: bytes, init: int) -> int:
    """CRC-8, MSB first, no final XOR, one bit at a time (no table)."""
    crc = init
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ POLY) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


@settings(max_examples=examples(300))
@given(st.binary(max_size=400), st.integers(0, 255))
@example(b"\xff" * 117, INIT)
@example(bytes(range(256)), DVB_S2_INIT)
def test_crc8_is_the_bitwise_crc_at_any_length_and_init(data: bytes, init: int) -> None:
    assert crc8(data, init) == bitwise(data, init)


def test_each_length_across_the_byte_loop_and_the_parity_form() -> None:
    """Lengths on both sides of where `crc8` changes form, each one byte set at a time."""
    for length in range(30, 130):
        for position in (0, length // 2, length - 1):
            for bit in range(8):
                data = bytearray(length)
                data[position] = 1 << bit
                assert crc8(bytes(data)) == bitwise(bytes(data), INIT), (length, position, bit)
        assert crc8(memoryview(bytes(range(length)))) == bitwise(bytes(range(length)), INIT)


@settings(max_examples=examples(60))
@given(
    st.integers(1, 200).flatmap(lambda n: st.lists(st.binary(min_size=n, max_size=n), max_size=12))
)
def test_residues_are_zero_exactly_for_packets_that_end_in_their_crc(packets: list[bytes]) -> None:
    sealed = [p[:-1] + bytes([bitwise(p[:-1], INIT)]) for p in packets]
    if packets:
        length = len(packets[0])
        assert crc8_residues(sealed, length) == [0] * len(sealed)
        assert crc8_residues(packets, length) == [bitwise(p, INIT) for p in packets]
