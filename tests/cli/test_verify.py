"""verify and replay at the click layer: bad input, runs that record and serve, signals,
and recordings that were cut short or are no recordings of ours.

The runs read a synthetic FSP stream served over local TCP (a capture player, not an FC:
the SITL is not needed to exercise the recording and serving path end to end); those that
are signalled run as their own process, as a user starts them.
"""

from __future__ import annotations

import contextlib
import csv
import json
import os
import re
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer as McapWriter
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from rosbags.rosbag2 import ReaderError as RosbagsReaderError
from rosbags.typesys import Stores, get_typestore

from tests.conftest import run_cli as run
from tests.fc.stand_in import msp_stand_in
from tests.recording.test_rosbag import flight, read_bag
from tests.verify.fake_fc import PACKET_S, FakeFc
from tests.waits import wait_for
from wftool.recording.events import Event
from wftool.recording.recorder import Recorder

NO_PORT = "socket://127.0.0.1:9"  # nothing listens: reached only if the checks before pass


def test_a_taken_record_path_is_refused_before_connecting(capsys, tmp_path):
    taken = tmp_path / "run.mcap"
    taken.write_text("an earlier run")
    code, _, err = run(capsys, "verify", "--stream", "--port", NO_PORT,
                       "--record", str(taken))  # fmt: skip
    assert code == 2 and err.count("\n") == 1
    assert "already exists" in err and taken.read_text() == "an earlier run"


def test_unwritable_record_path_is_refused_before_connecting(capsys, tmp_path):
    code, _, err = run(capsys, "verify", "--stream", "--port", NO_PORT,
                       "--record", str(tmp_path / "missing" / "run"))  # fmt: skip
    assert code == 2 and err.count("\n") == 1
    assert err.startswith("error: cannot write the recording:")


def test_foxglove_without_the_sdk_names_the_extra(capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "foxglove", None)
    code, _, err = run(capsys, "verify", "--stream", "--port", NO_PORT, "--foxglove")
    assert code == 2 and err.count("\n") == 1
    assert "pip install 'wftool[foxglove]'" in err


def _serve(reads: list[bytes], ready: threading.Event, port: list[int]) -> None:
    with socket.create_server(("127.0.0.1", 0)) as server:
        port.append(server.getsockname()[1])
        ready.set()
        connection, _ = server.accept()
        with connection:
            start = time.monotonic()
            for index, data in enumerate(reads):
                connection.sendall(data)
                # Three packets' worth of time after the one before, as due from the start: a
                # loaded host that wakes late sends what is due at once, as a UART would have.
                time.sleep(max(0.0, start + (index + 1) * 0.0057 - time.monotonic()))
            connection.recv(1)  # until the reader hangs up


def play(reads: list[bytes]) -> str:
    """The URL of a capture player serving `reads` to the first client."""
    ready, port = threading.Event(), []
    threading.Thread(target=_serve, args=(reads, ready, port), daemon=True).start()
    assert ready.wait(5)
    return f"socket://127.0.0.1:{port[0]}"


def test_verify_records_a_rosbag_and_serves_foxglove(capsys, tmp_path):
    pytest.importorskip("foxglove")
    bag = tmp_path / "flight"
    code, _, err = run(capsys, "verify", "--stream", "--port", play(flight(600)),
                       "--duration", "2", "--record", str(bag), "--foxglove", "0")  # fmt: skip
    assert code in (0, 1), err  # the verdict is not the point here
    assert "Foxglove  ws://127.0.0.1:" in err
    with AnyReader([bag], default_typestore=get_typestore(Stores.EMPTY)) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts["/fsp/imu"] > 1000 and counts["/fsp/health"] > 0  # the reader may skip
    code, out, _ = run(capsys, "replay", str(bag), "--json")  # what came before it opened
    assert json.loads(out)["frames"] == counts["/fsp/imu"]


def test_serving_foxglove_beyond_localhost_is_warned_of_first(capsys):
    pytest.importorskip("foxglove")
    code, _, err = run(capsys, "verify", "--stream", "--port", NO_PORT, "--duration", "1",
                       "--foxglove", "0", "--foxglove-host", "0.0.0.0")  # fmt: skip
    assert code == 2
    assert err.splitlines()[0] == (
        "warning: the Foxglove view on 0.0.0.0:0 serves the live stream to anyone who can "
        "reach this machine, without authentication"
    )


