"""`wftool sitl` without --verify, serving: it records and serves Foxglove while the FC runs.

wftool runs in its own process, as a user starts it, against the patched SITL; a Foxglove
protocol client watches, rosbags reads the recording, and `wftool replay` judges it.
"""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rosbags.rosbag2 import Reader

from tests.conftest import run_cli
from tests.sitl.test_process import sitl_pids, wait_for
from wftool.sitl.process import free_port_base

pytestmark = pytest.mark.slow


def test_serving_records_and_serves_foxglove_until_interrupted(
    sitl_binary: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("foxglove", reason="needs the Foxglove SDK: wftool[foxglove]")
    from tests.verify.test_foxglove import Viewer

    base, bag = free_port_base(), tmp_path / "served"
    process = subprocess.Popen(
        [sys.executable, "-m", "wftool", "sitl", "--binary", str(sitl_binary),
         "--workdir", str(tmp_path / "fc"), "--port-base", str(base), "--no-motion",
         "--record", str(bag), "--foxglove", "0", "--clock", "kalman"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # as from a terminal
    )  # fmt: skip
    try:
        assert process.stderr is not None
        said = []
        for line in process.stderr:
            said.append(line)
            if line.startswith("running"):
                break
        url = next(m[1] for line in said if (m := re.match(r"Foxglove +(ws://\S+)", line)))
        viewer = Viewer(url)
        imu = viewer.receive(400).get("/fsp/imu", [])
        viewer.close()
        assert len(imu) > 50  # live frames, while the FC keeps running
        time.sleep(2.0)
        process.send_signal(signal.SIGINT)  # Ctrl-C: the normal end of serving
        assert process.wait(30) == 0, process.stderr.read()
    finally:
        process.kill()
        process.wait()
    assert wait_for(lambda: not sitl_pids(base), 15)

    with Reader(bag) as reader:  # finished on the way out, and a rosbag2 directory
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts["/fsp/imu"] > 2000
    code, out, err = run_cli(capsys, "replay", str(bag), "--json")
    replayed = json.loads(out)
    assert code == 0, err  # judged as a board: the rate the FC's settings give, no loss
    assert replayed["frames"] == counts["/fsp/imu"]
    assert replayed["clock_estimator"] == "kalman"
    assert replayed["expected_rate_hz"] and replayed["lost_frames"] == 0


def test_time_reply_with_verify_needs_commands(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run_cli(capsys, "sitl", "--time-reply", "--verify", "3")
    assert code == 2
    assert err.strip() == "error: --time-reply answers commands: add --uplink to send them"


def test_with_the_users_obc_on_the_port_enter_engages_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """`wftool sitl --pilot` with nothing of wftool's reading the stream: each Enter on the
    terminal turns the override switch off and on; the end of input changes nothing more."""
    import os
    import socket
    import threading

    from wftool.cli.sitl import flip_on_enter
    from wftool.sitl.radio import HIGH, LOW, EngagingPilot, SimulatedRadio, channel_index

    master, slave = os.openpty()
    with (
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rc_input,
        os.fdopen(slave, "r") as terminal,
    ):
        rc_input.bind(("127.0.0.1", 0))
        monkeypatch.setattr(sys, "stdin", terminal)
        with SimulatedRadio(rc_input.getsockname()[1]) as radio:
            said: list[str] = []
            pilot = EngagingPilot(radio, 2, say=said.append)
            stop = threading.Event()
            flips = threading.Thread(target=flip_on_enter, args=(pilot, stop))
            flips.start()
            try:
                assert radio.channels[channel_index("aux2")] == LOW
                os.write(master, b"\n")
                assert wait_for(lambda: pilot.engagements == 1, 5.0)
                assert radio.channels[channel_index("aux2")] == HIGH
                assert said == ["pilot: override switch AUX2 on: engaging the OBC"]
            finally:
                stop.set()
                flips.join(5.0)
                os.close(master)
    assert not flips.is_alive()
