"""Hypothesis strategies for FSP packets: every field over its whole wire range."""

from __future__ import annotations

import struct

from hypothesis import strategies as st

from wftool.fsp import (
    ArmingAction,
    ArmingRequest,
    Authority,
    AuthorityExit,
    CommandPacket,
    SensorFrame,
    StatePacket,
    UplinkStatus,
)

u16 = st.integers(0, 2**16 - 1)
u24 = st.integers(0, 2**24 - 1)
u32 = st.integers(0, 2**32 - 1)
i16 = st.integers(-(2**15), 2**15 - 1)
# Any float32 bit pattern but NaN (NaN != NaN would make equality meaningless).
f32 = st.integers(0, 2**32 - 1).map(lambda b: struct.unpack("<f", struct.pack("<I", b))[0])
f32 = f32.filter(lambda x: x == x)


def tuples(element: st.SearchStrategy, n: int) -> st.SearchStrategy:
    return st.tuples(*[element] * n)


frames = st.builds(
    SensorFrame,
    sample_time_us=u32,
    acc=tuples(i16, 3),
    acc_1g=i16,
    gyro_scale=f32,
    gyro=tuples(i16, 3),
    attitude=tuples(i16, 4),
    rc=tuples(i16, 6),
    rpm=tuples(u16, 4),
    vbat=u16,
)


def _state_packets(frames: st.SearchStrategy[SensorFrame]) -> st.SearchStrategy[StatePacket]:
    return st.builds(
        StatePacket,
        tx_time_us=u32,
        frames=st.tuples(frames, frames),
        seq=u24,
        e1=st.booleans(),
        drops=u16,
        mavlink=st.none() | st.binary(min_size=64, max_size=64),
    )


state_packets = _state_packets(frames)

u8 = st.integers(0, 255)
command_packets = st.builds(
    CommandPacket, rc=tuples(i16, 6), seq=u24, tx_time_us=u32, at_us=st.none() | u32, sender=u24
)
"""Immediate and timed (E4) commands."""
arming_requests = st.builds(
    ArmingRequest, request=u8.map(ArmingAction), seq=u24, tx_time_us=u32, sender=u24
)
"""E5 arming requests, undefined requests (which the FC refuses) included."""
uplink_statuses = st.builds(
    UplinkStatus, command_seq=u24, tx_time_us=u32, accepted=u32, stale=u32, timeouts=u32,
    rejected=u32, timeout_ms=u16, flags=u8, failsafe_phase=u8, timed_out_us=u32,
) | st.builds(
    UplinkStatus, command_seq=u24, tx_time_us=u32, accepted=u32, stale=u32, timeouts=u32,
    rejected=u32, timeout_ms=u16, flags=u8, failsafe_phase=u8, timed_out_us=u32,
    authority=u8.map(Authority), exit=u8.map(AuthorityExit), proof_ms=u16, exit_us=u32,
    sender=u24, foreign=u32, refused=u32, msp_rc_refused=u32, rc_min_us=u16, rc_max_us=u16,
)  # fmt: skip
"""E3 uplink statuses: of older firmware (36 bytes) and with who flies (64 bytes)."""


@st.composite
def packet_lists(
    draw: st.DrawFn, min_size: int = 0, max_size: int = 30, statuses: bool = False
) -> list[StatePacket | UplinkStatus]:
    """Lists of state packets (uplink statuses among them, `statuses`) for tests of how a
    stream is framed, split and damaged: their frames are taken from up to 8 `frames` drawn
    for the example, rather than each drawn afresh (24 values a frame, 48 a packet: drawing
    them took a third of such a test's time)."""
    pool = st.sampled_from(draw(st.lists(frames, min_size=1, max_size=8)))
    packets = _state_packets(pool) | uplink_statuses if statuses else _state_packets(pool)
    return draw(st.lists(packets, min_size=min_size, max_size=max_size))


corruption = st.one_of(
    st.tuples(st.just("flip"), st.integers(0, 10_000), st.integers(1, 255)),
    st.tuples(st.just("cut"), st.integers(0, 10_000), st.integers(1, 200)),
    st.tuples(st.just("insert"), st.integers(0, 10_000), st.binary(min_size=1, max_size=300)),
)
"""(kind, position, argument) of one harm done to a stream: flip bits, cut bytes, insert."""


def harm(stream: bytearray, kind: str, position: int, arg: int | bytes) -> None:
    """Do one `corruption` to `stream` in place (`position` wraps around its length)."""
    position = position % len(stream) if stream else 0
    if kind == "flip":
        if stream:
            stream[position] ^= arg
    elif kind == "cut":
        del stream[position : position + arg]
    else:
        stream[position:position] = arg