def test_a_mcap_record_path_is_one_ros2_file_and_replays_with_its_clock(capsys, tmp_path):
    single = tmp_path / "run.mcap"
    code, _, err = run(capsys, "verify", "--stream", "--port", play(flight(600)),
                       "--duration", "2", "--record", str(single), "--clock", "kalman")  # fmt: skip
    assert code in (0, 1), err
    assert single.is_file()  # the MCAP file alone, in the ROS 2 format (the default)
    with AnyReader([single], default_typestore=get_typestore(Stores.EMPTY)) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        types = {c.topic: c.msgtype for c in reader.connections}
    assert types["/fsp/imu"] == "sensor_msgs/msg/Imu" and counts["/fsp/imu"] > 1000
    code, out, _ = run(capsys, "replay", str(single), "--json")
    replayed = json.loads(out)
    assert (replayed["frames"], replayed["clock_estimator"]) == (counts["/fsp/imu"], "kalman")


# -- bad run lengths, a port that never opens, Ctrl-C (issue 14, item 4) ----------------------


def wftool(*args: str) -> subprocess.Popen:
    """`python -m wftool ARGS` in its own process, started as from a terminal (a shell's
    background job would start it with SIGINT ignored)."""
    return subprocess.Popen(
        [sys.executable, "-m", "wftool", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip


def _run_did_not_end(*_: object) -> None:
    raise AssertionError("the run did not end within 20 s")


@pytest.mark.parametrize("duration", ["0", "-1", "nan", "inf"])
def test_a_duration_that_is_no_run_length_is_refused_before_anything_runs(
    duration, capsys, tmp_path
):
    with socket.create_server(("127.0.0.1", 0)) as listener:
        url = f"socket://127.0.0.1:{listener.getsockname()[1]}"
        record = tmp_path / "run.mcap"
        # In-process, under an alarm: nan once meant run forever (it sets signal handlers,
        # so it runs in the main thread).
        previous = signal.signal(signal.SIGALRM, _run_did_not_end)
        signal.alarm(20)
        try:
            code, out, err = run(capsys, "verify", "--stream", "--port", url, "--duration",
                                 duration, "--record", str(record))  # fmt: skip
        finally:
            signal.alarm(0)
            signal.signal(signal.SIGALRM, previous)
        listener.settimeout(0.1)
        with pytest.raises(TimeoutError):
            listener.accept()  # never connected
    assert (code, out) == (2, "")
    assert err == f"error: --duration must be a positive number of seconds, not {duration}\n"
    assert not record.exists()


def test_a_port_that_never_opens_prints_its_error_and_nothing_else(capsys):
    code, out, err = run(capsys, "verify", "--stream", "--port", NO_PORT, "--duration", "1")
    assert (code, out) == (2, "")
    assert err.startswith("error: cannot open socket://127.0.0.1:9") and err.count("\n") == 1


@pytest.mark.parametrize("rate", ["nan", "inf", "-inf", "-5", "0", "1e9", "8001"])
def test_an_uplink_rate_the_fc_cannot_take_is_refused(rate, capsys):
    code, out, err = run(capsys, "verify", "--stream", "--port", NO_PORT, "--duration", "1",
                         "--uplink", "--uplink-rate", rate)  # fmt: skip
    assert (code, out) == (2, "")
    assert err == (
        "error: --uplink-rate must be above 0 and at most 8000 commands/s (the FC applies one "
        f"per FSP frame at most), not {float(rate):g}\n"
    )


def test_an_fc_without_a_running_pid_loop_gives_no_frame_rate(capsys):
    status = struct.pack("<HHHI", 0, 0, 0, 0) + bytes(12)  # PID cycle 0: the loop is not run
    with msp_stand_in(lambda _command: status) as fc_url:
        code, out, err = run(capsys, "verify", "--stream", "--port", NO_PORT, "--duration", "1",
                             "--fsp-rate", "1000", "--fc", fc_url)  # fmt: skip
    assert (code, out) == (1, "")
    assert err == (
        f"error: the FC on {fc_url} reports no PID loop running (cycle time 0 in MSP_STATUS): "
        "its frame rate cannot be known\n"
    )


def test_the_baud_rate_must_be_positive(capsys):
    code, out, err = run(capsys, "verify", "--stream", "--port", NO_PORT, "--baud", "0")
    assert (code, out) == (2, "")
    assert "Invalid value for '--baud': 0 is not in the range x>=1" in err


def test_ctrl_c_ends_an_open_ended_run_with_its_verdict():
    with FakeFc() as fc:
        process = wftool("verify", "--stream", "--port", fc.url, "--max-loss", "100")
        # the run is up and reading (a loaded host took over 3 s to import it all)
        assert wait_for(lambda: fc.connections and len(fc.sent) > 500, 60)
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=30)
    assert process.returncode == 0, err  # the normal end: what it saw passes
    assert "PASS" in out and "✓ frames received" in out


# -- outages (item 1) --------------------------------------------------------------------------


def test_an_outage_the_user_allows_passes_and_is_shown(capsys):
    with FakeFc(connected_s=(1.0,), outages_s=(0.5,)) as fc:
        code, out, err = run(capsys, "verify", "--stream", "--port", fc.url, "--duration", "3",
                             "--json", "--max-outage", "3", "--max-loss", "100")  # fmt: skip
    assert code == 0, err
    summary = json.loads(out)
    assert summary["reconnects"] == 1 and summary["lost_packets"] > 0.5 / PACKET_S
    outage = next(c for c in summary["verdict"]["checks"] if c["name"] == "time disconnected")
    assert outage["passed"] and outage["value"] == round(summary["outage_s"], 3)
    assert 0.4 < summary["outage_s"] < 3.0


@pytest.mark.parametrize("limit", ["-1", "nan"])
def test_the_outage_limit_is_a_number_of_seconds(limit, capsys):
    code, out, err = run(capsys, "verify", "--stream", "--port", NO_PORT, "--max-outage", limit)
    assert (code, out) == (2, "") and "--max-outage" in err


# -- interrupted recordings (item 6) --------------------------------------------------------


def recorded(capsys, record, table) -> tuple[int, int, int]:
    """(frames replayed from the raw bytes, CSV rows, IMU messages) of a finished recording."""
    with open(record, "rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None, "not finished: no summary"
    channel = next(c.id for c in summary.channels.values() if c.topic == "/fsp/imu")
    code, out, err = run(capsys, "replay", str(record), "--json")
    assert code in (0, 1), err
    with open(table, newline="") as handle:
        rows = sum(1 for _ in csv.reader(handle)) - 1
    return json.loads(out)["frames"], rows, summary.statistics.channel_message_counts[channel]


def wait_for_rows(table: Path, rows: int, timeout: float = 60.0) -> None:
    """Until the CSV file a run writes holds `rows` lines (it is written as frames come)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if table.exists() and table.read_bytes().count(b"\n") >= rows:
            return
        time.sleep(0.05)
    raise AssertionError(f"{table} did not reach {rows} rows in {timeout} s")


@pytest.mark.parametrize(
    "sig, code, said",
    [(signal.SIGINT, 130, "aborted"), (signal.SIGTERM, 143, "terminated (SIGTERM)"),
     (signal.SIGHUP, 129, "terminated (SIGHUP)")],
)  # fmt: skip
def test_a_signal_stops_a_timed_recording_run_cleanly(sig, code, said, capsys, tmp_path):
    """Ctrl-C in a timed run, SIGTERM and SIGHUP in any: no verdict, the recording finished,
    and what it holds agrees everywhere."""
    record, table = tmp_path / "run.mcap", tmp_path / "run.csv"
    with FakeFc() as fc:
        process = wftool("verify", "--stream", "--port", fc.url, "--duration", "60",
                         "--record", str(record), "--csv", str(table))  # fmt: skip
        wait_for_rows(table, 1100)  # the run has read that much, however loaded the machine
        process.send_signal(sig)
        out, err = process.communicate(timeout=30)
    assert process.returncode == code, err
    assert err.splitlines()[-1] == said and "PASS" not in out and "FAIL" not in out
    frames, rows, imu = recorded(capsys, record, table)
    assert frames == rows == imu > 1000


def writer_processes(parent: int | None = None) -> list[int]:
    """The recording writers (`wftool.recording.mcapprocess`) that process `parent` (this
    one by default) started."""
    parent = os.getpid() if parent is None else parent
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            started_by = int(stat.read_text().rsplit(")", 1)[1].split()[1])
            command = (stat.parent / "cmdline").read_bytes()
        except (OSError, IndexError, ValueError):
            continue  # it ended meanwhile
        if started_by == parent and b"mcapprocess" in command:
            found.append(int(stat.parent.name))
    return found


def test_stop_signals_to_the_writer_while_it_writes_chunks_lose_nothing(capsys, tmp_path):
    """SIGINT, SIGTERM and SIGHUP land on the recording's writer every few ms once it has
    started (created its file), so also while it writes chunks: it goes on, the run ends
    as timed, and the file is whole."""
    record, table = tmp_path / "run.mcap", tmp_path / "run.csv"
    done, sent = threading.Event(), []

    def storm() -> None:
        signals = [signal.SIGINT, signal.SIGTERM, signal.SIGHUP]
        writers: list[int] = []  # found once: reading /proc every 4 ms left few signals
        while not done.wait(0.004):  # a loaded host wakes this thread every 10-30 ms: each
            if not writers and record.exists():  # time all three signals, one after another
                writers = writer_processes()
            for pid in writers:
                for sig in signals:
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(pid, sig)
                        sent.append(pid)

    sender = threading.Thread(target=storm)
    sender.start()
    try:
        with FakeFc() as fc:
            code, out, err = run(capsys, "verify", "--stream", "--port", fc.url, "--duration",
                                 "8", "--record", str(record), "--csv", str(table))  # fmt: skip
    finally:
        done.set()
        sender.join()
    assert len(sent) > 300 and code in (0, 1) and ("PASS" in out or "FAIL" in out), err
    frames, rows, imu = recorded(capsys, record, table)
    assert frames == rows == imu > 5000


def size(path) -> int:
    return path.stat().st_size if path.exists() else 0


def kill_while_recording(fc: FakeFc, record: Path, writer: bool) -> None:
    """SIGKILL a verify run a few chunks into its recording (an MCAP file, or a bag
    directory): the run alone, or with its recording's writer (as a power cut would; it runs
    in a session of its own)."""
    process = wftool("verify", "--stream", "--port", fc.url, "--duration", "60",
                     "--record", str(record))  # fmt: skip
    written = record / f"{record.name}_0.mcap" if record.suffix != ".mcap" else record
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and size(written) < 300_000:  # a few chunks
        time.sleep(0.1)
    for pid in writer_processes(process.pid) if writer else ():
        os.kill(pid, signal.SIGKILL)
    process.kill()
    process.communicate(timeout=30)


def test_a_killed_run_leaves_its_recording_finished_by_its_writer(capsys, tmp_path):
    """The run is killed, its writer is not: it finishes the file with all it was handed."""
    record = tmp_path / "run.mcap"
    with FakeFc() as fc:
        kill_while_recording(fc, record, writer=False)
    with open(record, "rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None, "not finished: no summary"
    code, out, err = run(capsys, "replay", str(record), "--json")
    assert code in (0, 1), err
    replayed = json.loads(out)
    assert replayed["frames"] > 1000 and replayed["lost_frames"] == 0
    assert not any("not finished" in note for note in replayed["verdict"]["notes"])


CUT_SHORT = re.compile(
    r"the recording was cut short at (?P<at>[0-9.]+) s \(of 60 planned\): (?P<why>.*)"
)


def bag_counts(bag: Path) -> tuple[int, int, dict[str, int]]:
    """What rosbags (an independent reader) says a bag holds: messages, duration (ns) and
    messages per topic, as its metadata.yaml lists them."""
    with Reader(bag) as reader:
        return (
            reader.message_count,
            reader.duration,
            {c.topic: c.msgcount for c in reader.connections},
        )


def mcap_counts(path: Path) -> tuple[int, int, dict[str, int]]:
    """The same figures from the MCAP file's own summary (the `mcap` library)."""
    with open(path, "rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None and summary.statistics is not None
    stats = summary.statistics
    topics = {c.topic: stats.channel_message_counts.get(i, 0) for i, c in summary.channels.items()}
    span = stats.message_end_time - stats.message_start_time + 1  # as rosbags counts it
    return stats.message_count, span, topics


def test_a_killed_run_is_said_cut_short_and_its_bag_repaired(capsys, tmp_path):
    """SIGKILL mid-run: its writer finishes the MCAP file, but metadata.yaml still lists what
    the start wrote (no message, 0 s). replay says the recording was cut short, how far into
    the 60 s planned, and reads what is there; `record repair` rebuilds metadata.yaml from
    the file (as `ros2 bag reindex` does), after which rosbags reads the bag in full; the
    recording still says it was cut short."""
    record = tmp_path / "run"
    with FakeFc() as fc:
        kill_while_recording(fc, record, writer=False)
    mcap = record / "run_0.mcap"
    held, span, topics = mcap_counts(mcap)
    assert held > 5000
    assert bag_counts(record) == (0, 0, dict.fromkeys(topics, 0))  # as the run left it

    code, out, err = run(capsys, "replay", str(record), "--json")
    assert code in (0, 1), err
    replayed = json.loads(out)
    assert replayed["frames"] > 1000 and replayed["lost_frames"] == 0
    cut = CUT_SHORT.fullmatch(replayed["verdict"]["notes"][-1])
    assert cut is not None, replayed["verdict"]["notes"]
    assert float(cut["at"]) == pytest.approx(replayed["duration_s"], abs=0.05)
    assert 1.0 < float(cut["at"]) < 60
    assert cut["why"].startswith("it was never closed")

    code, out, err = run(capsys, "record", "repair", str(record))
    assert (code, err) == (0, ""), err
    said = " ".join(out.split())
    assert f"run/metadata.yaml rebuilt from run_0.mcap: {held:,} messages over " in said
    assert "(it listed 0)" in said and "cut short at " in said and "(of 60 planned)" in said
    assert bag_counts(record) == (held, span, topics)
    in_file = {topic: len(messages) for topic, messages in read_bag(record).items()}
    assert in_file == {topic: n for topic, n in topics.items() if n}
    code, out, _ = run(capsys, "replay", str(record), "--json")
    assert json.loads(out) == replayed  # what was recorded is unchanged


def test_a_killed_run_and_writer_leave_a_bag_repair_ends_again(capsys, tmp_path):
    """The writer killed too (a power cut): the MCAP file has no ending, which rosbags
    cannot read. `record repair` writes it again with one, every message that could be read
    (the file as found kept beside it), and rebuilds metadata.yaml."""
    record = tmp_path / "run"
    with FakeFc() as fc:
        kill_while_recording(fc, record, writer=True)
    mcap = record / "run_0.mcap"
    before = mcap.read_bytes()
    with pytest.raises(RosbagsReaderError):
        bag_counts(record)
    code, out, _ = run(capsys, "replay", str(record), "--json")
    cut = CUT_SHORT.fullmatch(json.loads(out)["verdict"]["notes"][-1])
    assert cut is not None and cut["why"].startswith("run_0.mcap was not finished")
    frames = json.loads(out)["frames"]

    code, out, err = run(capsys, "record", "repair", str(record))
    assert (code, err) == (0, ""), err
    assert "run_0.mcap had no ending" in " ".join(out.split())
    assert (record / "run_0.mcap.cut").read_bytes() == before
    held, span, topics = mcap_counts(mcap)
    assert bag_counts(record) == (held, span, topics) and held > 5000
    code, out, _ = run(capsys, "replay", str(record), "--json")
    assert json.loads(out)["frames"] == frames  # every frame the cut file held
    code, _, err = run(capsys, "record", "repair", str(record))
    assert code == 0, err  # again: nothing left to end, the metadata rebuilt alike


def test_a_killed_run_and_writer_leave_a_recording_replay_reads_as_far_as_it_goes(capsys, tmp_path):
    record = tmp_path / "run.mcap"
    with FakeFc() as fc:
        kill_while_recording(fc, record, writer=True)
    code, out, err = run(capsys, "replay", str(record), "--json")
    assert code in (0, 1), err
    replayed = json.loads(out)
    assert replayed["frames"] > 1000 and replayed["lost_frames"] == 0
    note = replayed["verdict"]["notes"][-1]
    assert "run.mcap was not finished" in note and "messages" in note and "lost: " in note


@pytest.mark.parametrize("fmt", ["json", "ros2"])
def test_a_recording_cut_anywhere_is_read_as_far_as_it_goes(fmt, capsys, tmp_path):
    whole = tmp_path / "whole.mcap"
    with Recorder(whole, None, {"port": "test"}, record_format=fmt) as recorder:
        recorder.event(Event("connected", 1.0))
        for index, data in enumerate(flight(3000)):
            recorder.event(Event("bytes", 1.0 + index * 0.0057, data))
        recorder.event(Event("disconnected", 20.0))
    data = whole.read_bytes()
    replayed = []
    for fraction in (0.3, 0.6, 0.9, 0.999):
        cut = tmp_path / f"cut{fraction}.mcap"
        cut.write_bytes(data[: int(len(data) * fraction)])
        code, out, err = run(capsys, "replay", str(cut), "--json")
        assert code in (0, 1), err
        replayed.append(json.loads(out))
        assert "was not finished" in replayed[-1]["verdict"]["notes"][-1]
    frames = [r["frames"] for r in replayed]
    assert 0 < frames[0] < frames[1] < frames[2] <= frames[3] <= 6000


@pytest.mark.parametrize(
    "option", [("--record", "run.mcap", "--record-format", "json"), ("--csv", "run.csv")]
)
def test_an_existing_recording_is_never_overwritten(option, capsys, tmp_path):
    taken = tmp_path / option[1]
    taken.write_text("an earlier run")
    code, _, err = run(capsys, "verify", "--stream", "--port", NO_PORT,
                       option[0], str(taken), *option[2:])  # fmt: skip
    assert taken.read_text() == "an earlier run"
    assert code == 2 and err == f"error: cannot write the recording: {taken} already exists\n"


# -- replay of what is no recording of ours (item 9) --------------------------------------------


def crafted(path, events: list[bytes], metadata: dict[str, str] | None = None) -> None:
    """A well-formed MCAP file with an /fsp/events channel holding `events` as they are."""
    with open(path, "wb") as handle:
        writer = McapWriter(handle)
        writer.start()
        writer.add_metadata("wftool.verify", metadata or {"port": "test"})
        schema = writer.register_schema("wftool.verify.Event", "jsonschema", b"{}")
        channel = writer.register_channel("/fsp/events", "json", schema)
        for index, event in enumerate(events):
            writer.add_message(channel, index, event, index)
        writer.finish()


CONNECTED = b'{"kind": "connected", "t": 1.0}'
DAMAGED = {
    "bytes before connected": ([b'{"kind": "bytes", "t": 1.0, "data": "AQA="}'], None),
    "a string time": ([b'{"kind": "connected", "t": "soon"}'], None),
    "an infinite time": ([b'{"kind": "connected", "t": 1e999}'], None),
    "a JSON list": ([b"[1, 2, 3]"], None),
    "no JSON": ([b"{kind: connected"], None),
    "no kind": ([b'{"t": 1.0}'], None),
    "data not base64": ([CONNECTED, b'{"kind": "bytes", "t": 1.1, "data": "#!"}'], None),
    "rc not numbers": ([CONNECTED, b'{"kind": "command", "t": 1.1, "rc": ["a"]}'], None),
    "a rate not a number": ([CONNECTED], {"expected_rate_hz": "fast"}),
}


@pytest.mark.parametrize("case", DAMAGED)
def test_unexpected_content_in_a_recording_is_a_one_line_error(case, capsys, tmp_path):
    path = tmp_path / "odd.mcap"
    crafted(path, *DAMAGED[case])
    code, out, err = run(capsys, "replay", str(path))
    assert (code, out) == (2, "")
    assert err.startswith(f"error: recording {path} is damaged: ") and err.count("\n") == 1


def test_an_empty_or_foreign_file_says_why_it_is_no_recording(capsys, tmp_path):
    empty, foreign = tmp_path / "empty.mcap", tmp_path / "foreign.mcap"
    empty.write_bytes(b"")
    foreign.write_bytes(b"time,acc\n0,1\n")
    for path, reason in ((empty, "the file is empty"), (foreign, "not an MCAP file")):
        code, _, err = run(capsys, "replay", str(path))
        assert (code, err) == (2, f"error: cannot read recording {path}: {reason}\n")
