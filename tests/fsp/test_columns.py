"""The columnar decoder agrees exactly with StateDecoder: frames, times and every count.

StateDecoder is the oracle throughout: each test feeds it the same bytes, read by read with
the same arrival times, and compares every column with the packets and frames it returns.
"""

from __future__ import annotations

import base64
import json
import math
import sys
import tracemalloc
from collections.abc import Sequence
from contextlib import contextmanager
from pathlib import Path
from unittest import mock

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from tests.conftest import run_cli
from tests.fsp.strategies import corruption, harm, packet_lists
from tests.fsp.test_clock import MODEL as CLOCK_MODELS
from tests.fsp.test_clock import splice_step
from tests.fsp.test_decoder import frame
from tests.recording.test_reader import record_two_connections
from tests.tiers import examples
from wftool.bench.clock import simulate
from wftool.errors import UsageError
from wftool.fsp import (
    ClockEstimator,
    ClockState,
    StateDecoder,
    StatePacket,
    StreamStats,
    UplinkStatus,
)
from wftool.fsp.encoder import encode_state, encode_uplink_status
from wftool.fsp.framing import Rejection
from wftool.fsp.packets import FRAME_LAYOUT
from wftool.recording.events import Event
from wftool.recording.reader import recording_columns
from wftool.recording.recorder import FRAME_TOPIC, Recorder

np = pytest.importorskip("numpy", reason="the columnar decoder needs wftool[analysis]")
from wftool.fsp import columns  # noqa: E402 - after the NumPy check
from wftool.fsp.columns import StateColumns, decode_columns  # noqa: E402

STATE_VECTORS = [
    "state_base", "state_e1_wrap", "state_mavlink", "state_damaged", "time_reply_stream",
    "uplink_status_stream", "command_report_stream",
]  # fmt: skip
PERIOD = 953


def reference(
    data: bytes,
    sizes: Sequence[int] | None,
    times: Sequence[float] | None,
    clock: ClockEstimator | None = None,
    connections: Sequence[int] = (),
) -> tuple[list[StatePacket], StreamStats]:
    """What StateDecoder makes of `data` fed in reads of `sizes` stamped `times`, resynced
    before the reads `connections`."""
    decoder = StateDecoder(clock)
    packets: list[StatePacket] = []
    position = 0
    for index, size in enumerate(sizes if sizes is not None else [len(data)]):
        if index in connections:
            decoder.resync()
        arrival = times[index] if times is not None else None
        packets += decoder.feed(data[position : position + size], arrival)
        position += size
    return packets, decoder.stats


def same_float(a: float | None, b: float) -> bool:
    """Equal, with NaN equal to NaN and to None (no time)."""
    if a is None or math.isnan(a):
        return math.isnan(b)
    return a == b


def assert_agree(decoded: StateColumns, packets: list[StatePacket], stats: StreamStats) -> None:
    assert decoded.stats == stats
    frames = [f for p in packets for f in p.frames]
    assert (decoded.packets, len(decoded)) == (len(packets), len(frames))
    for name, _ in FRAME_LAYOUT:
        column = getattr(decoded, name).tolist()
        wire = [getattr(f, name) for f in frames]
        if name == "gyro_scale":  # a damaged packet that passes its CRC may carry a NaN
            assert all(same_float(w, c) for w, c in zip(wire, column, strict=True)), name
        else:
            assert [tuple(c) if isinstance(c, list) else c for c in column] == wire, name
    assert decoded.time_us.tolist() == [f.time_us for f in frames]
    assert all(map(same_float, [f.obc_time for f in frames], decoded.obc_time.tolist()))
    assert decoded.seq.tolist() == [p.seq for p in packets]
    assert decoded.e1.tolist() == [p.e1 for p in packets]
    assert decoded.drops.tolist() == [p.drops for p in packets]
    assert decoded.tx_time_us.tolist() == [p.tx_time_us for p in packets]
    assert decoded.packet_time_us.tolist() == [p.time_us for p in packets]
    assert decoded.epoch.tolist() == [p.epoch for p in packets]
    assert decoded.outlier.tolist() == [p.outlier for p in packets]
    assert all(map(same_float, [p.arrival_time for p in packets], decoded.arrival_time.tolist()))
    assert decoded.tunnel.tolist() == [p.tunnel for p in packets]
    if any(p.tunnel for p in packets):
        assert [bytes(row) for row, p in zip(decoded.mavlink, packets) if p.tunnel] == [
            p.mavlink for p in packets if p.tunnel
        ]
    else:
        assert decoded.mavlink is None


