"""The virtual FC runs like a board: every task at its configured rate, FSP frames exactly
one lockstep interval apart, nothing dropped. Against the patched SITL, a real Betaflight:
configured through the CLI, read over TCP, decoded with wftool.fsp.

The SITL's lockstep clock makes FC time exact, so these are statements about FC time (task
rates from the FC's own `tasks`, frame sample times), not timings of the machine running
the test. The configured rates come from the firmware itself: the `TASK_PERIOD_HZ(n)` each
task is declared with in the tree's src/main/fc/tasks.c, the settings the CLI reports, and
the PID looptime MSP reports.
"""

from __future__ import annotations

import re
import threading
from collections.abc import Iterator
from itertools import pairwise
from pathlib import Path

import pytest

from tests.waits import wait_for
from wftool.fc.cli_session import CliSession
from wftool.fc.msp import MspClient
from wftool.fc.tasks import parse_tasks
from wftool.fsp import FspReader, StatePacket
from wftool.fsp.schedule import frame_rate_hz, lockstep_interval
from wftool.sitl.process import VirtualBoard
from wftool.sitl.session import Motion, VirtualFcSession

RATE_TOLERANCE = 0.05
SETTLE_S = 6.0
"""`tasks` rates are moving averages over 64 runs: a 50 Hz task needs ~4 s (FC time) to
settle."""
MIN_CHECKED_HZ = 50
_DECLARED = re.compile(r'DEFINE_TASK\("(\w+)", (?:"(\w+)"|NULL), .*TASK_PERIOD_HZ\((\d+)\)')


class Collector(threading.Thread):
    """Reads the FSP port in the background."""

    def __init__(self, url: str) -> None:
        super().__init__(daemon=True)
        self.reader = FspReader(url).open()
        self.packets: list[StatePacket] = []
        self.done = threading.Event()

    def run(self) -> None:
        while not self.done.is_set():
            self.packets.extend(self.reader.read(0.05))

    def stop(self) -> None:
        self.done.set()
        self.join(2)
        self.reader.close()

    def fc_seconds(self) -> float:
        """The FC time the frames read so far span."""
        packets = self.packets
        if not packets or packets[0].frames[0].time_us is None:
            return 0.0
        last = packets[-1].frames[-1].time_us or 0
        return (last - packets[0].frames[0].time_us) / 1e6

    def wait_fc_seconds(self, seconds: float) -> None:
        """Until the frames span `seconds` of FC time (a loaded host runs the virtual FC
        slower than its own clock: the FC's time is what the rates are averaged over)."""
        assert wait_for(lambda: self.fc_seconds() >= seconds, 10 * seconds + 30), (
            f"{self.fc_seconds():.1f} s of FC time in the stream"
        )


def task_rates(session: CliSession) -> dict[str, int]:
    """Task name -> the rate the FC's `tasks` reports."""
    return {name: row.rate_hz for name, row in parse_tasks(session.run("tasks")).items()}


def declared_rates(tree: Path) -> dict[str, int]:
    """Task name -> the rate its DEFINE_TASK declares, where that is a number."""
    rates = {}
    for line in (tree / "src/main/fc/tasks.c").read_text().splitlines():
        if match := _DECLARED.search(line):
            name, sub, hz = match.groups()
            rates[f"{name}/{sub}" if sub else name] = int(hz)
    return rates


@pytest.fixture
def moving_fc(sitl_binary: Path, tmp_path: Path) -> Iterator[VirtualFcSession]:
    with VirtualFcSession(sitl_binary, tmp_path, motion=Motion(), port_base=None) as session:
        yield session


def test_every_task_runs_at_its_configured_rate(
    moving_fc: VirtualFcSession, firmware_tree: Path
) -> None:
    collector = Collector(moving_fc.fsp_url)  # a client on FSP, as in flight
    collector.start()
    collector.wait_fc_seconds(SETTLE_S)
    with MspClient.open(moving_fc.msp_url) as msp:
        looptime_us = msp.pid_looptime_us()
    session = CliSession.open(moving_fc.msp_url)  # left open: `exit` would reboot the FC
    try:
        serial_hz = int(session.get("serial_update_rate_hz").value)
        measured = task_rates(session)
    finally:
        session.close()
        collector.stop()

    configured = {
        name: hz for name, hz in declared_rates(firmware_tree).items() if hz >= MIN_CHECKED_HZ
    }
    configured.update(
        GYRO=round(1e6 / looptime_us),
        FILTER=round(1e6 / looptime_us),
        PID=round(1e6 / looptime_us),
        SERIAL=serial_hz,
        FSP=frame_rate_hz(moving_fc.rate_hz, looptime_us),
    )
    checked = {name: hz for name, hz in configured.items() if name in measured}
    assert {"ACC", "ATTITUDE", "SERIAL", "FSP", "PID", "DISPATCH"} <= checked.keys(), measured
    off = {
        name: (measured[name], hz)
        for name, hz in checked.items()
        if abs(measured[name] - hz) > RATE_TOLERANCE * hz
    }
    assert not off, f"(measured, configured) Hz: {off}"


