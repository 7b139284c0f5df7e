"""ROS 2 recordings, read back by rosbags (an independent rosbag2/MCAP reader and CDR codec).

A synthetic flight goes through the real decoder and recorder; a second, separate decoder
gives the frames each message is compared with. Every message of every topic is checked,
values and stamps; `wftool replay` must reproduce the run from the same directory.
"""

from __future__ import annotations

import itertools
import json
import math
import random
import resource
import shutil
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from wftool.errors import RecordingError, UsageError
from wftool.fsp import SensorFrame, StateDecoder, StatePacket, UplinkFlag, UplinkStatus
from wftool.fsp.encoder import encode_state, encode_uplink_status
from wftool.recording import rosbag
from wftool.recording.events import Event, StreamHealth
from wftool.recording.reader import read_recording
from wftool.recording.recorder import Recorder
from wftool.recording.ros2msg import decode_events
from wftool.recording.rosbag import EVENT_BATCH_S
from wftool.verify.monitor import HealthSampler, StreamMonitor
from wftool.verify.session import replay_recording

PERIOD_US = 953
PACKETS_PER_READ = 3
READ_S = PACKETS_PER_READ * 2 * PERIOD_US * 1e-6
STATUS_EVERY = 50
"""Packets between the uplink statuses of `flight(statuses=True)`: about 100 ms, as the FC's."""
LIVE = UplinkFlag.LIVE | UplinkFlag.OVERRIDE | UplinkFlag.ARMED


def fc_status(seq: int, tx_time_us: int) -> UplinkStatus:
    """What a piloted FC reports after state packet `seq` of `flight`: commands flying it
    under override; from packet 1000 on, timed out (the pilot's sticks again); from 2000
    on, the pilot's radio lost too (RX loss, failsafe)."""
    flags, phase, timeouts, timed_out_us = LIVE, 0, 0, 0
    if seq >= 1000:
        flags, timeouts = UplinkFlag.OVERRIDE | UplinkFlag.ARMED, 1
        timed_out_us = (tx_time_us - (seq - 1000) * 2 * PERIOD_US - 700) % 2**32
    if seq >= 2000:
        flags, phase = flags | UplinkFlag.RX_LOSS, 1
    accepted = min(seq, 1000) // 2
    return UplinkStatus(
        accepted % 2**24, tx_time_us, accepted, seq // 400, timeouts, seq // 700, 50, flags,
        phase, timed_out_us,
    )  # fmt: skip


