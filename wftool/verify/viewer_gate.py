"""The live view's front door: a process between viewers and the Foxglove server that bounds
what each viewer can cost (docs/ros2.md, "Live view")."""

from __future__ import annotations

import contextlib
import json
import os
import select
import selectors
import socket
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field

from wftool.errors import UsageError


@dataclass(frozen=True)
class GateLimits:
    """What one viewer may cost, and how soon a dead one is dropped."""

    viewers: int = 32
    """Connections at once; more are closed as they come."""
    handshake_s: float = 10.0
    """Time to complete the WebSocket handshake; a connection that does not is dropped."""
    request_bytes: int = 16 << 10
    """The longest handshake request."""
    message_bytes: int = 64 << 10
    """The longest message a viewer may send, its fragments together (subscriptions are a
    few hundred bytes); the server holds an unfinished one whole."""
    buffer_bytes: int = 256 << 10
    """Bytes held for a viewer that reads slowly, here and in each socket buffer between the
    server and the viewer; beyond, the server's own per-viewer queue (which drops the oldest
    messages) holds the rest."""
    stall_s: float = 30.0
    """A viewer that takes nothing for this long while data waits for it is dropped."""
    keepalive_s: tuple[int, int, int] = (10, 5, 3)
    """TCP keepalive: idle seconds, seconds between probes, probes; a viewer whose host
    vanished (no FIN, no RST) is dropped within idle + interval × probes."""
    user_timeout_s: int = 30
    """Data unacknowledged this long: the viewer is gone (TCP_USER_TIMEOUT)."""


_BOOT = (
    "import json, sys; sys.path[:] = json.loads(sys.argv.pop(1)); "
    "from wftool.verify.viewer_gate import serve; sys.exit(serve(sys.argv[1]))"
)
"""The gate's start: with the caller's import path, so it runs the caller's wftool."""
START_S = 10.0
"""How long the gate may take to bind and say so."""


class ViewerGate:
    """The gate process: listens on `host:port` (0: any free port) and relays each viewer to
    the server on 127.0.0.1:`upstream_port`. Ends with `close()`, or when its parent dies."""

    def __init__(
        self, host: str, port: int, upstream_port: int, limits: GateLimits | None = None
    ) -> None:
        config = {"host": host, "port": port, "upstream": upstream_port}
        config.update(asdict(limits or GateLimits()))
        try:
            self._process = subprocess.Popen(
                [sys.executable, "-c", _BOOT, json.dumps(sys.path), json.dumps(config)],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                start_new_session=True,  # out of reach of the terminal's Ctrl-C: ends with us
            )
        except OSError as exc:
            raise UsageError(f"cannot start the Foxglove view's gate: {exc}") from None
        started = _first_line(self._process, START_S)
        if "port" not in started:
            self.close()
            reason = started.get("error", "it did not start")
            raise UsageError(f"cannot serve Foxglove on {host}:{port}: {reason}")
        self.port: int = started["port"]

    def close(self) -> None:
        """Stop relaying: every viewer is disconnected."""
        if self._process.stdin is not None and not self._process.stdin.closed:
            self._process.stdin.close()  # the gate ends when its input does
        try:
            self._process.wait(5.0)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()
        if self._process.stdout is not None:
            self._process.stdout.close()


def _first_line(process: subprocess.Popen, timeout: float) -> dict:
    """The JSON line the gate says it started (or why not) with; {} if it said nothing."""
    stdout = process.stdout
    assert stdout is not None  # started with stdout=PIPE
    ready, _, _ = select.select([stdout], [], [], timeout)
    line = stdout.readline() if ready else b""
    try:
        return json.loads(line) if line else {}
    except ValueError:
        return {}


# -- the gate process -----------------------------------------------------------------------

_HEADER_END = b"\r\n\r\n"
_READ = 1 << 18
_TICK_S = 0.25
"""How often deadlines are looked at."""
_GATHER_S = 0.002
"""A pause after each round, so that what the server writes message by message is relayed
some messages at a time: one viewer of 4 kHz frames (16,000 messages/s) cost the gate 8.6 %
of a core with a round per message, 1 % so. A viewer sees the stream later by as much."""


