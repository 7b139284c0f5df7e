"""The MSP poller against the patched SITL (a real Betaflight answering MSP).

What is checked is what the poller promises, not how fast a loaded machine is: every
request goes out in a slot of its command's schedule (never early, never twice), at most
WINDOW are unanswered at any time, every reply is stamped on reception after its request,
every slot is accounted for, and the FC answers no more than its serial task can.
"""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import run_cli
from wftool.errors import UsageError
from wftool.fc.msp import Cmd, FrameReader, MspVersion, parse_raw_imu
from wftool.fc.msp_poller import PAPER_SCHEDULE, MspPoller, MspReply, PollRate, parse_schedule
from wftool.link.transport import open_port
from wftool.recording.msp import msp_replies
from wftool.sitl.process import VirtualFC

SERIAL_TASK_HZ = 100
"""A fresh SITL's serial_update_rate_hz (Betaflight's default)."""


class Seen:
    """A poll observer that keeps everything, in order."""

    def __init__(self) -> None:
        self.events: list[tuple[str, float, object]] = []
        self.replies: list[MspReply] = []
        self.start = self.end = math.nan

    def connected(self, t: float) -> None:
        self.start = t

    def disconnected(self, t: float) -> None:
        self.end = t

    def request(self, t: float, wire: bytes) -> None:
        self.events.append(("request", t, FrameReader().feed(wire.replace(b"<", b">", 1))[0].cmd))

    def read(self, t: float, data: bytes) -> None:
        self.events.append(("read", t, data))

    def reply(self, reply: MspReply) -> None:
        self.events.append(("reply", reply.t, reply.cmd))
        self.replies.append(reply)


def poll(fc: VirtualFC, duration_s: float, window: int, **options) -> tuple[object, Seen]:
    seen = Seen()
    link = open_port(fc.url, timeout=0)
    try:
        result = MspPoller(link, PAPER_SCHEDULE, window=window, **options).run(duration_s, seen)
    finally:
        link.close()
    return result, seen


def assert_slots_of_their_own(result, seen: Seen, rate: PollRate) -> None:
    """Every request of `rate`'s command in a slot of its own (k = its slot, distinct and
    increasing), and every slot sent, skipped or missed."""
    stats = result.commands[rate.cmd]
    period = 1.0 / rate.rate_hz
    slots = [
        math.floor((t - seen.start) / period)
        for kind, t, cmd in seen.events
        if kind == "request" and cmd == rate.cmd
    ]
    assert len(slots) == stats.sent > 0
    assert slots == sorted(set(slots)) and slots[-1] < stats.slots
    assert stats.sent + stats.skipped + stats.missed == stats.slots


@pytest.mark.parametrize("window", [4, 1])
def test_schedule_window_and_stamps_on_sitl(virtual_fc: VirtualFC, window: int) -> None:
    result, seen = poll(virtual_fc, 3.0, window)
    assert not result.interrupted and result.corrupt_frames == 0 and result.stray_replies == 0
    for rate in PAPER_SCHEDULE:
        stats = result.commands[rate.cmd]
        assert_slots_of_their_own(result, seen, rate)
        assert stats.slots <= result.duration_s * rate.rate_hz + 1
        assert stats.replies == stats.sent - stats.lost and stats.lost == 0
        assert stats.error_replies == 0
    # Never more than WINDOW unanswered.
    in_flight = worst = 0
    for kind, _, _ in seen.events:
        in_flight += {"request": 1, "reply": -1}.get(kind, 0)
        worst = max(worst, in_flight)
    assert worst == window and in_flight == 0
    # Stamped on reception: each reply at the time of the read that completed it, after its
    # request, in order.
    reads = [t for kind, t, _ in seen.events if kind == "read"]
    assert all(reply.t in reads for reply in seen.replies)
    assert all(r.requested_at is not None and r.t >= r.requested_at for r in seen.replies)
    assert [r.t for r in seen.replies] == sorted(r.t for r in seen.replies)
    assert seen.start <= seen.replies[0].t and seen.replies[-1].t <= seen.end
    imu = next(r for r in seen.replies if r.cmd == Cmd.RAW_IMU)
    assert len(parse_raw_imu(imu.payload).gyro) == 3
    # One command per serial task run: the FC (whose clock never runs ahead of the host's)
    # answers at most 100 a second, however many are asked for.
    answered = sum(stats.replies for stats in result.commands.values())
    assert answered <= SERIAL_TASK_HZ * (seen.end - seen.start) + window
    assert sum(stats.sent for stats in result.commands.values()) < sum(
        stats.slots for stats in result.commands.values()
    )