def flight(packets: int, seed: int = 1, *, statuses: bool = False) -> list[bytes]:
    """Reads of a random but plausible E1 stream: RC held for a while, some blank frames;
    with `statuses`, an FC's uplink status (`fc_status`) after every `STATUS_EVERY` packets
    and where its flags change."""
    rng = random.Random(seed)
    rc = (1500, 1500, 1500, 1000, 1000, 1000)
    reads, chunk = [], b""
    t_us = 4_294_000_000  # wraps early on
    for seq in range(packets):
        frames = []
        for _ in range(2):
            if rng.random() < 0.05:
                rc = (rng.randint(1000, 2000), 1500, rng.randint(990, 2010), 1000, 1000, 2000)
            blank = rng.random() < 0.02  # no attitude, no acc calibration
            attitude = (-32768, *(rng.randint(-900, 900) for _ in range(3)))
            frames.append(
                SensorFrame(
                    t_us % 2**32,
                    tuple(rng.randint(-4000, 4000) for _ in range(3)),
                    0 if blank else 2048,
                    0.0609756,
                    tuple(rng.randint(-32768, 32767) for _ in range(3)),
                    (0, 0, 0, 0) if blank else attitude,
                    rc,
                    tuple(rng.randint(0, 65535) for _ in range(4)),
                    rng.randint(1400, 1680),
                )
            )
            t_us += PERIOD_US
        packet = StatePacket((t_us + 90) % 2**32, tuple(frames), seq, True, seq // 500)
        chunk += encode_state(packet)
        if statuses and (seq % STATUS_EVERY == STATUS_EVERY // 2 or seq in (1000, 2000)):
            chunk += encode_uplink_status(fc_status(seq, (t_us + 130) % 2**32))
        if seq % PACKETS_PER_READ == PACKETS_PER_READ - 1:
            reads.append(chunk)
            chunk = b""
    return [*reads, chunk] if chunk else reads


def record(recorder: Recorder, reads: list[bytes], t0: float = 5000.0):
    """Feed `reads` the way the live loop does; the monitor and the health snapshots."""
    monitor = StreamMonitor("socket://sim:5762")
    sampler = HealthSampler(monitor)
    snapshots: list[StreamHealth] = []
    t = t0
    monitor.connected(t)
    recorder.event(Event("connected", t))
    for data in reads:
        t += READ_S
        recorder.event(Event("bytes", t, data))
        packets = monitor.feed(data, t)
        health = sampler.sample(packets, t)
        if health is not None and (not snapshots or health is not snapshots[-1]):
            snapshots.append(health)
        recorder.packets(packets, health)
    recorder.event(Event("command", t, rc=(1100, 1500, 1500, 1000, 1000, 1000)))
    monitor.disconnected(t)
    recorder.event(Event("disconnected", t))
    return monitor, snapshots


def decoded_frames(reads: list[bytes], t0: float = 5000.0) -> list[SensorFrame]:
    """The frames as a separate decoder sees them, with their OBC capture times."""
    monitor = StreamMonitor("check")
    monitor.connected(t0)
    frames, t = [], t0
    for data in reads:
        t += READ_S
        for packet in monitor.feed(data, t):
            frames.extend(packet.frames)
    return frames


def stamp_of(message) -> int:
    return message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec


def read_bag(path: Path) -> dict[str, list[tuple[int, object]]]:
    """Every message by topic, (log time, message), via rosbags with only the file's schemas."""
    topics: dict[str, list] = {}
    with AnyReader([path], default_typestore=get_typestore(Stores.EMPTY)) as reader:
        for connection, log_time, raw in reader.messages():
            message = reader.deserialize(raw, connection.msgtype)
            topics.setdefault(connection.topic, []).append((log_time, message))
    return topics


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory):
    bag = tmp_path_factory.mktemp("bags") / "flight"
    reads = flight(3000, statuses=True)
    with Recorder(bag, None, {"port": "socket://sim:5762"}) as recorder:
        monitor, snapshots = record(recorder, reads)
    return bag, reads, monitor, snapshots


def test_layout_is_a_rosbag2_directory(recorded):
    bag, *_ = recorded
    assert sorted(p.name for p in bag.iterdir()) == ["flight_0.mcap", "metadata.yaml"]
    with Reader(bag) as reader:  # rosbags' rosbag2 reader: metadata.yaml + storage plugin
        counts = {c.topic: c.msgcount for c in reader.connections}
        types = {c.topic: c.msgtype for c in reader.connections}
        in_file = sum(1 for _ in reader.messages())
        assert reader.message_count == in_file == sum(counts.values())
        assert reader.storage.metadata.custom["port"] == "socket://sim:5762"
    assert types["/fsp/imu"] == "sensor_msgs/msg/Imu"
    assert types["/fsp/battery"] == "sensor_msgs/msg/BatteryState"
    assert counts["/fsp/imu"] == counts["/fsp/rpm"] == 6000


@pytest.fixture(scope="module")
def read_back(recorded):
    """(frames from a separate decoder, every message by topic, the bag's wall offset)."""
    bag, reads, *_ = recorded
    with Reader(bag) as reader:
        offset = int(reader.storage.metadata.custom["wall_offset_ns"])
    return decoded_frames(reads), read_bag(bag), offset


def assert_imu_matches(message, frame: SensorFrame) -> None:
    """An Imu message carries `frame` in ROS units (the formulas of the module docstring)."""
    w, x, y, z = frame.attitude
    q = message.orientation
    assert (q.w, q.x, q.y, q.z) == (w / 32768, x / 32768, y / 32768, z / 32768)
    assert message.orientation_covariance[0] == (0.0 if any(frame.attitude) else -1.0)
    rad_s = [v * frame.gyro_scale * math.pi / 180 for v in frame.gyro]
    av = message.angular_velocity
    assert [av.x, av.y, av.z] == pytest.approx(rad_s, rel=1e-12)
    a = message.linear_acceleration
    if frame.acc_1g:
        m_s2 = [v / frame.acc_1g * 9.80665 for v in frame.acc]
        assert [a.x, a.y, a.z] == pytest.approx(m_s2, rel=1e-12)
        assert message.linear_acceleration_covariance[0] == 0.0
    else:
        assert message.linear_acceleration_covariance[0] == -1.0


def test_every_imu_and_rpm_message_matches_its_frame(read_back):
    frames, topics, offset = read_back
    imu, rpm = topics["/fsp/imu"], topics["/fsp/rpm"]
    assert len(imu) == len(rpm) == len(frames) == 6000
    for frame, (log_time, message), (_, rpm_message) in zip(frames, imu, rpm):
        stamp = offset + int(frame.obc_time * 1e9)
        assert stamp_of(message) == stamp_of(rpm_message) == stamp
        assert abs(log_time - stamp) < 50_000_000  # log time: when the OBC read it
        assert_imu_matches(message, frame)
        assert tuple(rpm_message.rpm) == frame.rpm


def test_rc_steps_and_battery_rate(read_back):
    frames, topics, offset = read_back
    # Before its first lock the estimator gives the packets of one read the same times.
    by_stamp: dict[int, list[SensorFrame]] = {}
    for frame in frames:
        by_stamp.setdefault(offset + int(frame.obc_time * 1e9), []).append(frame)
    assert max(map(len, by_stamp.values())) <= PACKETS_PER_READ
    rc = [(stamp_of(m), m) for _, m in topics["/fsp/rc"]]
    for stamp, message in rc:
        fields = (message.roll, message.pitch, message.yaw, message.throttle, message.aux3,
                  message.aux4)  # fmt: skip
        assert fields in [f.rc for f in by_stamp[stamp]]
    written = [stamp for stamp, _ in rc]
    stamps = [offset + int(f.obc_time * 1e9) for f in frames]  # capture order
    for (before, old), (after, new) in zip(zip(stamps, frames), zip(stamps[1:], frames[1:])):
        if old.rc != new.rc:  # a step: both sides are there
            assert before in written and after in written
    gaps = [b - a for a, b in itertools.pairwise(written)]
    assert max(gaps) <= 100_000_000 + PERIOD_US * 1000
    assert len(written) < len(frames) / 3  # held values are not repeated per frame

    battery = [m for _, m in topics["/fsp/battery"]]
    span_s = (stamps[-1] - stamps[0]) / 1e9
    assert len(battery) == pytest.approx(span_s * 10, abs=1.5)
    for message in battery:
        voltages = [f.vbat / 100 for f in by_stamp[stamp_of(message)]]
        assert any(message.voltage == pytest.approx(v) for v in voltages)


def test_health_snapshots_are_all_there(recorded):
    bag, _, monitor, snapshots = recorded
    health = [m for _, m in read_bag(bag)["/fsp/health"]]
    assert len(health) == len(snapshots) > 50
    for message, snapshot in zip(health, snapshots):
        assert (message.seq, message.frames, message.fc_drops) == (
            snapshot.seq, snapshot.frames, snapshot.fc_drops,
        )  # fmt: skip
    last = health[-1]
    assert last.e1 and last.clock_locked and last.connected
    assert last.fc_drops == monitor.summary().fc_drops > 0


def sent_statuses(reads: list[bytes]) -> list[UplinkStatus]:
    """The FC's uplink statuses in `reads`, in order, as a separate decoder takes them."""
    decoder, statuses = StateDecoder(), []
    for data in reads:
        before = decoder.stats.uplink_statuses
        decoder.feed(data)
        assert decoder.stats.uplink_statuses - before <= 1  # one a read: none unseen here
        if decoder.stats.uplink_statuses != before:
            statuses.append(decoder.uplink_status)
    return statuses


def test_the_fcs_uplink_statuses_are_recorded_each_change_at_once(recorded, read_back):
    """Every status that changes the FC's flags or failsafe phase is in the recording, the
    rest at least every other one; each as the FC sent it, stamped with its FC send time on
    the frames' clock, its last timeout too."""
    _, reads, monitor, _ = recorded
    frames, topics, offset = read_back
    sent = sent_statuses(reads)
    assert len(sent) == 3000 // STATUS_EVERY + 2
    recorded_statuses = [m for _, m in topics["/fsp/uplink_status"]]
    by_tx = {status.tx_time_us: status for status in sent}
    assert [m.tx_time_us for m in recorded_statuses] == sorted(
        (m.tx_time_us for m in recorded_statuses), key=lambda tx: sent.index(by_tx[tx])
    )  # in the order sent, each once
    changes = [s for s, before in zip(sent, [None, *sent]) if before is None or
               (s.flags, s.failsafe_phase) != (before.flags, before.failsafe_phase)]  # fmt: skip
    assert len(changes) == 3
    assert {s.tx_time_us for s in changes} <= {m.tx_time_us for m in recorded_statuses}
    positions = [sent.index(by_tx[m.tx_time_us]) for m in recorded_statuses]
    assert max(b - a for a, b in itertools.pairwise(positions)) <= 2
    obc_time = {frame.values[0]: frame.obc_time for frame in frames}
    for message in recorded_statuses:
        status = by_tx[message.tx_time_us]
        flags = [message.live, message.override, message.obc_receiver, message.rx_loss,
                 message.armed, message.arm_switch]  # fmt: skip
        assert flags == [status.has(flag) for flag in UplinkFlag]
        assert (message.command_seq, message.accepted, message.stale, message.rejected,
                message.timeouts, message.timeout_ms, message.failsafe_phase,
                message.timed_out_us) == (
            status.command_seq, status.accepted, status.stale, status.rejected,
            status.timeouts, status.timeout_ms, status.failsafe_phase, status.timed_out_us,
        )  # fmt: skip
        # Sent 130 µs after the packet's last frame period ended: that frame's stamp + 1083 µs.
        last_frame = obc_time[(status.tx_time_us - 130 - PERIOD_US) % 2**32]
        expected = offset + round(last_frame * 1e9) + (PERIOD_US + 130) * 1000
        assert abs(stamp_of(message) - expected) < 5_000
        timed_out = message.timed_out.sec * 1_000_000_000 + message.timed_out.nanosec
        if status.timeouts:
            waited_ns = (status.tx_time_us - status.timed_out_us) % 2**32 * 1000
            assert abs(stamp_of(message) - timed_out - waited_ns) < 5_000
        else:
            assert timed_out == 0
    assert monitor.summary().fc_uplink.status == sent[-1]
    assert recorded_statuses[-1].rx_loss and recorded_statuses[-1].failsafe_phase == 1


def test_replay_reproduces_the_run(recorded):
    bag, _, monitor, _ = recorded
    assert replay_recording(bag).summary() == monitor.summary()
    assert replay_recording(bag / "flight_0.mcap").summary() == monitor.summary()
    _, events = read_recording(bag)
    kinds = [e.kind for e in events]
    assert kinds[0] == "connected" and kinds[-2:] == ["command", "disconnected"]


def test_a_mcap_path_is_the_same_recording_in_one_file(recorded, tmp_path: Path):
    """`--record run.mcap` in the ROS 2 format: the bag's MCAP file alone, at that path."""
    bag, reads, monitor, _ = recorded
    single = tmp_path / "run.mcap"
    with Recorder(single, None, {"port": "socket://sim:5762"}) as recorder:
        record(recorder, reads)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.mcap"]
    with Reader(single) as reader:  # rosbags opens one storage file as a bag, as rosbag2 does
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert reader.message_count == sum(counts.values())
    with Reader(bag) as reader:
        assert counts == {c.topic: c.msgcount for c in reader.connections}
    topics = read_bag(single)
    for frame, (_, message) in zip(decoded_frames(reads), topics["/fsp/imu"], strict=True):
        assert_imu_matches(message, frame)
    assert replay_recording(single).summary() == monitor.summary()


@pytest.mark.parametrize("record_format", ["ros2", "json"])
def test_events_read_through_the_indexes_are_every_event_in_written_order(
    tmp_path: Path, record_format: str
):
    """`read_recording` jumps to the events through the MCAP indexes; the mcap library's
    own reader, walking every record, must find the same events in the same order."""
    path = tmp_path / "run.mcap"
    reads = flight(4000)  # several chunks
    with Recorder(path, None, {}, record_format=record_format) as recorder:
        record(recorder, reads)
    with open(path, "rb") as handle:
        reader = make_reader(handle)
        assert len(reader.get_summary().chunk_indexes) > 1
        walked = []
        for _, channel, message in reader.iter_messages(
            topics=["/fsp/events"], log_time_order=False
        ):
            if channel.message_encoding == "cdr":  # a batch
                walked += decode_events(message.data).events()
            else:
                raw = json.loads(message.data)
                walked.append((raw["kind"], raw["t"]))
    _, events = read_recording(path)
    indexed = list(events)
    assert len(indexed) == len(walked) == len(reads) + 3  # connect, command, disconnect
    for event, in_file in zip(indexed, walked):
        assert (event.kind, event.t, event.data, event.rc)[: len(in_file)] == in_file
    assert [e.data for e in indexed if e.kind == "bytes"] == reads


def test_events_read_by_rosbags_are_the_reads_in_order(recorded, read_back):
    """Every event, as rosbags decodes the batches with the file's own definition."""
    _, reads, *_ = recorded
    _, topics, _ = read_back
    kinds, data, rc = [], [], []
    for _, batch in topics["/fsp/events"]:
        assert len(batch.t) == len(batch.kind) == len(batch.size) > 0
        assert batch.t[-1] - batch.t[0] < EVENT_BATCH_S
        blob, values = bytes(batch.data), batch.rc.tolist()
        for kind, size in zip(batch.kind.tolist(), batch.size.tolist()):
            kinds.append(kind)
            if kind == batch.BYTES:
                data.append(blob[:size])
                blob = blob[size:]
            elif kind == batch.COMMAND:
                rc.append(tuple(values[:size]))
                values = values[size:]
        assert blob == b"" and values == []
    assert kinds[0] == 0 and kinds[-2:] == [3, 1]  # CONNECTED; COMMAND, DISCONNECTED
    assert data == reads
    assert rc == [(1100, 1500, 1500, 1000, 1000, 1000)]


def test_json_format_still_replays(tmp_path: Path):
    reads = flight(300)
    metadata = {"port": "socket://sim:5762"}
    with Recorder(tmp_path / "run.mcap", None, metadata, record_format="json") as recorder:
        monitor, _ = record(recorder, reads)
    assert replay_recording(tmp_path / "run.mcap").summary() == monitor.summary()


# -- bad input ------------------------------------------------------------------------------


def test_unwritable_or_taken_paths_fail_before_the_run(tmp_path: Path):
    with pytest.raises(UsageError, match="cannot write the recording"):
        Recorder(tmp_path / "missing-dir" / "run", None, {})
    taken = tmp_path / "taken"
    taken.mkdir()
    (taken / "x").write_text("keep me")
    with pytest.raises(UsageError, match="already exists"):
        Recorder(taken, None, {})
    assert (taken / "x").read_text() == "keep me"
    (tmp_path / "run.mcap").write_text("keep me")
    with pytest.raises(UsageError, match="already exists"):
        Recorder(tmp_path / "run.mcap", None, {})
    assert (tmp_path / "run.mcap").read_text() == "keep me"
    (tmp_path / "dir.mcap").mkdir()
    with pytest.raises(UsageError, match="is a directory"):
        Recorder(tmp_path / "dir.mcap", None, {})
    (tmp_path / "a-file").write_text("")
    with pytest.raises(UsageError, match="cannot write the recording"):
        Recorder(tmp_path / "a-file" / "run", None, {})
    empty = tmp_path / "empty"
    empty.mkdir()
    Recorder(empty, None, {}).close()  # an empty directory is fine, as for ros2 bag record
    assert (empty / "metadata.yaml").exists()


@pytest.mark.parametrize("existing", [False, True], ids=["new", "empty-dir"])
def test_a_run_that_loses_the_race_for_a_path_leaves_the_winners_recording(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, existing: bool
):
    # Two runs on one path: the other run claims it between this one's check and its claim.
    path = tmp_path / "run"
    if existing:
        path.mkdir()
    other: list[Recorder] = []
    real = rosbag.McapProcess

    def claimed_meanwhile(*args, **kwargs):
        if not other:
            other.append(None)  # type: ignore[arg-type]
            other[0] = Recorder(path, None, {"run": "winner"})
        return real(*args, **kwargs)

    monkeypatch.setattr(rosbag, "McapProcess", claimed_meanwhile)
    with pytest.raises(
        UsageError, match=r"cannot write the recording: .*run_0.mcap already exists"
    ):
        Recorder(path, None, {"run": "loser"})
    # The winner runs on: a killed run leaves its recording readable from these files.
    assert sorted(p.name for p in path.iterdir()) == ["metadata.yaml", "run_0.mcap"]
    assert '"run": "winner"' in (path / "metadata.yaml").read_text()
    other[0].close()
    with AnyReader([path]) as reader:
        assert reader.message_count == 0  # a whole (empty) recording, readable by rosbags


@contextmanager
def file_size_limit(limit: int) -> Iterator[None]:
    """Processes started within (the recording's writer) may write files of `limit` bytes
    at most (RLIMIT_FSIZE): a write past it is cut short there and the next fails (EFBIG),
    as on a full disk, in the kernel."""
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))


