"""Table 1's statistics against recordings with known intervals, and bad input.

The recordings are written by the real recorders (FSP: `Recorder`, both formats, and the
raw bytes as a capture; MSP: `MspRecorder`) from sample times chosen here, with a gap, an
FC reset and a reconnection; the expected figures are computed from those times by plain
Python, not by the code under test.
"""

from __future__ import annotations

import itertools
import json
import math
import random
from pathlib import Path

import pytest
from mcap.writer import Writer

from tests.conftest import NEEDS_MATPLOTLIB, run_cli
from tests.recording.test_reader import RecordingMonitor
from wftool.errors import UsageError
from wftool.fc.msp import Cmd, MspVersion, encode_request
from wftool.fc.msp_poller import MspReply
from wftool.fsp import SensorFrame, StatePacket
from wftool.fsp.encoder import encode_state
from wftool.recording.events import run_metadata
from wftool.recording.msp import MspRecorder
from wftool.recording.recorder import Recorder
from wftool.verify.session import replay

np = pytest.importorskip("numpy", reason="needs the analysis extra (NumPy)")
pytestmark = NEEDS_MATPLOTLIB

from wftool.analysis.timing import load_timing, table_rows  # noqa: E402

EXPECTED_HZ = 1000.0
STEPS_US = (960, 980, 1000, 1000, 1000, 1020, 1040, 2000)
"""Frame-to-frame steps: jitter around 1 ms, and now and then a frame the FC skipped
(within what the decoder takes as the stream going on)."""
Packet = tuple[int, int, int]
"""(E1 seq, first frame's time, second frame's time), µs."""


def lower(values: list[float], q: float) -> float:
    """The q-quantile as a value that occurred: sorted[floor(q (n - 1))]."""
    ordered = sorted(values)
    return ordered[math.floor(q * (len(ordered) - 1))]


def check_stats(stats, deltas_us: list[float]) -> None:
    assert stats.count == len(deltas_us)
    assert stats.mean_us == pytest.approx(sum(deltas_us) / len(deltas_us), rel=1e-12)
    assert stats.p50_us == pytest.approx(lower(deltas_us, 0.5))
    assert stats.p1_us == pytest.approx(lower(deltas_us, 0.01))
    assert stats.p99_us == pytest.approx(lower(deltas_us, 0.99))
    assert stats.spread_us == pytest.approx(lower(deltas_us, 0.99) - lower(deltas_us, 0.01))


def frame(t_us: int) -> SensorFrame:
    return SensorFrame(
        t_us % 2**32, (0, 0, -2048), 2048, 0.06, (0, 0, 0), (32767, 0, 0, 0), (1500,) * 6,
        (0,) * 4, 1600,
    )  # fmt: skip


def packets(rng: random.Random, start_us: int, count: int, seq: int) -> list[Packet]:
    out, t = [], start_us
    for index in range(count):
        second = t + rng.choice(STEPS_US)
        out.append((seq + index, t, second))
        t = second + rng.choice(STEPS_US)
    return out


def fsp_run() -> list[list[list[Packet]]]:
    """Per connection, its stretches of packets. Connection 1: A; the FC stalls 0.5 s (a
    gap); B, three of whose packets are lost in transport (one interval to leave out); the
    FC reboots (time and seq start over); C. The port is gone for 1000 packets (about 2 s,
    a gap); connection 2: D. B is the longest."""
    rng = random.Random(11)
    a = packets(rng, 4_000_000, 100, 0)
    b = packets(rng, a[-1][2] + 500_000, 400, a[-1][0] + 1)
    del b[150:153]
    c = packets(rng, 2_000_000, 150, 0)
    d = packets(rng, c[-1][2] + 1000, 1050, c[-1][0] + 1)[1000:]
    return [[a, b, c], [d]]


def write_fsp(path: Path, record_format: str) -> bytes:
    """The run through the real recorder; returns connection 1's bytes (a raw capture)."""
    metadata = run_metadata("socket://sim:5762", 2_000_000, EXPECTED_HZ, None)
    capture = b""
    t_obc, previous = 100.0, None
    with Recorder(path, None, metadata, record_format) as recorder:
        live = RecordingMonitor(recorder)
        for number, connection in enumerate(fsp_run()):
            live.connected(t_obc)
            for stretch in connection:
                for seq, first, second in stretch:
                    # The OBC clock moves with the FC's, across the gaps too; after the FC
                    # rebooted (its clock went back) it moves on by 10 ms.
                    moved = previous is not None and second > previous
                    t_obc += (second - previous) * 1e-6 if moved else 0.01
                    previous = second
                    packet = StatePacket(second + 80, (frame(first), frame(second)), seq, True, 0)
                    wire = encode_state(packet)
                    live.feed(wire, t_obc)
                    if number == 0:
                        capture += wire
            live.disconnected(t_obc + 0.001)
    return capture


def frame_times(stretch: list[Packet]) -> list[int]:
    return [t for _, first, second in stretch for t in (first, second)]


