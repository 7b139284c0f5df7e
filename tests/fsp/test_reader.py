"""FspReader over a real TCP connection (pyserial `socket://`), the way it reads the SITL."""

from __future__ import annotations

import re
import socket
import threading
import time
from collections.abc import Iterator

import pytest

from tests.fsp.test_decoder import PERIOD, stream
from tests.fsp.test_timed import locked_decoder, obc_of
from wftool.errors import ClockError, PortError, UsageError
from wftool.fsp import (
    ArmingAction,
    ArmingRequest,
    Authority,
    AuthorityExit,
    CommandDecoder,
    CommandPacket,
    CommandSender,
    FspPort,
    FspReader,
    StateDecoder,
    UplinkStatus,
    encode_command,
    encode_uplink_status,
)
from wftool.fsp.packets import TimeReply
from wftool.fsp.twoway import RoundTripRejection


@pytest.fixture
def server() -> Iterator[socket.socket]:
    listener = socket.create_server(("127.0.0.1", 0))
    yield listener
    listener.close()


def url_of(listener: socket.socket) -> str:
    return f"socket://127.0.0.1:{listener.getsockname()[1]}"


def test_sends_commands_then_reads_frames(server):
    wire = stream(range(200), e1=True)
    received = CommandDecoder()
    commands = []

    def fc() -> None:
        conn, _ = server.accept()
        with conn:
            conn.settimeout(5.0)
            while len(commands) < 3:  # pyserial flushes input on open: talk once it is up
                commands.extend(received.feed(conn.recv(100)))
            for start in range(0, len(wire), 1000):
                conn.sendall(wire[start : start + 1000])
                time.sleep(0.002)
            conn.recv(1)  # hold the line until the reader is done

    thread = threading.Thread(target=fc)
    thread.start()
    with FspReader(url_of(server)) as reader:
        for throttle in (1000, 1100, 1200):
            reader.send_command((1500, 1500, 1500, throttle, 1000, 2000))
        frames = []
        for frame in reader.frames():
            frames.append(frame)
            if len(frames) == 400:
                break
    thread.join(5)
    assert [c.rc[3] for c in commands] == [1000, 1100, 1200]
    assert [c.seq for c in commands] == [0, 1, 2]
    assert [f.sample_time_us for f in frames] == [1_000_000 + i * 953 for i in range(400)]
    assert all(f.obc_time is not None for f in frames)
    assert reader.decoder.stats.lost_packets == 0


def test_port_that_vanishes_raises_port_error(server):
    def fc() -> None:
        conn, _ = server.accept()
        time.sleep(0.2)
        conn.close()

    threading.Thread(target=fc).start()
    with FspReader(url_of(server)) as reader, pytest.raises(PortError, match="lost connection"):
        for _ in range(100):
            reader.read(0.5)


def test_port_that_cannot_open_raises_port_error(server):
    url = url_of(server)
    server.close()
    with pytest.raises(PortError, match="cannot open"):
        FspReader(url).open()
    with pytest.raises(PortError, match="cannot open"):
        FspReader("/dev/does-not-exist").open()


NEUTRAL = (1500, 1500, 1500, 1000, 1000, 1000)


@pytest.mark.parametrize(
    ("rc", "error"),
    [
        ((-32768, 1500, 1500, 1000, 1000, 1000), "RC roll -32768 µs is outside Betaflight's "
         "pulse range 750..2250 µs"),
        ((1500, -1, 1500, 1000, 1000, 1000), "RC pitch -1 µs is outside"),
        ((1500, 1500, 0, 1000, 1000, 1000), "RC yaw 0 µs is outside"),
        ((1500, 1500, 1500, 749, 1000, 1000), "RC throttle 749 µs is outside"),
        ((1500, 1500, 1500, 1000, 2251, 1000), "RC aux3 2251 µs is outside"),
        ((1500, 1500, 1500, 1000, 1000, True), "RC aux4 must be an int (µs), not bool True"),
        ((1500.0, 1500, 1500, 1000, 1000, 1000), "RC roll must be an int (µs), not float"),
        ((b"\x05", 1500, 1500, 1000, 1000, 1000), "RC roll must be an int (µs), not bytes"),
        (bytes(range(1, 7)), "RC values are a sequence of 6 ints, not bytes"),
        ("150015", "RC values are a sequence of 6 ints, not str"),
        ((1500,) * 5, "a command carries 6 RC values"),
    ],
)  # fmt: skip
def test_rc_values_outside_the_pulse_range_never_leave_the_obc(rc, error):
    received = CommandDecoder()
    with FspReader("loop://", decoder=StateDecoder("twoway")) as reader:  # loop: what is sent
        with pytest.raises((TypeError, ValueError), match=re.escape(error)):
            reader.send_command(rc, now=1.0)
        assert reader.port.read(100) == b""  # nothing was sent
        sent = reader.send_command(NEUTRAL, now=2.0)
        commands = received.feed(reader.port.read(100))
        round_trips = reader.decoder.round_trips
        assert round_trips is not None
        assert round_trips.match(TimeReply(0, 1_000_000, 0, 0)) is None  # no trace of it
        assert round_trips.rejected[RoundTripRejection.UNMATCHED] == 1
    assert (sent.seq, [(c.seq, c.rc) for c in commands]) == (0, [(0, NEUTRAL)])


