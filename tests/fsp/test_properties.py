"""Property tests: round trips, arbitrary read splits, and corruption that never breaks us."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from tests.fsp.strategies import (
    arming_requests,
    command_packets,
    corruption,
    harm,
    packet_lists,
    state_packets,
    uplink_statuses,
)
from tests.tiers import examples
from wftool.fsp import CommandDecoder, StateDecoder, UplinkStatus
from wftool.fsp.encoder import (
    encode_arming_request,
    encode_command,
    encode_state,
    encode_uplink_status,
)
from wftool.fsp.packets import pack_state
from wftool.link.crc import crc8


@given(st.lists(state_packets, min_size=1, max_size=40))
def test_state_round_trip(packets):
    wire = b"".join(encode_state(p) for p in packets)
    assert StateDecoder().feed(wire) == packets


@given(st.lists(command_packets | arming_requests, min_size=1, max_size=40))
def test_uplink_round_trip(packets):
    encode = {"CommandPacket": encode_command, "ArmingRequest": encode_arming_request}
    wire = b"".join(encode[type(p).__name__](p) for p in packets)
    assert CommandDecoder().feed(wire) == packets


@given(st.lists(state_packets | uplink_statuses, min_size=1, max_size=30))
def test_uplink_statuses_of_both_lengths_come_between_the_state_packets(packets):
    decoder = StateDecoder()
    states = []
    for packet in packets:
        if isinstance(packet, UplinkStatus):
            decoder.feed(encode_uplink_status(packet))
            assert decoder.uplink_status == packet
        else:
            states += decoder.feed(encode_state(packet))
    assert states == [p for p in packets if not isinstance(p, UplinkStatus)]
    assert decoder.stats.errors == 0


@given(packet_lists(min_size=1, max_size=30), st.data())
def test_any_split_of_the_stream_gives_the_same_result(packets, data):
    wire = b"".join(encode_state(p) for p in packets)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(wire)), max_size=50)))
    decoder = StateDecoder()
    out = []
    for start, end in zip([0, *cuts], [*cuts, len(wire)]):
        out += decoder.feed(wire[start:end])
    whole = StateDecoder()
    assert out == whole.feed(wire) == packets
    assert decoder.stats == whole.stats


@settings(max_examples=examples(300))
@given(
    packet_lists(min_size=1, max_size=25),
    st.lists(st.tuples(st.integers(0, 24), corruption), max_size=12),
    st.binary(max_size=300),
)
def test_corruption_never_raises_never_passes_bad_crc_and_keeps_untouched(
    packets, damage, leading_garbage
):
    segments = [bytearray(encode_state(p)) for p in packets]
    touched = set()
    for index, (kind, position, arg) in damage:
        if index >= len(segments):
            continue
        harm(segments[index], kind, position, arg)
        touched.add(index)

    stream = bytearray(leading_garbage)
    if stream and stream[-1] != 0:
        stream.append(0)  # otherwise the garbage legitimately merges into packet 0
    intact = []
    for index, segment in enumerate(segments):
        preceded_by_delimiter = not stream or stream[-1] == 0
        if index not in touched and preceded_by_delimiter:
            intact.append(packets[index])
        stream += segment

    decoder = StateDecoder()
    out = []
    for start in range(0, len(stream), 97):
        out += decoder.feed(bytes(stream[start : start + 97]))

    for packet in out:
        payload = pack_state(packet)
        assert crc8(payload[:-1]) == payload[-1]
    remaining = iter(out)
    assert all(any(p == q for q in remaining) for p in intact), "an untouched packet was lost"


@given(st.binary(max_size=5000))
def test_arbitrary_bytes_never_raise(data):
    decoder = StateDecoder()
    decoder.feed(data)
    decoder.feed(data[::-1])
    assert decoder.stats.bytes == 2 * len(data)
