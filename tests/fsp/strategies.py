"""Hypothesis strategies for FSP packets: every field over its whole wire range."""

from __future__ import annotations

import struct

from hypothesis import strategies as st

from wftool.fsp import CommandPacket, SensorFrame, StatePacket

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

state_packets = st.builds(
    StatePacket,
    tx_time_us=u32,
    frames=st.tuples(frames, frames),
    seq=u24,
    e1=st.booleans(),
    drops=u16,
    mavlink=st.none() | st.binary(min_size=64, max_size=64),
)

command_packets = st.builds(CommandPacket, rc=tuples(i16, 6), seq=u24, tx_time_us=u32)