@contextmanager
def small_blocks(scan_bytes: int = 7):
    """Blocks of 3 rows, decoded one by one when the joint decode fails, and `scan_bytes`
    deframed at a time: every block edge and the whole fallback path get exercised by a
    short stream."""
    with mock.patch.multiple(columns, BLOCK_ROWS=3, _SMALL=1, _SCAN_BYTES=scan_bytes):
        yield


def check(
    data: bytes,
    sizes: Sequence[int] | None = None,
    times: Sequence[float] | None = None,
    connections: Sequence[int] = (),
    scan_bytes: int = 7,
) -> StreamStats:
    """Columns agree with StateDecoder, with the normal and the smallest blocks."""
    packets, stats = reference(data, sizes, times, connections=connections)
    assert_agree(decode_columns(data, sizes, times, connections=connections), packets, stats)
    with small_blocks(scan_bytes):
        decoded = decode_columns(data, sizes, times, connections=connections)
        assert_agree(decoded, packets, stats)
    return stats


# -- strategies ------------------------------------------------------------------------------


@st.composite
def reads(draw: st.DrawFn, data: bytes, timed: bool | None = None):
    """Cut `data` into reads; maybe stamp them with OBC times, some gaps longer than a wrap."""
    cuts = sorted(draw(st.lists(st.integers(0, len(data)), max_size=40)))
    sizes = [end - start for start, end in zip([0, *cuts], [*cuts, len(data)])]
    if not (draw(st.booleans()) if timed is None else timed):
        return sizes, None
    steps = st.sampled_from([0.0, 1e-3, 0.05, 0.9, 3.0, 4100.0, 9000.0]) | st.floats(0, 10)
    start = draw(st.floats(0, 1e6))
    times, t = [], start
    for _ in sizes:
        t += draw(steps)
        times.append(t)
    return sizes, times


def damage(wire: bytes, harms: list) -> bytes:
    stream = bytearray(wire)
    for kind, position, arg in harms:
        harm(stream, kind, position, arg)
    return bytes(stream)


@st.composite
def steady_streams(draw: st.DrawFn) -> tuple[bytes, list[float]]:
    """A flight as the FC sends it: E1 on or off, lost packets, FC drops, the u32 wrap, and
    FC reboots, an old packet sent again or one with a wild time; one read per packet,
    stamped by a clock that sometimes stalls for long."""
    e1 = draw(st.booleans())
    t_us = draw(st.integers(2**32 - 400_000, 2**32 - 1) | st.integers(0, 2**32 - 1))
    seq, drops, arrival = draw(st.integers(0, 2**24 - 1)), draw(st.integers(0, 2**16 - 1)), 0.0
    wire, times, sent = b"", [], []
    events = ["send"] * 8 + ["lose", "drop", "reboot", "stall", "jump", "repeat", "wild"]
    for _ in range(draw(st.integers(1, 60))):
        event = draw(st.sampled_from(events))
        if event == "repeat" and sent:
            wire += draw(st.sampled_from(sent[-20:]))
            times.append(arrival)
            continue
        if event == "wild":  # a time that passed the CRC by chance
            near = st.integers(-3000, 1_500_000)  # within a second, as a steady step
            wild = draw(st.integers(0, 2**32 - 1) | near.map(t_us.__add__))
            frames = (frame(wild), frame(wild + PERIOD))
            wire += encode_state(StatePacket(wild % 2**32, frames, seq, e1, drops))
            times.append(arrival)
            t_us, seq, arrival = t_us + 2 * PERIOD, (seq + 1) % 2**24, arrival + 2 * PERIOD * 1e-6
            continue
        if event == "jump":  # seq skips; by half its range or more, a repeat, not a loss
            seq = (seq + draw(st.sampled_from([2**23 - 1, 2**23, 2**23 + 1, 2**24 - 1]))) % 2**24
        elif event == "reboot":
            t_us, seq, arrival = draw(st.integers(0, 5_000_000)), 0, arrival + 2.0
        elif event == "stall":  # the FC keeps time; the OBC reads nothing for a long while
            gap_s = draw(st.sampled_from([5.0, 4100.0, 9000.0]))
            t_us, arrival = t_us + int(gap_s * 1e6), arrival + gap_s
        elif event == "drop":
            drops += draw(st.integers(1, 5))
        first, second = frame(t_us), frame(t_us + PERIOD)
        packet = StatePacket((t_us + PERIOD + 50) % 2**32, (first, second), seq, e1, drops)
        if event != "lose":
            sent.append(encode_state(packet))
            wire += sent[-1]
            times.append(arrival)
        t_us, seq, arrival = t_us + 2 * PERIOD, (seq + 1) % 2**24, arrival + 2 * PERIOD * 1e-6
    return wire, times


