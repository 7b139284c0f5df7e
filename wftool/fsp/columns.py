"""Columnar decoding: a whole FSP capture into NumPy arrays, one per field, with no object per
frame, agreeing exactly with `StateDecoder` fed the same reads (how: docs/design.md).

    run = decode_columns(data, read_sizes, arrival_times)   # needs wftool[analysis]
    run.time_us, run.acc_g, run.obc_time, run.stats
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, fields
from functools import partial
from typing import TYPE_CHECKING, Any

from cobs import cobs

from wftool.extras import require
from wftool.fsp.clock import (
    STEADY_GAP_S,
    STEADY_STEP_US,
    U32,
    BatchObserver,
    ClockEstimator,
    FcClock,
)
from wftool.fsp.decoder import (
    JITTER_US,
    Reading,
    StateDecoder,
    StreamStats,
    follows,
    restarted,
)
from wftool.fsp.framing import STATE_VERSIONS, STREAM_VERSIONS, Rejection, longest_chunk
from wftool.fsp.packets import (
    COMMAND_REPORT_LENGTH,
    DROPS_MODULUS,
    FRAME_LAYOUT,
    HEADER_LAYOUT,
    MAVLINK_FIELD_LENGTH,
    Q15,
    SEQ_MODULUS,
    STATE_LENGTH,
    TRAILER_LAYOUT,
    TUNNEL_LAYOUT,
    UPLINK_STATUS_LENGTHS,
    Layout,
)
from wftool.link.crc import crc8, crc8_check_words

if TYPE_CHECKING:
    import numpy as np

WHAT = "columnar decoding"
"""What needs NumPy, for `wftool.extras.require`."""
BLOCK_ROWS = 4096
"""Rows decoded per `cobs` call and checked per CRC pass: small enough to stay in cache."""
_SCAN_BYTES = 1 << 20
"""Bytes deframed at a time: what a block of garbage costs, at most, while it is read."""
_SMALL = 16
"""A block of rows this small whose joint decode fails is decoded row by row."""
_MAX_CHUNK = longest_chunk(STREAM_VERSIONS)
_BETWEEN = (*UPLINK_STATUS_LENGTHS, COMMAND_REPORT_LENGTH)
"""The packets between the state packets that are counted, not decoded into columns."""
assert max(STATE_VERSIONS) < 254  # so every COBS encoding of a state packet is 1 byte longer


@dataclass(frozen=True, eq=False)
class StateColumns:
    """Decoded state packets as columns. Frames `2i` and `2i + 1` come from packet `i`.

    Per frame, in capture order: the FSP frame fields as on the wire (spec §4), multi-axis
    ones as 2-D arrays, plus `time_us` and `obc_time`. Per packet: the header and trailer
    fields, the packet's own times and its epoch. `stats` is what `StateDecoder.stats`
    would read after the same bytes.
    """

    time_us: np.ndarray
    """int64: FC capture time unwrapped to 64 bits (restarts at the raw value on a reset)."""
    obc_time: np.ndarray
    """float64: capture time on the OBC clock (s); NaN without arrival times."""
    sample_time_us: np.ndarray
    """uint32: the raw FC capture time."""
    acc: np.ndarray
    """int16 × 3."""
    acc_1g: np.ndarray
    gyro_scale: np.ndarray
    """float32: °/s per gyro count."""
    gyro: np.ndarray
    """int16 × 3."""
    attitude: np.ndarray
    """int16 × 4: the quaternion (w, x, y, z) in Q15."""
    rc: np.ndarray
    """int16 × 6: roll, pitch, yaw, throttle, aux3, aux4."""
    rpm: np.ndarray
    """uint16 × 4."""
    vbat: np.ndarray
    """uint16: cV."""
    seq: np.ndarray
    """uint32, per packet: the E1 sequence number."""
    e1: np.ndarray
    """bool, per packet: whether the packet carries the E1 counters."""
    drops: np.ndarray
    """uint16, per packet: the E1 FC-side drop counter."""
    tx_time_us: np.ndarray
    """uint32, per packet: the raw FC send time."""
    packet_time_us: np.ndarray
    """int64, per packet: the send time unwrapped like `time_us`."""
    arrival_time: np.ndarray
    """float64, per packet: OBC time of the read that completed the packet; NaN if unknown."""
    epoch: np.ndarray
    """int64, per packet: FC resets seen up to and including this packet."""
    outlier: np.ndarray
    """bool, per packet: `StatePacket.outlier` (times provisional, left out of the books)."""
    tunnel: np.ndarray
    """bool, per packet: the 180-byte variant."""
    mavlink: np.ndarray | None
    """uint8 × 64, per packet: the tunnel field (zero for base packets); None if no tunnel."""
    stats: StreamStats

    def __len__(self) -> int:
        return len(self.time_us)

    @property
    def packets(self) -> int:
        return len(self.seq)

    @property
    def nbytes(self) -> int:
        """Memory the arrays hold."""
        return sum(
            value.nbytes
            for field in fields(self)
            if hasattr(value := getattr(self, field.name), "nbytes")
        )

    @property
    def acc_g(self) -> np.ndarray:
        """Acceleration in g; NaN while the FC reports no 1 g calibration (acc_1g = 0)."""
        import numpy as np

        one_g = np.where(self.acc_1g == 0, np.nan, self.acc_1g.astype(np.float64))
        return self.acc / one_g[:, None]

    @property
    def gyro_dps(self) -> np.ndarray:
        return self.gyro * self.gyro_scale.astype("float64")[:, None]

    @property
    def quaternion(self) -> np.ndarray:
        """(w, x, y, z); −32768 reads as −1.0 (spec §4)."""
        return self.attitude / Q15

    @property
    def vbat_v(self) -> np.ndarray:
        return self.vbat / 100.0


def decode_columns(
    data: bytes,
    read_sizes: Sequence[int] | np.ndarray | None = None,
    arrival_times: Sequence[float] | np.ndarray | None = None,
    *,
    clock: ClockEstimator | str | None = None,
    connections: Sequence[int] = (),
) -> StateColumns:
    """Decode `data` as a fresh `StateDecoder` would, fed it read by read.

    `read_sizes` are the lengths of the reads `data` arrived in (default: one read); they
    matter only where an over-long chunk spans reads. `arrival_times` holds each read's OBC
    time (s) and enables OBC times through `clock`, an estimator or its name as
    `StateDecoder` takes it (default: `StateDecoder`'s default). `connections` are the
    indices of the reads that began a new connection after the first: the decoder was
    `resync`ed before each.
    """
    require("analysis", "numpy", what=WHAT)
    import numpy as np

    buf = np.frombuffer(data, np.uint8)
    size = len(buf)
    if read_sizes is None:
        if arrival_times is not None and len(arrival_times) != 1:
            raise ValueError("arrival_times needs read_sizes, one time per read")
        read_ends = np.array([size], np.int64)
    else:
        read_ends = np.cumsum(np.asarray(read_sizes, np.int64))
        total = read_ends[-1] if len(read_ends) else 0
        if total != size or np.any(np.diff(read_ends, prepend=0) < 0):
            raise ValueError("read_sizes must be non-negative and add up to len(data)")
        if arrival_times is not None and len(arrival_times) != len(read_ends):
            raise ValueError("arrival_times needs one time per read")
    starts = np.asarray(connections, np.int64)
    if np.any((starts < 1) | (starts >= len(read_ends))):
        raise ValueError("connections must be indices of reads after the first")
    cuts = np.unique(read_ends[starts - 1])  # where each of those reads begins

    stats = StreamStats(bytes=size, rejected=dict.fromkeys(Rejection, 0))
    parts: dict[str, list] = {}
    for block in _deframe(np, data, buf, read_ends, cuts, stats):
        for name, part in _block_columns(np, *block).items():
            parts.setdefault(name, []).append(part)
    if not parts:
        empty = np.zeros(0, _record_dtype(np, STATE_LENGTH, STATE_LENGTH))
        parts = {
            name: [part] for name, part in _block_columns(np, np.zeros(0, np.int64), empty).items()
        }
    tunnels = parts.pop("mavlink")
    if any(len(part) for part in tunnels if part is not None):
        parts["mavlink"] = [
            np.zeros((len(p), MAVLINK_FIELD_LENGTH), np.uint8) if m is None else m
            for m, p in zip(tunnels, parts["position"])
        ]
    raw = {name: np.concatenate(parts.pop(name)) for name in list(parts)}  # freeing as it goes
    if raw["tunnel"].any() and not raw["tunnel"].all():  # both variants: merge in order
        order = np.argsort(raw["position"], kind="stable")
        raw = {name: column[order] for name, column in raw.items()}

    arrival = None
    if arrival_times is not None:
        times = np.asarray(arrival_times, np.float64)
        arrival = times[np.searchsorted(read_ends, raw["position"], side="right")]
    return _timed(np, raw, arrival, clock, stats)


def _block_columns(np: Any, positions: np.ndarray, records: np.ndarray) -> dict[str, Any]:
    """The raw columns of one block of records, copied while the block is in cache."""
    names = records.dtype.names or ()  # a structured array: never None
    frames = records["frames"]
    columns = {name: np.ascontiguousarray(frames[name]) for name, _ in FRAME_LAYOUT}
    columns.update(
        position=positions,
        seq=records["seq_low"] | records["seq_high"].astype(np.uint32) << 8,
        e1=records["reserved2_high"] >= 0x80,
        drops=np.ascontiguousarray(records["drops"]),
        tx_time_us=np.ascontiguousarray(records["tx_time_us"]),
        tunnel=np.full(len(records), "mavlink" in names),
        mavlink=np.ascontiguousarray(records["mavlink"]) if "mavlink" in names else None,
    )
    return columns


# -- bytes to accepted packet records ---------------------------------------------------------


def _field_dtype(np: Any, layout: Layout) -> list[tuple]:
    """`layout`'s `struct` codes as NumPy fields: "3h" is 3 × int16, "64s" is 64 × uint8."""
    dtype: list[tuple] = []
    for name, code in layout:
        count, kind = int(code[:-1] or 1), code[-1]
        if kind == "s":
            dtype.append((name, np.uint8, (count,)))
        else:
            dtype.append((name, "<" + kind, (count,)) if count > 1 else (name, "<" + kind))
    return dtype


def _record_dtype(np: Any, length: int, width: int) -> np.dtype:
    """The state packet of `length` bytes as a structured dtype, padded to `width` bytes."""
    tunnel = _field_dtype(np, TUNNEL_LAYOUT) if length != STATE_LENGTH else []
    frame = np.dtype(_field_dtype(np, FRAME_LAYOUT))
    packed = np.dtype(
        [
            *_field_dtype(np, HEADER_LAYOUT),
            ("frames", frame, (2,)),
            *tunnel,
            *_field_dtype(np, TRAILER_LAYOUT),
        ]
    )
    if packed.itemsize != length:
        raise AssertionError(f"layout of {packed.itemsize} bytes for a {length}-byte packet")
    names = packed.names
    return np.dtype(
        {
            "names": names,
            "formats": [packed.fields[name][0] for name in names],
            "offsets": [packed.fields[name][1] for name in names],
            "itemsize": width,
        }
    )


def _boundaries(
    np: Any, buf: np.ndarray, cuts: np.ndarray
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Where chunks end, a scan block at a time, in order: (positions, whether each is a cut
    rather than a delimiter, the earliest start of each one's chunk: past the last delimiter
    before it). The end of the data comes last, as a cut.

    A delimiter right after another ends an empty chunk, which counts nowhere: it is left
    out, so garbage such as a long run of zeros costs no memory.
    """
    size = len(buf)
    previous = -1  # the last delimiter so far
    for start in range(0, max(size, 1), _SCAN_BYTES):
        stop = min(start + _SCAN_BYTES, size)
        last = stop == size
        zeros = np.flatnonzero(buf[start:stop] == 0)
        zeros += start
        kept = np.flatnonzero(np.diff(zeros, prepend=previous) > 1)
        here = cuts[(cuts >= start) & ((cuts <= stop) if last else (cuts < stop))]
        if last:
            here = np.append(here, size)
        if not (len(kept) or len(here)):
            previous = int(zeros[-1]) if len(zeros) else previous
            continue
        behind = np.searchsorted(zeros, here)  # how many delimiters of the block precede
        floors = np.concatenate(([previous], zeros))[np.concatenate((kept, behind))] + 1
        ends = np.concatenate((zeros[kept], here))
        cut = np.concatenate((np.zeros(len(kept), bool), np.ones(len(here), bool)))
        if len(zeros):
            previous = int(zeros[-1])
        order = np.lexsort((~cut, ends))  # a cut ends the chunk before a delimiter there
        yield ends[order], cut[order], floors[order]


def _deframe(
    np: Any,
    data: bytes,
    buf: np.ndarray,
    read_ends: np.ndarray,
    cuts: np.ndarray,
    stats: StreamStats,
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Blocks of accepted packets: (delimiter position of each, its record), in stream
    order within each packet length and scan block. Counts the rejections, and the uplink
    statuses (E3) and command reports (E4) between the packets, as it goes.

    Mirrors `framing.Deframer` fed read by read: a chunk is dropped undecoded (LENGTH) when
    at the end of some read more than `_MAX_CHUNK` of it had arrived; a chunk that no
    delimiter completes is pending, not rejected, and so is one cut off at `cuts`, where the
    byte stream broke (`Deframer.resync`): the next chunk begins there.
    """
    rejected = stats.rejected
    bounds = np.concatenate(([0], read_ends))
    encoded = {length + 1: length for length in STATE_VERSIONS}
    after = 0  # where the next chunk begins: past the last delimiter, or right at the cut
    # Chunks end at delimiters, at cuts and (the pending tail) at the end of the data.
    for ends, cut, floors in _boundaries(np, buf, cuts):
        starts = np.concatenate(([after], ends[:-1] + ~cut[:-1]))
        np.maximum(starts, floors, out=starts)  # a delimiter left out ends an empty chunk
        after = int(ends[-1]) + (not cut[-1])
        lengths = ends - starts
        last_read_end = bounds[np.searchsorted(bounds, ends, side="right") - 1]
        discarded = last_read_end - starts > _MAX_CHUNK
        rejected[Rejection.LENGTH] += int(np.count_nonzero(discarded))
        complete = ~discarded & (lengths > 0) & ~cut

        candidate = complete & np.isin(lengths, list(encoded))
        other = complete & ~candidate
        for start, end in zip(starts[other].tolist(), ends[other].tolist()):
            try:
                payload = cobs.decode(data[start:end])
            except cobs.DecodeError:
                rejected[Rejection.COBS] += 1
                continue
            if len(payload) not in _BETWEEN:
                rejected[Rejection.LENGTH] += 1  # no other length can decode to a packet
            elif payload[0] != STREAM_VERSIONS[len(payload)]:
                rejected[Rejection.VERSION] += 1
            elif crc8(payload[:-1]) != payload[-1]:
                rejected[Rejection.CRC] += 1
            elif len(payload) in UPLINK_STATUS_LENGTHS:
                stats.uplink_statuses += 1
            else:
                stats.command_reports += 1

        for encoded_length, length in encoded.items():
            rows = np.flatnonzero(candidate & (lengths == encoded_length))
            if len(rows) == 0:
                continue
            windows = np.lib.stride_tricks.sliding_window_view(buf, encoded_length)
            width = 8 * -(-encoded_length // 8)  # whole uint64 words, for the CRC
            dtype = _record_dtype(np, length, width)
            for first in range(0, len(rows), BLOCK_ROWS):
                block = rows[first : first + BLOCK_ROWS]
                payloads = np.zeros((len(block), width), np.uint8)
                decoded = _decode_rows(np, windows[starts[block]], payloads)
                keep = _accepted(np, payloads, decoded, length, rejected)
                records = payloads.view(dtype)[:, 0]
                if not keep.all():
                    records, block = records[keep], block[keep]
                yield ends[block], records


def _decode_rows(np: Any, chunks: np.ndarray, payloads: np.ndarray) -> np.ndarray:
    """Decode each row of `chunks` into the same row of `payloads`; return which decoded.

    A decoded row is followed by a 0 byte in `payloads` (the CRC check relies on it).
    """
    count, encoded_length = chunks.shape
    try:
        joined = cobs.decode(chunks.tobytes())
    except cobs.DecodeError:
        joined = b""
    if len(joined) == count * encoded_length - 1:
        # No 0xFF code was met, so output byte i is input byte i + 1, and it is 0 exactly
        # when input byte i + 1 was a code: the decode passed through it. A row decodes on
        # its own when the joint decode entered it at its first byte and left at its last.
        flat = np.frombuffer(joined, np.uint8)
        split = (count - 1) * encoded_length
        out = payloads[:, :encoded_length]
        out[:-1] = flat[:split].reshape(count - 1, encoded_length)
        out[-1, :-1] = flat[split:]
        out[-1, -1] = 0
        decoded = out[:, -1] == 0
        decoded[1:] &= out[:-1, -1] == 0
        for row in np.flatnonzero(~decoded).tolist():
            decoded[row] = _decode_row(np, chunks[row], payloads[row])
        return decoded
    if count <= _SMALL:
        return np.array([_decode_row(np, c, p) for c, p in zip(chunks, payloads)], bool)
    half = count // 2
    return np.concatenate(
        [
            _decode_rows(np, chunks[:half], payloads[:half]),
            _decode_rows(np, chunks[half:], payloads[half:]),
        ]
    )


def _decode_row(np: Any, chunk: np.ndarray, payload: np.ndarray) -> bool:
    payload[:] = 0
    try:
        decoded = cobs.decode(chunk.tobytes())
    except cobs.DecodeError:
        return False
    payload[: len(decoded)] = np.frombuffer(decoded, np.uint8)
    return True


def _accepted(
    np: Any, payloads: np.ndarray, decoded: np.ndarray, length: int, rejected: dict
) -> np.ndarray:
    """Which rows pass, counting the others under their cause in `Deframer`'s order."""
    rejected[Rejection.COBS] += len(decoded) - int(np.count_nonzero(decoded))
    versioned = decoded & (payloads[:, 0] == STATE_VERSIONS[length])
    rejected[Rejection.VERSION] += int(np.count_nonzero(decoded & ~versioned))
    checked = versioned & crc8_check_words(payloads.view("<u8"))
    rejected[Rejection.CRC] += int(np.count_nonzero(versioned & ~checked))
    return checked


# -- times and bookkeeping --------------------------------------------------------------------


def _timed(
    np: Any,
    raw: dict[str, np.ndarray],
    arrival_time: np.ndarray | None,
    clock: ClockEstimator | str | None,
    stats: StreamStats,
) -> StateColumns:
    """Unwrap, count loss and align clocks the way `StateDecoder.feed` does, per packet."""
    count = len(raw["seq"])
    sample_time_us = raw["sample_time_us"].astype(np.int64)
    base_raw, second_raw = sample_time_us[:, 0], sample_time_us[:, 1]
    seq = np.where(raw["e1"], raw["seq"].astype(np.int64), -1)  # -1: no E1
    period = (second_raw - base_raw) % U32
    outlier, restart = _order(
        np, base_raw, period, arrival_time, seq, raw["drops"].astype(np.int64)
    )
    # The booked packets (all but outliers) are unwrapped as one chain ...
    booked = np.flatnonzero(~outlier)
    chain_us, chain_reset, wraps = _unwrap(
        np,
        base_raw[booked],
        None if arrival_time is None else arrival_time[booked],
        restart[booked],
    )
    base_us = np.zeros(count, np.int64)
    reset = np.zeros(count, bool)
    base_us[booked], reset[booked] = chain_us, chain_reset
    # ... and an outlier is timed as the nearest instant to the packet booked before it.
    outliers = np.flatnonzero(outlier)
    if len(outliers):
        before = booked[np.searchsorted(booked, outliers) - 1]  # the first one is booked
        step = (base_raw[outliers] - base_raw[before]) % U32
        base_us[outliers] = base_us[before] + np.where(step >= U32 // 2, step - U32, step)
    second_us = base_us + (second_raw - base_raw) % U32
    packet_time_us = base_us + (raw["tx_time_us"].astype(np.int64) - base_raw) % U32
    epoch = np.cumsum(reset, dtype=np.int64)
    chain = {key: raw[key][booked] for key in ("e1", "seq", "drops")}
    _count_loss(np, chain, base_us[booked], second_us[booked], chain_reset, stats)
    stats.packets, stats.frames = count, 2 * count
    stats.e1 = bool(raw["e1"][-1]) if count else None
    stats.wraps, stats.resets = wraps, int(epoch[-1]) if count else 0
    stats.outliers = len(outliers)

    time_us = np.stack([base_us, second_us], axis=1).reshape(-1)
    if arrival_time is None:
        obc_time = np.full(2 * count, np.nan)
        arrival_time = np.full(count, np.nan)
    else:
        estimator = StateDecoder(clock).clock  # the estimator StateDecoder would use
        obc_time = _obc_times(np, estimator, reset, outlier, packet_time_us, arrival_time, time_us)
    frames = {name: raw[name].reshape(2 * count, *raw[name].shape[2:]) for name, _ in FRAME_LAYOUT}
    return StateColumns(
        time_us=time_us,
        obc_time=obc_time,
        **frames,
        seq=raw["seq"],
        e1=raw["e1"],
        drops=raw["drops"],
        tx_time_us=raw["tx_time_us"],
        packet_time_us=packet_time_us,
        arrival_time=arrival_time,
        epoch=epoch,
        outlier=outlier,
        tunnel=raw["tunnel"],
        mavlink=raw.get("mavlink"),
        stats=stats,
    )


def _order(
    np: Any,
    raw: np.ndarray,
    period: np.ndarray,
    obc: np.ndarray | None,
    seq: np.ndarray,
    drops: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """(outliers, booked packets whose E1 `seq` restarted) as `StateDecoder` finds them.

    Where each packet `follows` the one before (`decoder.follows`, here on whole arrays)
    there is nothing to decide; from each packet that does not, the decoder's walk is
    repeated packet by packet until a packet follows the newest booked one again.
    """
    count = len(raw)
    outlier = np.zeros(count, bool)
    restart = np.zeros(count, bool)
    if count < 2:
        return outlier, restart
    step = (raw[1:] - raw[:-1]) % U32
    steady = step < STEADY_STEP_US
    if obc is not None:
        steady &= obc[1:] - obc[:-1] < STEADY_GAP_S
    sent = (seq[1:] - seq[:-1]) % SEQ_MODULUS
    expected = (2 * sent + (drops[1:] - drops[:-1]) % DROPS_MODULUS) * period[:-1]
    in_place = np.abs(step - expected) <= expected // 2 + JITTER_US
    periodic = (period[:-1] > 0) & (period[:-1] < STEADY_STEP_US)
    in_seq = (sent > 0) & (sent < SEQ_MODULUS // 2) & (in_place | ~periodic)
    steady &= in_seq | (seq[1:] < 0) | (seq[:-1] < 0)

    def reading(index: int) -> Reading:
        number = int(seq[index])
        return (
            int(raw[index]),
            int(period[index]),
            None if obc is None else float(obc[index]),
            None if number < 0 else number,
            int(drops[index]),
        )

    end = 0
    for start in (np.flatnonzero(~steady) + 1).tolist():
        if start < end:
            continue
        last, suspect = start - 1, None
        index = start
        while index < count:
            if follows(reading(last), reading(index)):
                last, suspect = index, None  # an earlier suspect stays an outlier
            elif suspect is not None and follows(reading(suspect), reading(index)):
                outlier[suspect] = False
                restart[suspect] = restarted(reading(last), reading(suspect))
                last, suspect = index, None
            else:
                outlier[index] = True
                suspect = index
            index += 1
            if suspect is None:
                break
        end = index
    return outlier, restart


def _unwrap(
    np: Any, raw: np.ndarray, obc: np.ndarray | None, restart: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int]:
    """(64-bit times, where a reset happened, wraps) of `FcClock` fed `raw` and `obc`;
    `restart` marks the readings whose stream started over (`FcClock.unwrap(restarted=)`).

    A steady step is forward by its u32 difference; every other step (a long gap, a jump
    back, a reboot) is decided by an `FcClock` that has seen only the reading before it,
    which is all `FcClock.unwrap` looks at. Within an epoch times are then cumulative.
    """
    count = len(raw)
    reset = np.zeros(count, bool)
    if count == 0:
        return raw.copy(), reset, 0
    steps = np.zeros(count, np.int64)
    steps[1:] = (raw[1:] - raw[:-1]) % U32
    steady = steps < STEADY_STEP_US
    if obc is not None:
        steady[1:] &= obc[1:] - obc[:-1] < STEADY_GAP_S
    steady[0] = True
    for index in np.flatnonzero(~steady).tolist():
        fc_clock = FcClock()
        before, after = (None, None) if obc is None else obc[index - 1 : index + 1].tolist()
        fc_clock.unwrap(int(raw[index - 1]), before)
        time_us, reset[index] = fc_clock.unwrap(
            int(raw[index]), after, restarted=bool(restart[index])
        )
        steps[index] = time_us - raw[index - 1]
    # Each epoch starts at its raw reading and adds up its steps from there.
    starts = np.flatnonzero(reset)
    steps[starts] = 0
    steps[0] = 0
    cumulative = np.cumsum(steps)
    epoch_start = np.zeros(count, np.int64)
    epoch_start[starts] = starts
    epoch_start = np.maximum.accumulate(epoch_start)
    times = cumulative - cumulative[epoch_start] + raw[epoch_start]
    laps = times // U32
    wraps = int(np.sum((laps[1:] - laps[:-1])[~reset[1:]]))
    return times, reset, wraps


def _count_loss(
    np: Any,
    raw: dict[str, np.ndarray],
    base_us: np.ndarray,
    second_us: np.ndarray,
    reset: np.ndarray,
    stats: StreamStats,
) -> None:
    """`StateDecoder._count_loss` over every pair of consecutive booked packets of one epoch."""
    same_epoch = ~reset[1:]  # a packet after a reset has no predecessor to compare with
    e1 = raw["e1"][1:] & raw["e1"][:-1] & same_epoch
    seq = raw["seq"].astype(np.int64)
    gap = (seq[1:] - seq[:-1] - 1) % SEQ_MODULUS
    lost = np.where(e1 & (gap < SEQ_MODULUS // 2), gap, 0)  # larger: a repeat or reorder
    drops = raw["drops"].astype(np.int64)
    stats.lost_packets += int(lost.sum())
    stats.lost_frames += 2 * int(lost.sum())
    stats.fc_drops += int(np.where(e1, (drops[1:] - drops[:-1]) % DROPS_MODULUS, 0).sum())

    timed = same_epoch & ~e1
    period = (second_us - base_us)[1:]
    timed &= period > 0
    if timed.any():
        missing = np.rint((base_us[1:][timed] - second_us[:-1][timed]) / period[timed]) - 1
        stats.lost_frames += int(np.maximum(missing, 0).sum())


def _obc_times(
    np: Any,
    clock: ClockEstimator,
    reset: np.ndarray,
    outlier: np.ndarray,
    packet_time_us: np.ndarray,
    arrival_time: np.ndarray,
    time_us: np.ndarray,
) -> np.ndarray:
    """Each frame's OBC time from `clock`, told packet by packet what `StateDecoder` tells it.

    Each run of booked packets of one epoch goes to the estimator at once if it takes runs
    (`BatchObserver`, as the default one does), else packet by packet (`_track_each`).
    """
    track = clock.track if isinstance(clock, BatchObserver) else partial(_track_each, np, clock)
    frame_us = time_us.reshape(-1, 2)
    out = np.empty(frame_us.shape)
    start = 0
    for index in [*np.flatnonzero(reset | outlier).tolist(), len(reset)]:
        if start < index:
            out[start:index] = track(
                packet_time_us[start:index], arrival_time[start:index], frame_us[start:index]
            )
        if index == len(reset):
            break
        if reset[index]:  # booked: the next run starts with it
            clock.reset()
            start = index
        else:  # an outlier: timed, not observed
            out[index] = [_nan_for_none(clock.to_obc(t)) for t in frame_us[index].tolist()]
            start = index + 1
    return out.reshape(-1)


def _nan_for_none(value: float | None) -> float:
    return math.nan if value is None else value


def _track_each(
    np: Any, clock: ClockEstimator, fc_time_us: np.ndarray, obc_time: np.ndarray, at_us: np.ndarray
) -> np.ndarray:
    """`BatchObserver.track` for any estimator: observe and map packet by packet."""
    observe, to_obc = clock.observe, clock.to_obc
    out = array("d")
    append = out.append
    for fc_us, arrived, row in zip(fc_time_us.tolist(), obc_time.tolist(), at_us.tolist()):
        observe(fc_us, arrived)
        for t in row:
            mapped = to_obc(t)
            append(math.nan if mapped is None else mapped)
    return np.frombuffer(out, np.float64).reshape(at_us.shape)
