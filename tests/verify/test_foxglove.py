"""The live Foxglove view, seen by a WebSocket client speaking the Foxglove protocol.

The client is the `websockets` package plus the protocol as documented (serverInfo and
advertise as JSON, subscribe, binary message data); schemas are parsed and messages
decoded by rosbags. Nothing of wftool's encoding is used on the receiving side.
"""

from __future__ import annotations

import base64
import contextlib
import fcntl
import json
import os
import shutil
import socket
import struct
import subprocess
import sys
import threading
import time
from contextlib import ExitStack

import pytest

pytest.importorskip("foxglove", reason="needs the Foxglove SDK: pip install 'wftool[foxglove]'")

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from tests.recording.test_rosbag import assert_imu_matches, decoded_frames, flight, stamp_of
from wftool.errors import UsageError
from wftool.fsp import UplinkStatus
from wftool.recording.events import StreamHealth, UplinkReport
from wftool.recording.ros2msg import WFTOOL_MSGS
from wftool.verify.foxglove import TOPICS, FoxgloveLive, exposure_warning
from wftool.verify.viewer_gate import GateLimits

SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01
WAIT_S = 10.0


class Viewer:
    """A protocol client: subscribes to every advertised channel, decodes what arrives."""

    def __init__(self, url: str, max_queue: int | None = 16) -> None:
        self._stack = ExitStack()
        self.ws: ClientConnection = self._stack.enter_context(
            connect(url, subprotocols=[SUBPROTOCOL], max_queue=max_queue)
        )
        assert self.ws.subprotocol == SUBPROTOCOL
        info = json.loads(self.ws.recv(timeout=WAIT_S))
        assert info["op"] == "serverInfo"
        self.channels: dict[int, dict] = {}
        while len(self.channels) < len(TOPICS):
            message = json.loads(self.ws.recv(timeout=WAIT_S))
            if message["op"] == "advertise":
                self.channels.update({c["id"]: c for c in message["channels"]})
        self.store = get_typestore(Stores.EMPTY)
        for channel in self.channels.values():
            assert (channel["encoding"], channel["schemaEncoding"]) == ("cdr", "ros2msg")
            self.store.register(get_types_from_msg(channel["schema"], channel["schemaName"]))
        self.topic_of = {index: c["topic"] for index, c in enumerate(self.channels.values())}
        self.ws.send(
            json.dumps(
                {
                    "op": "subscribe",
                    "subscriptions": [
                        {"id": index, "channelId": channel_id}
                        for index, channel_id in enumerate(self.channels)
                    ],
                }
            )
        )
        self.type_of = {c["topic"]: c["schemaName"] for c in self.channels.values()}

    def close(self) -> None:
        self._stack.close()

    def receive(self, count: int) -> dict[str, list[tuple[int, object]]]:
        """`count` messages by topic: (timestamp, decoded message)."""
        topics: dict[str, list] = {}
        for _ in range(count):
            data = self.ws.recv(timeout=WAIT_S)
            while isinstance(data, str):  # status and other JSON ops
                data = self.ws.recv(timeout=WAIT_S)
            opcode, subscription, timestamp = struct.unpack_from("<BIQ", data)
            assert opcode == MESSAGE_DATA
            topic = self.topic_of[subscription]
            message = self.store.deserialize_cdr(bytes(data[13:]), self.type_of[topic])
            topics.setdefault(topic, []).append((timestamp, message))
        return topics


def wait_subscribed(live: FoxgloveLive, topics: set[str]) -> None:
    deadline = time.monotonic() + WAIT_S
    while live.subscribed_topics() != topics:
        assert time.monotonic() < deadline, live.subscribed_topics()
        time.sleep(0.01)