# -- tests -----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", STATE_VECTORS)
def test_spec_vectors(vectors_dir: Path, name: str) -> None:
    stats = check((vectors_dir / f"{name}.bin").read_bytes())
    assert stats.packets > 0


@pytest.mark.parametrize("name", STATE_VECTORS)
def test_physical_units_are_the_frames_own(vectors_dir: Path, name: str) -> None:
    data = (vectors_dir / f"{name}.bin").read_bytes()
    frames = [f for p in StateDecoder().feed(data) for f in p.frames]
    decoded = decode_columns(data)
    for unit in ("acc_g", "gyro_dps", "quaternion", "vbat_v"):
        expected = [getattr(f, unit) for f in frames]
        got = getattr(decoded, unit).tolist()
        flat = zip(np.ravel(expected).tolist(), np.ravel(got).tolist(), strict=True)
        assert all(same_float(a, b) for a, b in flat), unit


@settings(max_examples=examples(200), deadline=None)
@given(packet_lists(max_size=30).map(lambda ps: b"".join(map(encode_state, ps))), st.data())
def test_any_packets_any_reads(wire: bytes, data: st.DataObject) -> None:
    check(wire, *data.draw(reads(wire)))


@settings(max_examples=examples(100), deadline=None)
@given(packet_lists(max_size=30, statuses=True), st.data())
def test_uplink_statuses_of_both_lengths_are_counted_as_the_decoder_counts_them(
    packets: list, data: st.DataObject
) -> None:
    wire = b"".join(
        encode_uplink_status(p) if isinstance(p, UplinkStatus) else encode_state(p) for p in packets
    )
    stats = check(wire, *data.draw(reads(wire)))
    assert stats.uplink_statuses == sum(isinstance(p, UplinkStatus) for p in packets)


@settings(max_examples=examples(300), deadline=None)
@given(
    packet_lists(min_size=1, max_size=25).map(lambda ps: b"".join(map(encode_state, ps))),
    st.lists(corruption, max_size=12),
    st.binary(max_size=300),
    st.data(),
)
def test_corrupted_streams(wire: bytes, harms: list, garbage: bytes, data: st.DataObject) -> None:
    stream = garbage + damage(wire, harms)
    check(stream, *data.draw(reads(stream)))


@settings(max_examples=examples(200), deadline=None)
@given(
    packet_lists(max_size=20).map(lambda ps: b"".join(map(encode_state, ps))),
    st.lists(corruption, max_size=4),
    st.data(),
)
def test_reconnects_cut_the_chunk_across(wire: bytes, harms: list, data: st.DataObject) -> None:
    """A connection that breaks off mid-chunk, and one that starts mid-chunk: the cut
    chunks are dropped (or rejected, if too long already) as `StateDecoder.resync` does."""
    stream = damage(wire, harms)
    sizes, times = data.draw(reads(stream))
    connections = data.draw(st.lists(st.integers(1, max(1, len(sizes) - 1)), max_size=5))
    check(stream, sizes, times, [c for c in connections if c < len(sizes)])


@settings(max_examples=examples(200), deadline=None)
@given(
    packet_lists(min_size=1, max_size=12).map(lambda ps: list(map(encode_state, ps))),
    st.lists(st.tuples(st.integers(0, 12), st.integers(0, 40)), max_size=6),
    st.data(),
)
def test_runs_of_zeros_anywhere(encoded: list[bytes], runs: list, data: st.DataObject) -> None:
    stream = b"".join(encoded)
    for index, length in sorted(runs, reverse=True):
        at = sum(map(len, encoded[:index])) - (index % 3 == 1)  # between or inside a packet
        stream = stream[: max(at, 0)] + bytes(length) + stream[max(at, 0) :]
    sizes, times = data.draw(reads(stream))
    connections = data.draw(st.lists(st.integers(1, max(1, len(sizes) - 1)), max_size=3))
    check(stream, sizes, times, [c for c in connections if c < len(sizes)])