@pytest.mark.parametrize("record_format", ["ros2", "json"])
def test_full_disk_ends_the_run_with_a_readable_file(tmp_path, record_format):
    reads = flight(6000)
    path = tmp_path / ("run" if record_format == "ros2" else "run.mcap")
    with file_size_limit(400_000):
        recorder = Recorder(path, None, {}, record_format=record_format)
    with pytest.raises(RecordingError, match=r"File too large: .* finished and readable"):
        record(recorder, reads)
    recorder.close()
    mcap = path / "run_0.mcap" if record_format == "ros2" else path
    assert 0 < mcap.stat().st_size <= 400_000 + 64
    _, events = read_recording(path)
    replayed = [e for e in events if e.kind == "bytes"]
    assert replayed and [e.data for e in replayed] == reads[: len(replayed)]  # a clean prefix
    if record_format == "ros2":
        topics = read_bag(path)
        frames = decoded_frames(reads)
        imu = topics["/fsp/imu"]
        assert 0 < len(imu) < len(frames)
        with Reader(path) as reader:  # metadata.yaml counts what the file holds
            counts = {c.topic: c.msgcount for c in reader.connections}
        assert topics.keys() <= counts.keys()
        assert counts == {topic: len(topics.get(topic, ())) for topic in counts}  # 0: none


