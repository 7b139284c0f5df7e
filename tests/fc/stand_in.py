"""STAND-INS for an FC's port (not FCs): TCP servers that answer as a test says, for replies
a real FC will not give on request (a PID cycle of 0, a 60 KB MSP payload, a 400 KB `diff
all`). Each serves any number of connections, one after another."""

from __future__ import annotations

import contextlib
import socket
import threading
from collections.abc import Callable, Iterator

from wftool.fc.msp import Cmd, MspVersion, decode_frame, encode_request

Answer = Callable[[bytearray], bytes]
"""What to send for what has arrived; it removes from the buffer what it answered."""


@contextlib.contextmanager
def stand_in(answer: Answer) -> Iterator[str]:
    """Serve `answer` until the block ends; yields the socket:// URL."""
    listener = socket.create_server(("127.0.0.1", 0))
    listener.settimeout(0.1)
    done = threading.Event()

    def serve() -> None:
        while not done.is_set():
            try:
                connection, _ = listener.accept()
            except TimeoutError:
                continue
            with connection:
                connection.settimeout(0.1)
                received = bytearray()
                while not done.is_set():
                    try:
                        data = connection.recv(1 << 16)
                    except TimeoutError:
                        continue
                    if not data:
                        break
                    received += data
                    if reply := answer(received):
                        connection.sendall(reply)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield f"socket://127.0.0.1:{listener.getsockname()[1]}"
    finally:
        done.set()
        thread.join(5)
        listener.close()


def msp_stand_in(payload: Callable[[int], bytes]) -> contextlib.AbstractContextManager[str]:
    """Answers each MSP request (command id) with `payload(command)`, as MSP v2."""

    def answer(received: bytearray) -> bytes:
        frame, used = decode_frame(bytes(received))
        del received[:used]
        if frame is None:
            return b""
        return encode_request(frame.cmd, payload(frame.cmd), MspVersion.V2).replace(b"<", b">", 1)

    return stand_in(answer)


def identity_replies(version: str, api: tuple[int, int]) -> Callable[[int], bytes]:
    """MSP replies of an FC that says it runs Betaflight VERSION with MSP API API (a SITL:
    for firmware that cannot be had here, such as upstream master's)."""
    year, month, patch = (int(part) for part in version.split("."))
    replies = {
        Cmd.API_VERSION: bytes([0, *api]),
        Cmd.FC_VARIANT: b"BTFL",
        Cmd.FC_VERSION: bytes([year - 2000, month, patch, len(version)]) + version.encode(),
        Cmd.BOARD_INFO: b"SITL" + bytes(4) + b"\x04SITL\x00\x00" + bytes(32) + b"\x00",
        Cmd.BUILD_INFO: b"Jan  1 202600:00:00abcdef0",
    }
    return lambda command: replies.get(command, b"")


def cli_stand_in(output: Callable[[str], bytes]) -> contextlib.AbstractContextManager[str]:
    """Answers each command line with its echo, `output(command)` and the prompt."""

    def answer(received: bytearray) -> bytes:
        reply = b""
        while b"\n" in received:
            line, _, rest = bytes(received).partition(b"\n")
            received[:] = rest
            command = line.strip().decode()
            reply += command.encode() + b"\r\n" + output(command) + b"\r\n# "
        return reply

    return stand_in(answer)
