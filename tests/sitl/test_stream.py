"""FSP end to end on the patched SITL, a real Betaflight: configured through the CLI,
read on TCP 5762, decoded with wftool.fsp.

SITL does not run in real time, so the lockstep rate is computed from the loop rate the
SITL itself reports over the same window: its `tasks` run count for the PID task (reset by
each `tasks`), with the firmware's rule N = floor((1e6 / fsp_rate_hz) / looptime) + 1 and
SITL's nominal PID looptime (virtual gyro at 8 kHz, gyro_sync.c, times pid_process_denom).
"""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path

import pytest

from wftool.fc.cli_session import CliSession
from wftool.fsp import FspReader, StatePacket
from wftool.sitl.session import VirtualFcSession

pytestmark = pytest.mark.slow

SITL_GYRO_LOOPTIME_US = 125
WINDOW_S = 10.0


class Collector(threading.Thread):
    """Reads the FSP port in the background: (arrival time, packet) pairs."""

    def __init__(self, url: str) -> None:
        super().__init__(daemon=True)
        self.reader = FspReader(url).open()
        self.packets: list[tuple[float, StatePacket]] = []
        self.done = threading.Event()

    def run(self) -> None:
        while not self.done.is_set():
            for packet in self.reader.read(0.05):
                self.packets.append((packet.arrival_time, packet))

    def stop(self) -> None:
        self.done.set()
        self.join(2)
        self.reader.close()


def pid_runs(session: CliSession) -> tuple[float, int]:
    """(time of the reply, PID task runs since the previous `tasks`)."""
    output = session.run("tasks")
    at = time.monotonic()
    row = next(line for line in output.splitlines() if "(            PID)" in line)
    columns = row.split(")", 1)[1].split()  # rate max avg maxload avgload total late run reqd
    return at, int(columns[7])


def test_stream_is_valid_gapless_and_lockstepped(sitl_binary: Path, tmp_path: Path) -> None:
    with VirtualFcSession(sitl_binary, tmp_path) as fc:
        collector = Collector(fc.fsp_url)
        collector.start()
        session = CliSession.open(fc.msp_url)  # left open: `exit` would reboot the FC
        try:
            session.enter()
            rate_hz = int(session.get("fsp_rate_hz").value)
            denom = int(session.get("pid_process_denom").value)
            t0, _ = pid_runs(session)
            time.sleep(WINDOW_S)
            t1, runs = pid_runs(session)
        finally:
            session.close()
            collector.stop()

    stats = collector.reader.decoder.stats
    assert stats.packets > 500
    assert stats.errors <= 1  # at most the one chunk cut by joining mid-stream
    assert stats.e1 is True
    assert stats.lost_packets == 0  # E1 seq without gaps
    packets = [p for _, p in collector.packets]
    assert all(len(p.frames) == 2 and p.mavlink is None for p in packets)
    seqs = [p.seq for p in packets]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))

    looptime_us = SITL_GYRO_LOOPTIME_US * denom
    every = math.floor((1e6 / rate_hz) / looptime_us) + 1
    lockstep_hz = runs / (t1 - t0) / every
    window = [p for arrival, p in collector.packets if t0 <= arrival <= t1]
    drops = window[-1].drops - window[0].drops
    captured_hz = (2 * len(window) + drops) / (t1 - t0)
    assert captured_hz == pytest.approx(lockstep_hz, rel=0.05), (runs, every, drops)