def test_viewer_receives_what_was_published():
    frames = decoded_frames(flight(100))  # 200 frames with OBC times
    uplink = [  # the FC's statuses: none yet, commands flying, then timed out
        None,
        UplinkReport(UplinkStatus(1, 10, 1, 0, 0, 0, 50, 0b10011, 0), 5000.5, None),
        UplinkReport(UplinkStatus(9, 90, 9, 1, 1, 0, 50, 0b10010, 0, 70), 5001.5, 5001.25),
    ]
    health = [
        StreamHealth(5000.0 + i, i, 0, True, i > 0, True, 2 * i, 4 * i, 0, 0, i, 0, 0, 0, uplink[i])
        for i in range(3)
    ]
    with FoxgloveLive(port=0) as live:
        assert live.url.startswith("ws://127.0.0.1:")  # localhost unless told otherwise
        viewer = Viewer(live.url)
        for channel in viewer.channels.values():  # served as the wftool_msgs package has them
            package, _, name = channel["schemaName"].split("/")
            if package == "wftool_msgs":
                definition = channel["schema"].split("=" * 80 + "\nMSG: ")[0]
                assert definition == (WFTOOL_MSGS / "msg" / f"{name}.msg").read_text(), name
        wait_subscribed(live, set(TOPICS))
        for index, frame in enumerate(frames):
            live.publish(frame, health[index * len(health) // len(frames)])
        battery_count = 1 + int((frames[-1].obc_time - frames[0].obc_time) / 0.1)
        received = viewer.receive(4 * len(frames) + battery_count + len(health) + 2)
        viewer.close()
    offset = live._encoder.wall_offset_ns
    stamps = [offset + int(f.obc_time * 1e9) for f in frames]
    imu = received["/fsp/imu"]
    assert [t for t, _ in imu] == [stamp_of(m) for _, m in imu] == stamps
    for frame, (_, message) in zip(frames, imu):
        assert_imu_matches(message, frame)
    for frame, (_, message) in zip(frames, received["/fsp/attitude"], strict=True):
        angles = (message.roll_deg, message.pitch_deg, message.yaw_deg)
        assert angles == pytest.approx(frame.euler_deg, nan_ok=True)  # NaN: no attitude
    for frame, (_, message) in zip(frames, received["/fsp/rc"], strict=True):
        assert (message.roll, message.throttle, message.aux4) == (
            frame.rc[0], frame.rc[3], frame.rc[5]
        )  # fmt: skip
    for frame, (_, message) in zip(frames, received["/fsp/rpm"], strict=True):
        assert tuple(message.rpm) == frame.rpm
    battery = received["/fsp/battery"]
    assert len(battery) == battery_count
    assert battery[0][1].voltage == pytest.approx(frames[0].vbat / 100)
    assert [(m.seq, m.fc_drops, m.clock_locked) for _, m in received["/fsp/health"]] == [
        (h.seq, h.fc_drops, h.clock_locked) for h in health
    ]
    statuses = received["/fsp/uplink_status"]
    assert [(t, m.accepted, m.live, m.override, m.armed, m.timeouts) for t, m in statuses] == [
        (offset + int(5000.5e9), 1, True, True, True, 0),
        (offset + int(5001.5e9), 9, False, True, True, 1),
    ]
    assert stamp_of(statuses[1][1]) == offset + int(5001.5e9)


def _rss_bytes() -> int:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * 4096


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc/self/statm")
def test_a_stuck_viewer_never_holds_up_publishing():
    frames = decoded_frames(flight(500))
    rounds = 60  # 60 000 frames, 240 000+ messages, ~40 MB of CDR
    with FoxgloveLive(port=0, backlog=64) as live:
        stuck = Viewer(live.url, max_queue=1)  # subscribes, then never reads again
        wait_subscribed(live, set(TOPICS))
        rss_before = _rss_bytes()
        done = threading.Event()

        def flood() -> None:
            for _ in range(rounds):
                for frame in frames:
                    live.publish(frame)
            done.set()

        publisher = threading.Thread(target=flood, daemon=True)
        publisher.start()
        publisher.join(120.0)  # a guard against a hang, not a speed target
        assert done.is_set(), "publish() blocked behind a stuck viewer"
        growth = _rss_bytes() - rss_before
        assert growth < 16 * 2**20, f"memory grew by {growth / 2**20:.1f} MiB"

        # The server is still live for others: a new viewer gets fresh messages. (The stuck
        # viewer's subscriptions already count as sinks, so when the new one's subscription
        # takes effect cannot be waited for: publish until it receives. Its queue is
        # unbounded, so that it reads on and sees the server's close without waiting.)
        fresh = Viewer(live.url, max_queue=None)
        trickling = threading.Event()

        def trickle() -> None:
            while not trickling.wait(0.05):
                for frame in frames[:20]:
                    live.publish(frame)

        threading.Thread(target=trickle, daemon=True).start()
        try:
            assert len(fresh.receive(40)["/fsp/imu"]) >= 5
        finally:
            trickling.set()
        fresh.close()

        # What the stuck viewer finally gets is what fit in the loopback socket buffers (a few
        # MB, in the kernel) and its queue: a small part. The rest was dropped.
        got = 0
        try:
            while True:
                data = stuck.ws.recv(timeout=1.0)
                got += not isinstance(data, str)
        except (TimeoutError, ConnectionClosed):
            pass
        published = rounds * len(frames) * 4
        assert got < published / 4, (got, published)
        stuck.close()


def test_taken_port_is_a_one_line_usage_error():
    with FoxgloveLive(port=0) as live, pytest.raises(UsageError, match="cannot serve Foxglove"):
        FoxgloveLive(port=live.port)


def test_missing_sdk_names_the_extra(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setitem(sys.modules, "foxglove", None)  # import foxglove now fails
    with pytest.raises(UsageError, match=r"wftool\[foxglove\]"):
        FoxgloveLive(port=0)


def _handshake(port: int, host: str = "127.0.0.1") -> socket.socket:
    """A raw connection that has done the WebSocket handshake and sent nothing else."""
    sock = socket.create_connection((host, port), timeout=WAIT_S)
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall(
        f"GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
        f"Sec-WebSocket-Protocol: {SUBPROTOCOL}\r\n\r\n".encode()
    )
    response = b""
    while b"\r\n\r\n" not in response:
        response += sock.recv(4096)
    assert response.startswith(b"HTTP/1.1 101"), response
    return sock


def _closed(sock: socket.socket, within_s: float) -> bool:
    """Whether the peer closes `sock` within `within_s` (what it sends meanwhile is read)."""
    sock.settimeout(within_s)
    deadline = time.monotonic() + within_s
    try:
        while time.monotonic() < deadline:
            if not sock.recv(1 << 16):
                return True
    except TimeoutError:
        return False
    except OSError:  # reset
        return True
    return False


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc/self/statm")
def test_an_unfinished_viewer_message_costs_little_and_ends_the_viewer():
    """Viewers sending a message in fragments that never ends: the server held each whole
    (~60 MB a viewer). A viewer's message may be 64 KiB; past that it is dropped."""
    with FoxgloveLive(port=0) as live:
        rss_before = _rss_bytes()
        dropped_after = []
        for _ in range(4):
            sock = _handshake(live.port)
            sent, fragment = 0, 1 << 20
            with contextlib.suppress(OSError):
                while sent < 24 * fragment:  # masked with key 0: the payload as sent
                    opcode = 0x00 if sent else 0x01  # text, then continuations, no FIN
                    header = bytes([opcode, 0x80 | 127]) + struct.pack(">Q", fragment)
                    sock.sendall(header + bytes(4) + b"x" * fragment)
                    sent += fragment
            dropped_after.append(sent)
            assert _closed(sock, WAIT_S)
            sock.close()
        growth = _rss_bytes() - rss_before
        assert max(dropped_after) < 8 * fragment, dropped_after
        assert growth < 16 * 2**20, f"memory grew by {growth / 2**20:.1f} MiB"
        viewer = Viewer(live.url)  # the server serves on
        wait_subscribed(live, set(TOPICS))
        viewer.close()


def test_connections_that_never_handshake_are_dropped_and_bounded():
    limits = GateLimits(handshake_s=1.0)  # (10 s by default)
    with FoxgloveLive(port=0, limits=limits) as live:
        socks = [
            socket.create_connection(("127.0.0.1", live.port)) for _ in range(limits.viewers + 8)
        ]
        started = time.monotonic()
        over = socks[limits.viewers :]
        assert all(_closed(sock, 2.0) for sock in over), "connections past the limit stay open"
        held = socks[: limits.viewers]
        wait = limits.handshake_s + 2.0 - (time.monotonic() - started)
        assert all(_closed(sock, max(wait, 0.1)) for sock in held), "half-open ones stay"
        for sock in socks:
            sock.close()
        viewer = Viewer(live.url)  # and a real viewer gets in
        wait_subscribed(live, set(TOPICS))
        viewer.close()


def test_the_servers_log_never_blocks_it(tmp_path):
    """Failed handshakes make the SDK log a line each; with stderr a pipe nobody reads, the
    writes blocked and the server stopped taking viewers (after ~1,300 with a 64 KiB pipe)."""
    log, log_end = os.pipe()
    with contextlib.suppress(AttributeError, OSError):  # Linux: a pipe of one page fills sooner
        fcntl.fcntl(log_end, fcntl.F_SETPIPE_SZ, 4096)
    capacity = fcntl.fcntl(log_end, fcntl.F_GETPIPE_SZ) if hasattr(fcntl, "F_GETPIPE_SZ") else 65536
    server = subprocess.Popen(
        [sys.executable, "-c", SERVE_FOREVER], stdout=subprocess.PIPE, stderr=log_end
    )
    os.close(log_end)
    try:
        port = int(server.stdout.readline())
        for _ in range(2 * capacity // 40):  # 40 bytes of log each at least: twice the pipe
            with socket.create_connection(("127.0.0.1", port), timeout=WAIT_S) as sock:
                sock.sendall(
                    b"GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\n"
                    b"Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                    b"Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: none\r\n\r\n"
                )
                sock.recv(4096)
        viewer = Viewer(f"ws://127.0.0.1:{port}")
        viewer.close()
    finally:
        server.kill()
        server.wait()
    with open(log, "rb") as stderr:
        assert stderr.read(200).startswith(b"foxglove: Dropping client 127.0.0.1:")


SERVE_FOREVER = """
import time
from wftool.verify.foxglove import FoxgloveLive
live = FoxgloveLive(port=0)
print(live.port, flush=True)
while True:
    time.sleep(1)
"""


@pytest.mark.parametrize(
    ("host", "exposed"),
    [("127.0.0.1", False), ("localhost", False), ("::1", False), ("0.0.0.0", True),
     ("::", True)],
)  # fmt: skip
def test_serving_beyond_localhost_is_said_first(host, exposed):
    warning = exposure_warning(host, 8765)
    assert (warning is not None) == exposed
    if exposed:
        assert warning == (
            f"warning: the Foxglove view on {host}:8765 serves the live stream to anyone who "
            "can reach this machine, without authentication"
        )


VANISHING_VIEWER = """
import json, sys, time
from websockets.sync.client import connect
with connect(sys.argv[1], subprotocols=["foxglove.sdk.v1"]) as ws:
    channels = []
    while len(channels) < int(sys.argv[2]):
        message = ws.recv(timeout=10)
        if isinstance(message, str) and json.loads(message)["op"] == "advertise":
            channels += json.loads(message)["channels"]
    ws.send(json.dumps({"op": "subscribe", "subscriptions": [
        {"id": i, "channelId": c["id"]} for i, c in enumerate(channels)]}))
    print("subscribed", flush=True)
    time.sleep(600)
"""


@pytest.fixture
def second_host(tmp_path):
    """A network namespace behind a veth pair: (our address, its name). Its link can be cut
    so that it vanishes without a FIN or RST, as a viewer on a dead Wi-Fi does."""
    if os.geteuid() != 0 or not shutil.which("ip"):
        pytest.skip("needs root and iproute2 for a network namespace")
    name = f"wfgate{os.getpid() % 100000}"
    ours, theirs = f"{name}a", f"{name}b"
    subnet = f"10.{200 + os.getpid() % 50}.{os.getpid() % 250}"

    def ip(*args: str) -> None:
        subprocess.run(["ip", *args], check=True, capture_output=True)

    ip("netns", "add", name)
    try:
        ip("link", "add", ours, "type", "veth", "peer", "name", theirs, "netns", name)
        ip("addr", "add", f"{subnet}.1/30", "dev", ours)
        ip("link", "set", ours, "up")
        ip("-n", name, "addr", "add", f"{subnet}.2/30", "dev", theirs)
        ip("-n", name, "link", "set", theirs, "up")
        yield f"{subnet}.1", name, theirs
    finally:
        subprocess.run(["ip", "netns", "del", name], capture_output=True)
        subprocess.run(["ip", "link", "del", ours], capture_output=True)


def test_a_viewer_whose_host_vanished_is_dropped(second_host):
    address, namespace, link = second_host
    limits = GateLimits(keepalive_s=(1, 1, 2), user_timeout_s=3)
    with FoxgloveLive(port=0, host=address, limits=limits) as live:
        viewer = subprocess.Popen(
            ["ip", "netns", "exec", namespace, sys.executable, "-c", VANISHING_VIEWER,
             f"ws://{address}:{live.port}", str(len(TOPICS))],
            stdout=subprocess.PIPE, env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
        )  # fmt: skip
        try:
            assert viewer.stdout.readline() == b"subscribed\n"
            wait_subscribed(live, set(TOPICS))
            subprocess.run(["ip", "-n", namespace, "link", "set", link, "down"], check=True)
            deadline = time.monotonic() + 15  # keepalive: 1 s idle + 2 probes 1 s apart
            while live.subscribed_topics() and time.monotonic() < deadline:
                time.sleep(0.1)
            assert live.subscribed_topics() == set(), "a viewer that vanished is kept"
        finally:
            viewer.kill()
            viewer.wait()