def test_a_run_of_zeros_costs_no_memory_for_its_length() -> None:
    """Memory follows the frames decoded, not the garbage: 32 MiB of zeros between two
    packets cost what 4 MiB do (one deframing block's worth, while it is read)."""
    packets = [StatePacket(1000 + i, (frame(i), frame(i + 1)), i, True) for i in range(2)]
    first, second = map(encode_state, packets)
    peaks = {}
    for size in (4 << 20, 32 << 20):
        data = first + bytes(size) + second
        tracemalloc.start()
        try:
            decoded = decode_columns(data)
            peaks[size] = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert decoded.packets == 2 and decoded.stats.errors == 0
    assert peaks[32 << 20] < peaks[4 << 20] + (1 << 20), peaks


@settings(max_examples=examples(200), deadline=None)
@given(steady_streams(), st.booleans())
def test_flights_with_loss_drops_wraps_resets(flight: tuple[bytes, list[float]], timed: bool):
    wire, times = flight
    sizes = [118] * len(times)  # one base packet per read
    check(wire, sizes, times if timed else None)


def test_a_flight_exercises_every_count() -> None:
    """A fixed flight where every bookkeeping path fires, so agreement means something."""
    wire = b""
    t_us = 2**32 - 50 * PERIOD
    for index in range(200):
        if index == 120:
            t_us = 1000  # the FC rebooted
        if index not in (30, 31, 150):  # lost in transport
            frames = (frame(t_us), frame(t_us + PERIOD))
            tx_us = (t_us + PERIOD + 50) % 2**32
            wire += encode_state(StatePacket(tx_us, frames, index, True, 4 * (index > 60)))
        t_us += 2 * PERIOD
    # A chunk longer than any packet, between packets 4 and 5.
    wire = wire[: 4 * 118] + bytes(range(1, 256)) * 2 + b"\x00" + wire[4 * 118 :]
    sizes = [118] * (len(wire) // 118) + [len(wire) % 118]
    times = [100.0 + read * 2 * PERIOD * 1e-6 for read in range(len(sizes))]
    for timed in (None, times):
        stats = check(wire, sizes, timed)
        assert (stats.wraps, stats.resets, stats.lost_packets, stats.fc_drops) == (1, 1, 3, 4)
        assert stats.rejected[Rejection.LENGTH] == 1


@pytest.mark.parametrize("split", [0, 50, 181, 182, 300, 511, 512])
def test_an_over_long_chunk_is_rejected_as_in_the_reads(split: int) -> None:
    """A chunk longer than any packet is dropped undecoded if a read ends past its limit,
    else decoded whole (and then maybe a COBS error): both decoders see the same reads."""
    packets = [StatePacket(1000 + i, (frame(i), frame(i + 1)), i, True) for i in range(3)]
    garbage = bytes([7]) + bytes(range(1, 256)) * 2  # not valid COBS past 7 bytes
    wire = encode_state(packets[0]) + garbage + b"\x00" + b"".join(map(encode_state, packets))
    cut = len(encode_state(packets[0])) + split
    stats = check(wire, [cut, len(wire) - cut])
    assert stats.errors == 1 and stats.packets == 4


def test_a_long_noisy_flight_is_timed_as_state_decoder_times_it() -> None:
    """Long enough for the envelope estimator to lock, track, drop its line and step, with
    a repeated packet and an FC reboot: the batch path of the default estimator agrees."""
    trace = simulate(CLOCK_MODELS["reads 1 ms"], 30, 40.0)
    splice_step(trace, len(trace.arrival) // 2, -0.05)
    packets: list[bytes] = []
    sizes, times = [], []
    reboot = 3 * len(trace.arrival) // 4
    for index, (fc_us, arrival) in enumerate(zip(trace.fc_time_us, trace.arrival)):
        seq = index
        if index >= reboot:  # the FC rebooted: its clock and sequence start over
            fc_us, seq = fc_us - trace.fc_time_us[reboot] + 2_000_000, index - reboot
        sample_us = fc_us - PERIOD - 120
        frames = (frame(sample_us % 2**32), frame((sample_us + PERIOD) % 2**32))
        packet = encode_state(StatePacket(fc_us % 2**32, frames, seq % 2**24, True))
        if index == 5000:
            packet += packets[-100]  # an old packet sent again
        packets.append(packet)
        sizes.append(len(packet))
        times.append(arrival)
    # Deframed 1009 bytes at a time (not 7: 2.5 MB in 7-byte steps took 13 s): not a
    # multiple of the 118-byte packet, so over the flight the scan blocks still end at
    # every byte of a packet, ~20 times each.
    stats = check(b"".join(packets), sizes, times, scan_bytes=1009)
    assert (stats.resets, stats.outliers) == (1, 1)


class LatestArrival:
    """A crude estimator of our own: the newest packet's arrival, shifted by FC time."""

    def __init__(self) -> None:
        self.latest: tuple[int, float] | None = None

    def observe(self, fc_time_us: int, obc_time: float) -> None:
        self.latest = (fc_time_us, obc_time)

    def to_obc(self, fc_time_us: int) -> float | None:
        if self.latest is None:
            return None
        return self.latest[1] + (fc_time_us - self.latest[0]) * 1e-6

    def reset(self) -> None:
        self.latest = None

    @property
    def state(self) -> ClockState:
        return ClockState(self.latest is not None, 0.0, math.nan, math.nan, 0, 0)


@settings(max_examples=examples(50), deadline=None)
@given(steady_streams())
def test_any_clock_estimator_is_told_what_state_decoder_tells_it(flight) -> None:
    wire, times = flight
    sizes = [118] * len(times)
    packets, stats = reference(wire, sizes, times, LatestArrival())
    assert_agree(decode_columns(wire, sizes, times, clock=LatestArrival()), packets, stats)


def test_recording_round_trip(tmp_path: Path) -> None:
    """A recorded run decodes, across its reconnect, to what its live decoder saw, and to
    the frames the recording itself carries (read back with the mcap library)."""
    mcap = tmp_path / "run.mcap"
    record_two_connections(mcap, None, reboot=True)
    decoded = recording_columns(mcap)
    assert len(decoded) == 900
    assert decoded.stats.resets == 1 and decoded.stats.errors == 1
    with open(mcap, "rb") as handle:
        reader = make_reader(handle)
        events = [json.loads(m.data) for _, _, m in reader.iter_messages(topics=["/fsp/events"])]
    chunks, times, connections = [], [], []
    for event in events:
        if event["kind"] == "connected" and chunks:
            connections.append(len(chunks))
        elif event["kind"] == "bytes":
            chunks.append(base64.b64decode(event["data"]))
            times.append(event["t"])
    assert connections == [30]  # 300 packets in reads of 10
    sizes = list(map(len, chunks))
    assert_agree(decoded, *reference(b"".join(chunks), sizes, times, connections=connections))

    with open(mcap, "rb") as handle:  # in written order: log times are OBC times, and
        recorded = [  # the estimator's early ones may step back as its line settles
            json.loads(m.data)
            for _, _, m in make_reader(handle).iter_messages(
                topics=[FRAME_TOPIC], log_time_order=False
            )
        ]
    assert decoded.time_us.tolist() == [m["fc_time_us"] for m in recorded]
    assert decoded.sample_time_us.tolist() == [m["sample_time_us"] for m in recorded]
    assert decoded.acc.tolist() == [m["acc_raw"] for m in recorded]
    assert decoded.rpm.tolist() == [m["rpm"] for m in recorded]
    assert np.repeat(decoded.seq, 2).tolist() == [m["seq"] for m in recorded]
    assert np.repeat(decoded.epoch, 2).tolist() == [m["epoch"] for m in recorded]


def test_bytes_outside_a_connection_is_a_damaged_recording(tmp_path: Path) -> None:
    mcap = tmp_path / "run.mcap"
    with Recorder(mcap, None, {}) as recorder:
        recorder.event(Event("bytes", 1.0, b"\x01\x00"))
    with pytest.raises(UsageError, match="damaged: bytes outside a connection"):
        recording_columns(mcap)


def test_read_sizes_must_cover_the_data() -> None:
    with pytest.raises(ValueError, match="add up"):
        decode_columns(b"\x00" * 10, [4, 4])
    with pytest.raises(ValueError, match="one time per read"):
        decode_columns(b"\x00" * 10, [5, 5], [1.0])


def test_without_numpy_one_line_names_the_extra(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    monkeypatch.setitem(sys.modules, "numpy", None)  # import numpy now raises ImportError
    with pytest.raises(UsageError) as error:
        decode_columns(b"")
    assert str(error.value) == "columnar decoding needs NumPy: pip install 'wftool[analysis]'"
    with pytest.raises(UsageError, match=r"wftool\[analysis\]"):
        recording_columns(tmp_path / "not-even-read.mcap")
    code, out, err = run_cli(capsys, "bench", "decode", "--minutes", "0.01", "--repeat", "1")
    assert (code, out) == (2, "")
    assert err == "error: columnar decoding needs NumPy: pip install 'wftool[analysis]'\n"
