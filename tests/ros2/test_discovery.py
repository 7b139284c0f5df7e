"""Who may command the aircraft: a ROS 2 program on another host is not heard by the node
unless the user widens its range. The other host is a network namespace of this test's own,
linked to this one by a veth pair; its program does everything it can to be heard
(discovery on its subnet, and this host's address as a static peer)."""

from __future__ import annotations

import os
import random
import shutil
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.ros2 import peers

pytestmark = pytest.mark.usefixtures("ros2_env")

RC = [1500, 1500, 1500, 1000, 1000, 1000]
NODE_S = 14.0
"""How long the node listens: discovery between two hosts takes well under a second."""


@dataclass(frozen=True)
class OtherHost:
    netns: str
    address: str
    """The other host's address."""
    our_address: str
    """This host's address on the link between them."""

    @property
    def wrapper(self) -> list[str]:
        return ["ip", "netns", "exec", self.netns]


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, timeout=10)


@pytest.fixture
def other_host() -> Iterator[OtherHost]:
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("a second host (a network namespace) needs root and iproute2's ip")
    tag = f"{os.getpid() % 10000}{random.randrange(100)}"
    netns, ours, theirs = f"wfros{tag}", f"wfh{tag}", f"wfn{tag}"
    subnet = f"10.{random.randrange(200, 250)}.{random.randrange(256)}"
    host = OtherHost(netns, f"{subnet}.2", f"{subnet}.1")
    _ip("netns", "add", netns)
    try:
        _ip("link", "add", ours, "type", "veth", "peer", "name", theirs)
        _ip("link", "set", theirs, "netns", netns)
        _ip("addr", "add", f"{host.our_address}/30", "dev", ours)
        _ip("link", "set", ours, "up")
        inside = ("netns", "exec", netns, "ip")
        _ip(*inside, "addr", "add", f"{host.address}/30", "dev", theirs)
        _ip(*inside, "link", "set", theirs, "up")
        _ip(*inside, "link", "set", "lo", "up")
        _ip(*inside, "route", "add", "default", "via", host.our_address)
        yield host
    finally:
        _ip("netns", "del", netns)  # takes the veth pair with it


def _environment(**settings: str | None) -> dict[str, str]:
    env = dict(os.environ)
    for name in (
        "ROS_AUTOMATIC_DISCOVERY_RANGE",
        "ROS_STATIC_PEERS",
        "FASTDDS_DEFAULT_PROFILES_FILE",
    ):
        env.pop(name, None)
    env.update({name: value for name, value in settings.items() if value is not None})
    return env


@pytest.mark.parametrize(
    "node_range, heard",
    [(None, False), ("SUBNET", True)],
    ids=["by default", "widened to the subnet"],
)
def test_a_commander_on_another_host_is_heard_only_when_widened(
    other_host: OtherHost, node_range: str | None, heard: bool, tmp_path: Path
):
    """By default the node neither finds nor hears it: nothing reaches the gate. Widened, the
    same program is heard (so the link works, and the first case means something)."""
    namespace = peers.namespace_of(tmp_path)
    env = _environment(ROS_AUTOMATIC_DISCOVERY_RANGE=node_range)
    attacker = _environment(
        ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET", ROS_STATIC_PEERS=other_host.our_address
    )
    plan = [{"rc": RC, "after_s": 0.02} for _ in range(50)]  # 50 Hz for a second
    with peers.node(namespace, NODE_S, env) as (process, scope):
        assert scope.startswith("this host only" if node_range is None else "the local network")
        started = time.monotonic()
        outcome = peers.command(
            f"{namespace}/fsp/command", plan, NODE_S - 4, wrapper=other_host.wrapper, env=attacker
        )
        assert time.monotonic() - started < NODE_S  # the node was listening all along
        counts = peers.node_counts(process)
    if heard:
        assert outcome == "matched"
        assert counts["received"] > 0 and counts["sent"] > 0
    else:
        assert outcome == "unmatched"
        assert counts["received"] == 0 and counts["sent"] == 0