def test_a_slot_gone_by_while_the_poller_was_held_up_is_not_sent_late(
    virtual_fc: VirtualFC, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The host holds the poller up between a slot's coming and its request going out (here
    once, for 3 periods, as a loaded host did): the request of the slot that went by is not
    sent, as late as that, into its successor's slot; it is skipped."""
    rate = PollRate(Cmd.RC, 50.0)  # the FC answers well within a period: the window has room
    expire, held = MspPoller._expire, []

    def held_up(poller: MspPoller, stats: dict, t: float) -> None:
        expire(poller, stats, t)
        if not held and stats[rate.cmd].slots == 10:
            held.append(t)
            time.sleep(3 / rate.rate_hz)

    monkeypatch.setattr(MspPoller, "_expire", held_up)
    seen = Seen()
    link = open_port(virtual_fc.url, timeout=0)
    try:
        result = MspPoller(link, (rate,), window=4).run(1.0, seen)
    finally:
        link.close()
    assert held and result.commands[rate.cmd].skipped >= 1
    assert_slots_of_their_own(result, seen, rate)


def test_msp_v2_requests_are_answered(virtual_fc: VirtualFC) -> None:
    result, _ = poll(virtual_fc, 1.0, 2, version=MspVersion.V2)
    assert result.commands[Cmd.RAW_IMU].replies > 0 and result.corrupt_frames == 0


def test_schedules_are_parsed_and_bad_ones_refused() -> None:
    assert parse_schedule(["raw_imu=500", "MSP_RC=50"]) == (
        PollRate(Cmd.RAW_IMU, 500.0),
        PollRate(Cmd.RC, 50.0),
    )
    for bad in (["RAW_IMU"], ["NOPE=10"], ["RC=0"], ["RC=fast"], ["RC=10", "rc=20"]):
        with pytest.raises(UsageError):
            MspPoller(None, parse_schedule(bad))


def test_record_msp_cli_and_bad_input(
    virtual_fc: VirtualFC, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "msp"
    # RAW_IMU alone: under the paper's schedule a fresh virtual FC (serial task at 100 Hz, one
    # command a run) answers RC and ATTITUDE first, and RAW_IMU 1-35 times in 2 s
    code, stdout, stderr = run_cli(
        capsys, "record", "msp", "--port", virtual_fc.url, "--duration", "2", "--out", str(out),
        "--schedule", "RAW_IMU=100",
    )  # fmt: skip
    assert code == 0, stderr
    assert "RAW_IMU" in stdout and "commands/s" in stdout and "stamped on reception" in stderr
    code, stdout, stderr = run_cli(capsys, "analyze", "timing", str(out), "--out", str(tmp_path))
    assert code == 0, stderr
    assert "OBC reception time" in stdout

    for args, message in (
        (["--out", str(out)], "already exists"),
        (["--schedule", "WHAT=1"], "expected NAME=HZ"),
        (["--port", "socket://127.0.0.1:1", "--out", str(tmp_path / "x")], "cannot open"),
    ):
        argv = ["record", "msp", "--port", virtual_fc.url, "--duration", "1", *args]
        code, stdout, stderr = run_cli(capsys, *argv)
        assert code == 2, stdout + stderr
        assert len(stderr.strip().splitlines()) == 1 and message in stderr, stderr
    assert not (tmp_path / "x").exists()  # nothing left behind by a run that could not start


def test_a_link_that_echoes_is_no_fc_answering(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # pyserial's loop:// gives back every byte written: our requests, never a reply.
    out = tmp_path / "echo"
    argv = ["record", "msp", "--port", "loop://", "--duration", "1", "--out", str(out)]
    code, stdout, stderr = run_cli(capsys, *argv, "--json")
    assert code == 0, stderr
    summary = json.loads(stdout)
    sent = sum(row["sent"] for row in summary["commands"])
    assert sent > 0
    assert [row["replies"] for row in summary["commands"]] == [0] * len(PAPER_SCHEDULE)
    assert sum(row["lost"] for row in summary["commands"]) == sent
    assert summary["echoed_requests"] == sent
    _, connections = msp_replies(out)
    assert connections == [[]]
    code, stdout, stderr = run_cli(capsys, "analyze", "timing", str(out), "--out", str(tmp_path))
    assert code == 2
    assert stderr.strip().splitlines() == [f"error: {out} holds no MSP_RAW_IMU replies"]


def test_ctrl_c_ends_an_open_ended_recording_and_keeps_it(
    virtual_fc: VirtualFC, tmp_path: Path
) -> None:
    bag = tmp_path / "msp"
    process = subprocess.Popen(
        [sys.executable, "-m", "wftool", "record", "msp", "--port", virtual_fc.url,
         "--out", str(bag), "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # as from a terminal
    )  # fmt: skip
    try:
        assert process.stderr is not None and process.stdout is not None
        assert process.stderr.readline().startswith("polling ")
        time.sleep(1.5)
        process.send_signal(signal.SIGINT)
        assert process.wait(30) == 0, process.stderr.read()
        counts = json.loads(process.stdout.read())
        assert "(interrupted)" in process.stderr.read()
    finally:
        process.kill()
        process.wait()
    assert counts["interrupted"]
    metadata, [replies] = msp_replies(bag)
    assert json.loads(metadata["result"]) == counts
    imu = counts["commands"][0]
    assert imu["command"] == "RAW_IMU"
    assert imu["sent"] + imu["skipped"] + imu["missed"] == imu["slots"]
    assert sum(1 for reply in replies if reply.cmd == Cmd.RAW_IMU) == imu["replies"] > 0