@dataclass
class _Frames:
    """The client's WebSocket frames, read as they pass: a message longer than `limit`
    (its fragments together) is a violation. Nothing is kept but the header being read."""

    limit: int
    header: bytearray = field(default_factory=bytearray)
    remaining: int = 0
    """Payload bytes of the current frame still to pass."""
    message: int = 0
    """Bytes of the data message being sent in fragments."""

    def passes(self, data: bytes) -> bool:
        """Whether `data` keeps within the limit."""
        position = 0
        while position < len(data):
            if self.remaining:
                step = min(self.remaining, len(data) - position)
                self.remaining -= step
                position += step
                continue
            self.header.append(data[position])
            position += 1
            size = self._frame_size()
            if size is None:
                continue
            first = self.header[0]
            fin, opcode = first & 0x80, first & 0x0F
            self.header.clear()
            if opcode & 0x08:  # a control frame: at most 125 bytes, never fragmented
                if size > 125:
                    return False
            else:
                self.message = size if opcode else self.message + size
                if self.message > self.limit:
                    return False
                if fin:
                    self.message = 0
            self.remaining = size
        return True

    def _frame_size(self) -> int | None:
        """The payload size once the header is whole (with its mask key), else None."""
        header = self.header
        if len(header) < 2:
            return None
        size, masked = header[1] & 0x7F, header[1] & 0x80
        extended = {126: 2, 127: 8}.get(size, 0)
        if len(header) < 2 + extended + (4 if masked else 0):
            return None
        if extended:
            size = int.from_bytes(header[2 : 2 + extended], "big")
        return size


class _Viewer:
    """One viewer's connection, and its connection to the server once its handshake request
    is whole (the server never sees a connection that does not get that far)."""

    def __init__(self, client: socket.socket, limits: GateLimits) -> None:
        self.client = client
        self.upstream: socket.socket | None = None
        self.limits = limits
        now = time.monotonic()
        self.handshake_until = now + limits.handshake_s
        self.taken_at = now
        """When the client last took bytes (or there were none for it)."""
        self.request = bytearray()
        self.requested = False
        self.response = bytearray()
        self.upgraded = False
        self.frames = _Frames(limits.message_bytes)
        self.to_client = bytearray()
        self.to_upstream = bytearray()
        self.upstream_done = False

    @property
    def sockets(self) -> tuple[socket.socket, ...]:
        return (self.client,) if self.upstream is None else (self.client, self.upstream)

    def from_client(self, data: bytes) -> bool:
        """Take what the client sent; False if it broke a limit."""
        if not self.requested:
            self.request += data
            end = self.request.find(_HEADER_END)
            if end < 0:
                self.to_upstream += data
                return len(self.request) <= self.limits.request_bytes
            self.requested = True
            frames = bytes(self.request[end + len(_HEADER_END) :])
            self.to_upstream += data[: len(data) - len(frames)]
            self.request = bytearray()
            data = frames
        if not self.frames.passes(data):
            return False
        self.to_upstream += data
        return True

    def from_upstream(self, data: bytes) -> None:
        if not self.upgraded:
            self.response += data[: self.limits.request_bytes]
            if _HEADER_END in self.response:
                self.upgraded = self.response.startswith(b"HTTP/1.1 101")
                self.response = bytearray()
        if not self.to_client:
            self.taken_at = time.monotonic()
        self.to_client += data

    def expired(self, now: float) -> bool:
        if not self.upgraded and now > self.handshake_until:
            return True
        return bool(self.to_client) and now - self.taken_at > self.limits.stall_s

    def close(self) -> None:
        for sock in self.sockets:
            sock.close()


def serve(config_text: str) -> int:
    """The gate process: bind, say where (or why not) on stdout, relay until stdin ends."""
    config = json.loads(config_text)
    host, port, upstream_port = config.pop("host"), config.pop("port"), config.pop("upstream")
    config["keepalive_s"] = tuple(config["keepalive_s"])
    limits = GateLimits(**config)
    try:
        listener = _listen(host, port)
    except OSError as exc:
        _say({"error": exc.strerror or str(exc)})
        return 1
    _say({"port": listener.getsockname()[1]})
    selector = selectors.DefaultSelector()
    selector.register(listener, selectors.EVENT_READ, "accept")
    selector.register(sys.stdin.fileno(), selectors.EVENT_READ, "parent")
    viewers: dict[socket.socket, _Viewer] = {}
    """Each viewer under each of its sockets."""
    next_tick = time.monotonic() + _TICK_S
    while True:
        for key, events in selector.select(_TICK_S):
            if key.data == "parent":
                if not os.read(sys.stdin.fileno(), 4096):
                    for viewer in set(viewers.values()):
                        viewer.close()
                    return 0
            elif key.data == "accept":
                _accept(listener, limits, viewers)
            else:
                sock = key.fileobj
                assert isinstance(sock, socket.socket)
                found = viewers.get(sock)
                if found is not None and not _relay(found, sock, events, upstream_port):
                    _drop(found, viewers, selector)
                elif found is not None and found.upstream is not None:
                    viewers[found.upstream] = found
        now = time.monotonic()
        if now >= next_tick:
            next_tick = now + _TICK_S
            for viewer in {v for v in viewers.values() if v.expired(now)}:
                _drop(viewer, viewers, selector)
        for viewer in set(viewers.values()):
            _watch(viewer, selector)
        if viewers:
            time.sleep(_GATHER_S)


