"""verify --record (ROS 2), --clock and --foxglove at the click layer: bad input, then runs.

The run reads a synthetic FSP stream served over local TCP (a capture player, not an FC:
the SITL is not needed to exercise the recording and serving path end to end).
"""

from __future__ import annotations

import json
import socket
import sys
import threading
import time

import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from tests.conftest import run_cli as run
from tests.verify.test_rosbag import flight

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
            for data in reads:
                connection.sendall(data)
                time.sleep(0.0057)  # three packets' worth of time
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
