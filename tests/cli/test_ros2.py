"""`wftool ros2` and `wftool sitl --ros2` at the command line: what they refuse, in one line,
before anything starts; and what the node says when it does."""

from __future__ import annotations

import socket
import sys
from types import SimpleNamespace

import pytest

from tests.conftest import run_cli
from tests.ros2 import peers
from tests.verify.test_monitor import feed_fc_uplink
from wftool.cli.ros2 import status_line
from wftool.errors import EXIT_USAGE
from wftool.verify.monitor import StreamMonitor


def test_without_the_extra_it_names_it(capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "rclpy", None)  # as if the ros2 extra were missing
    code, _, err = run_cli(capsys, "ros2", "--port", "socket://127.0.0.1:9")
    assert code == EXIT_USAGE
    assert err.strip() == "error: the ROS 2 node needs ROS 2 (rclpy): pip install 'wftool[ros2]'"


def test_a_port_is_needed(capsys):
    code, _, err = run_cli(capsys, "ros2")
    assert code == EXIT_USAGE
    assert "which FSP port? --port URL" in err


@pytest.mark.parametrize(
    "args, message",
    [
        (("--accept-commands",), "--accept-commands is the ROS 2 node's: add --ros2"),
        (("--ros2", "--accept-commands", "--uplink"), "--uplink and --accept-commands both"),
    ],
)
def test_sitl_refuses_commands_it_cannot_take(capsys, args, message):
    code, _, err = run_cli(capsys, "sitl", "--binary", sys.executable, *args)
    assert code == EXIT_USAGE
    assert message in err


@pytest.mark.usefixtures("ros2_env")
def test_a_port_that_cannot_open_is_one_line_and_the_node_says_who_may_command(capsys, tmp_path):
    with socket.socket() as probe:  # a port nobody listens on
        probe.bind(("127.0.0.1", 0))
        url = f"socket://127.0.0.1:{probe.getsockname()[1]}"
    namespace = peers.namespace_of(tmp_path)
    code, _, err = run_cli(capsys, "ros2", "--port", url, "--namespace", namespace)
    assert code == EXIT_USAGE
    lines = err.splitlines()
    assert lines[-1].startswith("error: ") and url in lines[-1]
    text = " ".join(err.split())  # rich wraps long lines
    assert "discovery: this host only" in text
    assert "commands: not taken (--accept-commands takes them on fsp/command)" in text
    assert f"{namespace}/fsp/imu" in text


@pytest.mark.usefixtures("ros2_env")
def test_sitl_ros2_publishes_the_virtual_fcs_stream_while_it_verifies(
    capsys, sitl_binary, tmp_path
):
    out = tmp_path / "received.jsonl"
    namespace = peers.namespace_of(tmp_path)
    topics = {f"{namespace}/fsp/imu": "sensor_msgs/msg/Imu"}
    with peers.subscriber(out, 60, topics):
        code, _, err = run_cli(
            capsys, "sitl", "--binary", str(sitl_binary), "--port-base", "0", "--ros2",
            "--namespace", namespace, "--verify", "5",
        )  # fmt: skip
    assert code == 0, err
    assert f"publishing {namespace}/fsp/attitude" in " ".join(err.split())
    assert len(peers.received(out)) > 1000  # of 5 s at 1 kHz, less discovery and matching


def test_the_status_line_says_what_the_fc_made_of_the_commands():
    monitor = StreamMonitor("socket://sim:5762")
    feed_fc_uplink(monitor, 2100)  # timed out, then the pilot's radio lost
    node = SimpleNamespace(gate=None, unpublished=0)  # takes no commands: what it did is not said
    line = status_line(monitor.summary(), node)
    assert line.startswith("4200 frames published")
    assert line.endswith(
        "; the FC: 500 accepted, 5 stale, 1 timeouts; override, RX loss, armed; "
        "failsafe RX_LOSS_DETECTED"
    )
    assert "the FC" not in status_line(StreamMonitor("x").summary(), node)
    assert "refused" not in line
    refused = status_line(monitor.summary(), SimpleNamespace(gate=None, unpublished=3))
    assert "reconnects 0, 3 messages the middleware refused; the FC" in refused