def _say(message: dict) -> None:
    sys.stdout.write(json.dumps(message) + "\n")
    sys.stdout.flush()


def _listen(host: str, port: int) -> socket.socket:
    family, _, _, _, address = socket.getaddrinfo(
        host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
    )[0]
    dual = family == socket.AF_INET6 and address[0] == "::" and socket.has_dualstack_ipv6()
    listener = socket.create_server(
        (address[0], port), family=family, backlog=64, dualstack_ipv6=dual
    )
    listener.setblocking(False)
    return listener


def _accept(
    listener: socket.socket, limits: GateLimits, viewers: dict[socket.socket, _Viewer]
) -> None:
    try:
        client, _ = listener.accept()
    except OSError:  # gone before it was taken, or out of descriptors: it is not served
        return
    if len(set(viewers.values())) >= limits.viewers:
        client.close()
        return
    client.setblocking(False)
    client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    # Small socket buffers (no autotuning to megabytes): a slow viewer's backlog stays in
    # the server's queue, which drops the oldest, rather than in buffers that deliver it late.
    client.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, limits.buffer_bytes)
    client.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
    idle, interval, probes = limits.keepalive_s
    for option, value in (
        ("TCP_KEEPIDLE", idle),
        ("TCP_KEEPINTVL", interval),
        ("TCP_KEEPCNT", probes),
        ("TCP_USER_TIMEOUT", limits.user_timeout_s * 1000),
    ):
        if hasattr(socket, option):
            client.setsockopt(socket.IPPROTO_TCP, getattr(socket, option), value)
    viewers[client] = _Viewer(client, limits)


def _connect(viewer: _Viewer, upstream_port: int) -> None:
    """The viewer's connection to the server (on loopback: connecting does not wait)."""
    upstream = socket.create_connection(("127.0.0.1", upstream_port), timeout=2.0)
    upstream.setblocking(False)
    upstream.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    upstream.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, viewer.limits.buffer_bytes)
    viewer.upstream = upstream


def _relay(viewer: _Viewer, sock: socket.socket, events: int, upstream_port: int) -> bool:
    """Move what `sock` has to give, and what waits for either side; False when the viewer
    is done (gone, over a limit, or the server is done with it and all is delivered)."""
    try:
        if events & selectors.EVENT_READ and not _take(viewer, sock):
            return False
        if viewer.requested and viewer.upstream is None:
            _connect(viewer, upstream_port)
        _give(viewer)
    except OSError:  # reset, timed out (keepalive, user timeout), no server: gone
        return False
    return not (viewer.upstream_done and not viewer.to_client)


def _take(viewer: _Viewer, sock: socket.socket) -> bool:
    try:
        data = sock.recv(_READ)
    except (BlockingIOError, InterruptedError):
        return True
    if sock is viewer.client:
        return bool(data) and viewer.from_client(data)
    if data:
        viewer.from_upstream(data)
    else:
        viewer.upstream_done = True
    return True


def _give(viewer: _Viewer) -> None:
    for sock, waiting in ((viewer.client, viewer.to_client), (viewer.upstream, viewer.to_upstream)):
        if sock is None or not waiting:
            continue
        try:
            sent = sock.send(waiting)
        except (BlockingIOError, InterruptedError):
            continue
        del waiting[:sent]
        if sent and sock is viewer.client:
            viewer.taken_at = time.monotonic()


def _watch(viewer: _Viewer, selector: selectors.BaseSelector) -> None:
    """Read from a side only while the other's buffer has room; write while data waits."""
    room = viewer.limits.buffer_bytes
    wants = {
        viewer.client: (selectors.EVENT_READ if len(viewer.to_upstream) < room else 0)
        | (selectors.EVENT_WRITE if viewer.to_client else 0)
    }
    if viewer.upstream is not None:
        reading = len(viewer.to_client) < room and not viewer.upstream_done
        wants[viewer.upstream] = (selectors.EVENT_READ if reading else 0) | (
            selectors.EVENT_WRITE if viewer.to_upstream else 0
        )
    for sock, events in wants.items():
        try:
            current = selector.get_key(sock).events
        except KeyError:
            current = 0
        if events == current:
            continue
        if not events:
            selector.unregister(sock)
        elif current:
            selector.modify(sock, events, "relay")
        else:
            selector.register(sock, events, "relay")


def _drop(
    viewer: _Viewer, viewers: dict[socket.socket, _Viewer], selector: selectors.BaseSelector
) -> None:
    for sock in viewer.sockets:
        viewers.pop(sock, None)
        with contextlib.suppress(KeyError, ValueError):  # not watched at the moment
            selector.unregister(sock)
    viewer.close()
