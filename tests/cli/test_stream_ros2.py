"""verify --record (ROS 2) and --foxglove at the click layer: bad input first, then a run.

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


def test_record_path_ending_in_mcap_is_refused_before_connecting(capsys, tmp_path):
    code, _, err = run(capsys, "verify", "--stream", "--port", NO_PORT,
                       "--record", str(tmp_path / "run.mcap"))  # fmt: skip
    assert code == 2 and err.count("\n") == 1
    assert "a ROS 2 recording is a directory" in err


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


def test_verify_records_a_rosbag_and_serves_foxglove(capsys, tmp_path):
    pytest.importorskip("foxglove")
    reads = flight(600)
    ready, port = threading.Event(), []
    threading.Thread(target=_serve, args=(reads, ready, port), daemon=True).start()
    assert ready.wait(5)
    bag = tmp_path / "flight"
    code, _, err = run(capsys, "verify", "--stream", "--port", f"socket://127.0.0.1:{port[0]}",
                       "--duration", "2", "--record", str(bag), "--foxglove", "0")  # fmt: skip
    assert code in (0, 1), err  # the verdict is not the point here
    assert "Foxglove  ws://127.0.0.1:" in err
    with AnyReader([bag], default_typestore=get_typestore(Stores.EMPTY)) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts["/fsp/imu"] > 1000 and counts["/fsp/health"] > 0  # the reader may skip
    code, out, _ = run(capsys, "replay", str(bag), "--json")  # what came before it opened
    assert json.loads(out)["frames"] == counts["/fsp/imu"]