def deltas_of(stretch: list[Packet]) -> list[float]:
    """The intervals that count: all within a packet; between packets, only the next seq's."""
    deltas = []
    for index, (seq, first, second) in enumerate(stretch):
        if index and seq == stretch[index - 1][0] + 1:
            deltas.append(float(first - stretch[index - 1][2]))
        deltas.append(float(second - first))
    return deltas


def gap(before: list[Packet], after: list[Packet]) -> str:
    return f"gap of {(after[0][1] - before[-1][2]) * 1e-6:.3g} s"


@pytest.mark.parametrize("record_format", ["ros2", "json"])
def test_fsp_recording_known_intervals_split_at_gaps_and_reset(
    tmp_path: Path, record_format: str
) -> None:
    path = tmp_path / ("run" if record_format == "ros2" else "run.mcap")
    write_fsp(path, record_format)
    series = load_timing(path)
    assert (series.protocol, series.clock) == ("FSP", "FC sample time")
    assert series.expected_us == pytest.approx(1e6 / EXPECTED_HZ)
    [[a, b, c], [d]] = fsp_run()
    assert [s.samples for s in series.segments] == [2 * len(x) for x in (a, b, c, d)]
    assert [s.cut for s in series.segments] == ["gap of 0.5 s", "FC reset", gap(c, d), "end"]
    assert series.analysed == 1 and series.times_s.size == 2 * len(b)
    check_stats(series.stats, deltas_of(b))
    assert len(deltas_of(b)) == 2 * len(b) - 2  # the interval across the loss is left out
    for segment, stretch in zip(series.segments, (a, b, c, d)):
        check_stats(segment.stats, deltas_of(stretch))
    assert series.notes == [
        "split at 1 FC reset, 2 gaps into 4 segments; analysed the longest, segment 2 "
        f"({series.segments[1].duration_s:.1f} s of "
        f"{sum(s.duration_s for s in series.segments):.1f} s)",
        "1 interval(s) spanning frames lost in transport or dropped on the FC left out of the "
        "analysed segment's statistics",
    ]


def test_raw_capture_known_intervals(tmp_path: Path) -> None:
    capture = tmp_path / "fsp.bin"
    capture.write_bytes(write_fsp(tmp_path / "run", "ros2"))
    series = load_timing(capture, expected_rate_hz=EXPECTED_HZ)
    [[a, b, c], _] = fsp_run()
    assert [s.cut for s in series.segments] == ["gap of 0.5 s", "FC reset", "end"]
    assert [s.samples for s in series.segments] == [2 * len(x) for x in (a, b, c)]
    assert series.expected_us == pytest.approx(1000.0)
    check_stats(series.stats, deltas_of(b))


def test_agrees_with_verify_on_a_run_without_cuts(tmp_path: Path) -> None:
    """`verify`'s own interval histograms (another implementation) give the same figures,
    the interval across a transport loss left out by both."""
    path = tmp_path / "steady"
    metadata = run_metadata("socket://sim:5762", 2_000_000, EXPECTED_HZ, None)
    stretch = packets(random.Random(3), 1_000_000, 500, 0)
    del stretch[200:205]
    with Recorder(path, None, metadata) as recorder:
        live = RecordingMonitor(recorder)
        live.connected(50.0)
        for seq, first, second in stretch:
            packet = StatePacket(second + 80, (frame(first), frame(second)), seq, True, 0)
            live.feed(encode_state(packet), 50 + second * 1e-6)
        live.disconnected(60.0)
    ours = load_timing(path).stats
    verify = replay(path).summary.fc_interval
    assert (ours.count, ours.p1_us, ours.p50_us, ours.p99_us) == (
        verify.count, verify.p1_us, verify.p50_us, verify.p99_us
    )  # fmt: skip
    assert ours.count == len(deltas_of(stretch)) == 2 * len(stretch) - 2
    assert ours.mean_us == pytest.approx(verify.mean_us)


def reply_wire(cmd: int, payload: bytes) -> bytes:
    """A reply as the FC sends it: a v1 request frame with the direction '>' (the direction
    byte is outside the checksum)."""
    return encode_request(cmd, payload, MspVersion.V1).replace(b"$M<", b"$M>", 1)


