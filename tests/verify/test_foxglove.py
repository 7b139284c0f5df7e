"""The live Foxglove view, seen by a WebSocket client speaking the Foxglove protocol.

The client is the `websockets` package plus the protocol as documented (serverInfo and
advertise as JSON, subscribe, binary message data); schemas are parsed and messages
decoded by rosbags. Nothing of wftool's encoding is used on the receiving side.
"""

from __future__ import annotations

import json
import struct
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
from wftool.recording.events import StreamHealth
from wftool.recording.ros2msg import WFTOOL_MSGS
from wftool.verify.foxglove import TOPICS, FoxgloveLive

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
    health = [
        StreamHealth(5000.0 + i, i, 0, True, i > 0, True, 2 * i, 4 * i, 0, 0, i, 0, 0, 0)
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
        received = viewer.receive(4 * len(frames) + battery_count + len(health))
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
        # takes effect cannot be waited for: publish until it receives.)
        fresh = Viewer(live.url)
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