@pytest.mark.skipif(shutil.which("unshare") is None, reason="needs unshare(1)")
def test_full_tmpfs_ends_the_run_with_a_readable_bag(tmp_path: Path):
    """A real full file system: a 2 MiB tmpfs in a private mount namespace."""
    mount, out = tmp_path / "mnt", tmp_path / "out"
    mount.mkdir()
    out.mkdir()
    script = textwrap.dedent(
        f"""
        import shutil, sys
        from pathlib import Path
        from tests.recording.test_rosbag import flight, record
        from wftool.errors import RecordingError
        from wftool.recording.recorder import Recorder
        recorder = Recorder(Path({str(mount)!r}) / "run", None, {{}})
        try:
            record(recorder, flight(40000))
        except RecordingError as exc:
            print("stopped:", exc)
        recorder.close()
        shutil.copytree(Path({str(mount)!r}) / "run", Path({str(out)!r}) / "run")
        """
    )
    shell = f'mount -t tmpfs -o size=2m tmpfs "{mount}" && exec "{sys.executable}" -c "$0"'
    result = subprocess.run(
        ["unshare", "-rm", "sh", "-c", shell, script],
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parents[2],
        timeout=300,
    )
    if "mount:" in result.stderr or "unshare:" in result.stderr:
        pytest.skip(f"cannot mount a private tmpfs here: {result.stderr.strip()}")
    assert result.returncode == 0, result.stderr
    assert "stopped: recording stopped, No space left on device" in result.stdout
    bag = out / "run"
    imu = read_bag(bag)["/fsp/imu"]
    assert 1000 < len(imu) < 80000
    with Reader(bag) as reader:
        assert {c.topic: c.msgcount for c in reader.connections}["/fsp/imu"] == len(imu)
    assert 0 <= replay_recording(bag).summary().frames - len(imu) <= 2 * PACKETS_PER_READ