def test_msp_recording_known_reception_intervals(tmp_path: Path) -> None:
    rng = random.Random(5)
    imu = bytes(18)
    first = [10.0 + i * 1e-3 + rng.choice((0.0, 2e-4, 4e-4)) for i in range(400)]
    second = list(itertools.accumulate(rng.choice((0.9e-3, 1.3e-3)) for _ in range(900)))
    second = [first[-1] + 1.0 + t - second[0] for t in second]
    reads = first + second  # a 1 s silence between the two
    with MspRecorder(tmp_path / "msp", {"expected_rate_hz": "1000"}) as recorder:
        recorder.connected(9.99)
        for index, t in enumerate(reads):
            recorder.request(t - 4e-4, encode_request(Cmd.RAW_IMU, b"", MspVersion.V1))
            data = reply_wire(Cmd.RAW_IMU, imu)
            if index % 10 == 0:  # an RC reply in the same read: not an IMU sample
                data = reply_wire(Cmd.RC, bytes(16)) + data
            if index % 97 == 0:  # two IMU replies in one read: the same reception time
                data += reply_wire(Cmd.RAW_IMU, imu)
            recorder.read(t, data)
            recorder.reply(MspReply(Cmd.RAW_IMU, imu, t))
        recorder.disconnected(reads[-1] + 0.1)
    series = load_timing(tmp_path / "msp")
    assert (series.protocol, series.clock) == ("MSP", "OBC reception time")
    assert series.expected_us == pytest.approx(1000.0)
    assert [s.cut for s in series.segments] == ["gap of 1 s", "end"]
    received = []
    for index, t in enumerate(second, start=len(first)):
        received += [t, t] if index % 97 == 0 else [t]
    assert series.times_s.size == len(received)
    check_stats(series.stats, [(b - a) * 1e6 for a, b in itertools.pairwise(received)])


def test_cli_writes_the_table_and_figures(tmp_path: Path, capsys) -> None:
    write_fsp(tmp_path / "fsp", "ros2")
    out = tmp_path / "report"
    code, stdout, stderr = run_cli(
        capsys, "analyze", "timing", str(tmp_path / "fsp"), "--out", str(out), "--paper"
    )
    assert code == 0, stderr
    assert "FSP: the paper" in stdout and "FSP: fsp − the paper" in stdout
    assert "split at 1 FC reset, 2 gaps" in stdout
    data = json.loads((out / "timing.json").read_text())
    stats = load_timing(tmp_path / "fsp").stats
    assert data["recordings"][0]["stats"]["p99_us"] == stats.p99_us
    paper_p99 = data["paper"]["FSP"]["p99_us"]
    assert "Table 1" in paper_p99["source"]
    rows = {row["recording"]: row for row in table_rows([load_timing(tmp_path / "fsp")], True)}
    difference = float(rows["FSP: fsp − the paper"]["P99 (µs)"])
    assert difference == pytest.approx(stats.p99_us - paper_p99["value"], abs=0.05)
    assert "| FSP: fsp |" in (out / "timing.md").read_text()
    for name in ("fig2-histograms.png", "fig3-intervals.png"):
        assert (out / name).read_bytes()[:4] == b"\x89PNG"


def one_line_error(capsys, *args: str) -> str:
    code, stdout, stderr = run_cli(capsys, "analyze", "timing", *args)
    assert code == 2, stdout + stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:"), stderr
    return lines[0]


def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, capsys) -> None:
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    assert "is empty" in one_line_error(capsys, str(empty))

    assert "cannot read" in one_line_error(capsys, str(tmp_path / "missing.mcap"))

    foreign = tmp_path / "notes.txt"
    foreign.write_text("not a recording\n" * 100)
    assert "neither a wftool recording nor an FSP capture" in one_line_error(capsys, str(foreign))

    whole = tmp_path / "whole.mcap"
    write_fsp(whole, "ros2")
    header_only = tmp_path / "header.mcap"
    header_only.write_bytes(whole.read_bytes()[:20])
    one_line_error(capsys, str(header_only))

    other = tmp_path / "other.mcap"
    with open(other, "wb") as handle:
        writer = Writer(handle)
        writer.start()
        schema = writer.register_schema("Thing", "jsonschema", b"{}")
        channel = writer.register_channel("/elsewhere", "json", schema)
        writer.add_message(channel, 1, b"{}", 1)
        writer.finish()
    assert "no wftool recording" in one_line_error(capsys, str(other))

    empty_bag = tmp_path / "bag"
    empty_bag.mkdir()
    assert "expected one .mcap file" in one_line_error(capsys, str(empty_bag))


def test_a_recording_cut_short_is_analysed_as_far_as_it_goes(tmp_path: Path, capsys) -> None:
    """A writer killed mid-run leaves a file without its ending: what it holds is analysed,
    and the table says the recording was cut."""
    whole = tmp_path / "whole.mcap"
    write_fsp(whole, "json")  # JSON MCAP: about 3,000 bytes a packet, many chunks
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 3])
    code, stdout, stderr = run_cli(capsys, "analyze", "timing", str(cut), "--out", str(tmp_path))
    assert code == 0, stderr
    assert "not finished (its writer was stopped hard)" in stdout
    held, written = (sum(s.samples for s in load_timing(f).segments) for f in (cut, whole))
    assert 0 < held < written


def test_a_recording_without_samples_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "silent"
    with Recorder(path, None, run_metadata("socket://sim:5762", 1, None, None)) as recorder:
        live = RecordingMonitor(recorder)
        live.connected(1.0)
        live.feed(b"\x00\x00garbage", 1.5)
        live.disconnected(2.0)
    with pytest.raises(UsageError, match="holds no FSP frames"):
        load_timing(path)