def test_the_pulse_range_ends_are_sent():
    received = CommandDecoder()
    with FspReader("loop://") as reader:
        reader.send_command((750, 2250, 750, 2250, 750, 2250))
        commands = received.feed(reader.port.read(100))
    assert [c.rc for c in commands] == [(750, 2250, 750, 2250, 750, 2250)]


def test_a_timed_command_goes_out_for_the_fc_time_of_its_obc_instant():
    received = CommandDecoder()
    decoder = locked_decoder()
    first_tx = 1_000_000 + PERIOD + 100
    with FspReader("loop://", decoder=decoder) as reader:
        sent = reader.send_command(NEUTRAL, now=107.0, at=obc_of(9_000_000, first_tx))
        reader.send_command(NEUTRAL, now=107.001)
        commands = received.feed(reader.port.read(100))
    assert sent.at_us is not None and abs(sent.at_us - 9_000_000) <= 1
    assert [(c.seq, c.at_us) for c in commands] == [(0, sent.at_us), (1, None)]
    assert len(encode_command(sent)) == 30  # 28 bytes, COBS and the delimiter


def test_no_timed_command_leaves_before_the_clock_locks():
    received = CommandDecoder()
    with FspReader("loop://") as reader:
        with pytest.raises(ClockError, match="not locked"):
            reader.send_command(NEUTRAL, now=1.0, at=1.005)
        assert reader.port.read(100) == b""  # nothing sent, nothing counted
        assert reader.send_command(NEUTRAL, now=1.01).seq == 0
        assert [c.at_us for c in received.feed(reader.port.read(100))] == [None]


def test_a_port_alone_needs_a_decoder_for_a_timed_command():
    with FspPort("loop://") as port:
        with pytest.raises(UsageError, match="decoder"):
            port.send_command(NEUTRAL, at=1.0)
        packet = port.send_command(NEUTRAL, now=107.0, at=107.5, decoder=locked_decoder())
        assert packet.at_us is not None


def fc_status(rc_min_us: int, rc_max_us: int) -> bytes:
    """Wire bytes of an uplink status of the FC (spec §12) reporting its pulse range."""
    return encode_uplink_status(
        UplinkStatus(
            0, 2_000_000, 0, 0, 0, 0, 50, 0, 0, 0, Authority.PILOT, AuthorityExit.NONE, 500, 0,
            0, 0, 0, 0, rc_min_us, rc_max_us,
        )
    )  # fmt: skip


@pytest.mark.parametrize("kind", [FspPort, FspReader])
def test_a_port_checks_commands_against_the_pulse_range_its_fc_reports(kind):
    """Nothing to do for the user: the FC's statuses on the port set the range (loop://
    reads back what is written: here, what an FC would send)."""
    received = CommandDecoder()
    with kind("loop://") as port:
        port.send_command((1500, 1500, 1500, 2200, 1500, 1500))  # Betaflight's widest: no status
        port.port.write(stream(range(2), e1=True) + fc_status(1000, 2000) + stream([2], e1=True))
        while port.uplink_status is None:
            (port.read if isinstance(port, FspReader) else port.read_bytes)(0.1)
        assert port.sender.pulse_range == (1000, 2000)
        with pytest.raises(ValueError, match=r"throttle 2001 µs .* FC's pulse range 1000\.\.2000"):
            port.send_command((1500, 1500, 1500, 2001, 1500, 1500))
        port.send_command(NEUTRAL)
        commands = received.feed(port.port.read(200))
    assert [(c.seq, c.rc[3]) for c in commands] == [(1, 1000)]  # the refused one never left


def test_a_port_arms_and_disarms_as_its_commands_sender():
    received = CommandDecoder()
    with FspPort("loop://") as port:
        port.send_command(NEUTRAL, now=1.0)
        arm = port.send_arming(ArmingAction.ARM, now=1.01)
        port.send_arming(ArmingAction.DISARM, now=1.02)
        packets = received.feed(port.port.read(200))
    assert packets == [
        CommandPacket(NEUTRAL, 0, 1_000_000, None, port.sender.sender),
        ArmingRequest(ArmingAction.ARM, 1, 1_010_000, port.sender.sender),
        ArmingRequest(ArmingAction.DISARM, 2, 1_020_000, port.sender.sender),
    ]
    assert arm == packets[1]


def test_a_sender_given_to_ports_keeps_its_identity_and_sequence_across_them():
    """A program reconnecting is the same sender (spec §11); a new port is a new one."""
    sender = CommandSender()
    with FspPort("loop://", sender=sender) as port:
        first = port.send_command(NEUTRAL)
    with FspPort("loop://", sender=sender) as port:
        again = port.send_command(NEUTRAL)
    with FspPort("loop://") as port:
        other = port.send_command(NEUTRAL)
    assert (first.sender, again.sender, again.seq) == (sender.sender, sender.sender, 1)
    assert other.sender != sender.sender and other.seq == 0
