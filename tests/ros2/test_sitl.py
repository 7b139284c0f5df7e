"""`wftool ros2` end to end: the patched SITL streams FSP, the node (the real command, a
process of its own) publishes it, and separate rclpy processes subscribe and command."""

from __future__ import annotations

import itertools
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.ros2 import peers
from wftool.sitl.session import Motion, VirtualFcSession

pytestmark = [pytest.mark.slow, pytest.mark.usefixtures("ros2_env")]

SUBSCRIBE_S = 20.0
PERIOD_NS = 1_000_000  # the virtual FC's frame period: fsp_rate_hz 1100 at an 8 kHz PID loop


@pytest.fixture
def fsp_fc(sitl_binary: Path, tmp_path: Path) -> Iterator[VirtualFcSession]:
    with VirtualFcSession(sitl_binary, tmp_path / "fc", motion=Motion(), port_base=None) as session:
        yield session


@pytest.fixture
def node(fsp_fc: VirtualFcSession, tmp_path: Path) -> Iterator[str]:
    """`wftool ros2` on the virtual FC's FSP port, taking commands: its namespace."""
    assert fsp_fc.expected_rate_hz == pytest.approx(1e9 / PERIOD_NS)
    namespace = peers.namespace_of(tmp_path)
    log = (tmp_path / "node.log").open("w")
    process = subprocess.Popen(
        [sys.executable, "-m", "wftool", "ros2", "--port", fsp_fc.fsp_url, "--namespace",
         namespace, "--accept-commands", "--duration", str(SUBSCRIBE_S + 30)],
        stdout=log, stderr=subprocess.STDOUT, env=os.environ.copy(),
    )  # fmt: skip
    try:
        yield namespace
    finally:
        process.terminate()
        process.wait(timeout=20)
        log.close()
    assert process.returncode in (0, -15, 143), (tmp_path / "node.log").read_text()


def stamp_of(message: dict) -> int:
    return message["header"]["stamp"]["sec"] * 1_000_000_000 + message["header"]["stamp"]["nanosec"]


def test_a_subscriber_gets_every_frame_on_the_sample_grid_and_commands_fly(
    node: str, tmp_path: Path
):
    """For 20 s a separate subscriber receives ≥ 99.9 % of the frames the FC sampled, each
    stamped on the FC's 1 ms sample grid; a command published on ROS 2 in the middle comes
    back in the FC's RC channels in the stream, and stops when its sender does."""
    out = tmp_path / "received.jsonl"
    topics = {
        f"{node}/fsp/imu": "sensor_msgs/msg/Imu",
        f"{node}/fsp/rc": "wftool_msgs/msg/RcChannels",
        f"{node}/fsp/health": "wftool_msgs/msg/StreamHealth",
        f"{node}/fsp/command_status": "wftool_msgs/msg/CommandStatus",
    }
    roll = [1000 + 37 * i for i in range(20)]  # a pattern no stick sits at
    plan = [{"rc": [r, 1500, 1500, 1000, 1000, 1000], "after_s": 0.02} for r in roll * 5]
    with peers.subscriber(out, SUBSCRIBE_S, topics, matched=True) as subscriber:
        time.sleep(SUBSCRIBE_S / 2)
        assert peers.command(f"{node}/fsp/command", plan) == "matched"
        subscriber.wait(timeout=SUBSCRIBE_S + 30)
    got: dict[str, list[dict]] = {}
    for line in peers.received(out):
        got.setdefault(line["topic"].rsplit("/", 1)[-1], []).append(line["message"])

    stamps = [stamp_of(m) for m in got["imu"]]
    steps = [b - a for a, b in itertools.pairwise(stamps)]
    frames_sampled = round((stamps[-1] - stamps[0]) / PERIOD_NS) + 1
    assert len(stamps) >= 0.999 * frames_sampled
    assert frames_sampled >= 0.9 * SUBSCRIBE_S * 1e9 / PERIOD_NS  # the whole 20 s
    assert all(step > 0 for step in steps)  # in capture order, none twice
    off_grid = [s for s in steps if abs(s - round(s / PERIOD_NS) * PERIOD_NS) > 20_000]
    assert len(off_grid) <= len(steps) // 1000, off_grid[:10]  # within 20 µs of the grid
    assert statistics.median(steps) == pytest.approx(PERIOD_NS, abs=1_000)

    seen = [m["roll"] for m in got["rc"]]
    echoed = [r for r in roll if r in seen]
    assert len(echoed) >= len(roll) - 1, (echoed, sorted(set(seen)))
    assert seen[-1] not in roll  # the sender stopped: the FC is back on its own receiver
    status = got["command_status"][-1]
    assert status["accepting"] and status["received"] == len(plan)
    # Every command is accounted for; one the loop had no time to send before the next came
    # (superseded) or before it was too old (stale) is dropped, as on a loaded host it may be.
    assert status["sent"] + status["superseded"] + status["stale"] == len(plan), status
    assert status["not_newer"] + status["future"] + status["out_of_range"] == 0, status
    assert status["sent"] >= 0.9 * len(plan), status
    health = got["health"][-1]
    assert health["connected"] and health["lost_frames"] == 0 and health["fc_drops"] == 0