def test_frames_are_one_lockstep_interval_apart_with_nothing_dropped(
    moving_fc: VirtualFcSession,
) -> None:
    with MspClient.open(moving_fc.msp_url) as msp:
        looptime_us = msp.pid_looptime_us()
    collector = Collector(moving_fc.fsp_url)
    collector.start()
    collector.wait_fc_seconds(4.0)
    collector.stop()

    stats = collector.reader.decoder.stats
    assert stats.packets > 500
    assert stats.errors <= 1  # at most the one chunk cut by joining mid-stream
    assert stats.e1 is True
    packets = collector.packets
    seqs = [p.seq for p in packets]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # no packet lost
    assert packets[-1].drops == packets[0].drops  # no frame dropped on the FC
    assert all(len(p.frames) == 2 and p.mavlink is None for p in packets)
    times = [frame.time_us for p in packets for frame in p.frames]
    period = lockstep_interval(moving_fc.rate_hz, looptime_us) * looptime_us
    assert {b - a for a, b in pairwise(times)} == {period}


def test_a_gyro_clock_of_its_own_sets_the_loop_rate_and_micros_truncates(
    sitl_binary: Path, tmp_path: Path
) -> None:
    """A board's gyro runs off its own oscillator: the paper's BMI270 reports 3200 Hz and its
    scheduler 3148 Hz (§5.1). The loop locks onto the samples, FC time stays exact and
    micros() truncates it, as a timer does: fsp_rate_hz 1100 takes every 3rd iteration, so
    frames are 3/3148 s apart, each interval 952 or 953 µs, and their mean is exact."""
    clock_hz = 3148
    board = VirtualBoard(gyro_hz=3200, gyro_clock_hz=clock_hz)
    with VirtualFcSession(sitl_binary, tmp_path, port_base=None, board=board) as fc:
        collector = Collector(fc.fsp_url)
        collector.start()
        collector.wait_fc_seconds(SETTLE_S)
        collector.stop()
        with MspClient.open(fc.msp_url) as msp:
            period_us = msp.pid_looptime_us(256)  # 317 or 318 µs a read
        session = CliSession.open(fc.msp_url)  # left open: `exit` would reboot the FC
        try:
            measured = task_rates(session)
        finally:
            session.close()

    assert abs(period_us - 1e6 / clock_hz) < 0.25
    times = [frame.time_us for p in collector.packets for frame in p.frames]
    assert len(times) > 4000
    assert {b - a for a, b in pairwise(times)} == {952, 953}
    period_us = 3 * 1e6 / clock_hz
    assert abs((times[-1] - times[0]) / (len(times) - 1) - period_us) < 1 / (len(times) - 1)
    # the FC's own scheduler: rates from moving averages of truncated µs deltas
    for name, hz in (("GYRO", clock_hz), ("PID", clock_hz), ("FSP", clock_hz / 3)):
        assert abs(measured[name] - hz) <= 0.001 * hz + 1, (name, measured[name])


def test_msp_is_served_at_the_serial_rate_asked_for(sitl_binary: Path, tmp_path: Path) -> None:
    """The paper's MSP baseline polls at 1 kHz: with serial_update_rate_hz = 1000 the SERIAL
    task, which answers MSP, runs at 1 kHz."""
    with VirtualFcSession(sitl_binary, tmp_path, port_base=None) as fc:
        session = CliSession.open(fc.msp_url)
        session.set("serial_update_rate_hz", "1000")
        session.save()
        fc.fc.wait_back()
        collector = Collector(fc.fsp_url)  # the FC's time since its restart
        collector.start()
        collector.wait_fc_seconds(2.0)
        collector.stop()
        session = CliSession.open(fc.msp_url)
        try:
            serial_hz = task_rates(session)["SERIAL"]
        finally:
            session.close()
    assert abs(serial_hz - 1000) <= RATE_TOLERANCE * 1000
