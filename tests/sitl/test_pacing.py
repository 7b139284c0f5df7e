"""The virtual FC's UARTs as wires (`VirtualBoard(uart_pacing=True)`): each moves its bytes at
its baud rate in FC time, 10 bits a byte, both ways.

Judged against the SITL's true clock (`TrueClock`, the lockstep anchors) where the FC stamps
something: an FSP packet reaches the OBC no sooner than its wire time after its newest frame
was sampled, and the FC receives a command no sooner than its wire time after it was sent.
MSP replies carry no FC time: four asked for at once arrive one after another, a reply's
wire time apart, instead of together.
"""

from __future__ import annotations

import socket
import statistics
import time
from pathlib import Path

from tests.sitl.fresh import send_fresh
from wftool.fc.msp import MspClient
from wftool.fsp import DEFAULT_BAUDRATE, FspReader, StateDecoder, StatePacket
from wftool.fsp.encoder import encode_command
from wftool.fsp.packets import COMMAND_LENGTH, STATE_LENGTH, CommandPacket
from wftool.sitl.process import LOOPBACK, VirtualBoard
from wftool.sitl.session import VirtualFcSession
from wftool.sitl.truth import TrueClock

PACED = VirtualBoard(uart_pacing=True)
BITS_PER_BYTE = 10
COMMAND = (1500, 1500, 1500, 1000, 1000, 1000)
MSP_BAUD = 115200
MSP_RAW_IMU = 102
RAW_IMU_REPLY = 6 + 18
"""An MSPv1 reply: `$M>`, length, command, 9 × int16, checksum."""
MEASURED = 100
BURSTS = 9
ANSWERED_MIN = 95


def wire_s(nbytes: int, baud: int) -> float:
    return nbytes * BITS_PER_BYTE / baud


def test_an_fsp_packet_arrives_its_wire_time_after_its_newest_sample(
    sitl_binary: Path, tmp_path: Path
) -> None:
    packets: list[StatePacket] = []
    with VirtualFcSession(sitl_binary, tmp_path, port_base=None, board=PACED) as fc:
        with FspReader(fc.fsp_url) as reader:
            until = time.monotonic() + 3.0
            while time.monotonic() < until:
                packets.extend(reader.read(0.05))
        truth = TrueClock(fc.fc.log_path)
    assert len(packets) > 1000
    delays = [p.arrival_time - truth.instant(p.frames[-1].time_us) for p in packets[1:]]
    # COBS adds at least one byte, the delimiter another; micros() truncates by < 1 µs
    assert min(delays) >= wire_s(STATE_LENGTH + 2, DEFAULT_BAUDRATE) - 1e-6


def test_the_fc_receives_a_command_its_wire_time_after_it_was_sent(
    sitl_binary: Path, tmp_path: Path
) -> None:
    """Measured on MEASURED commands the FC took fresh, by its own report, each sent alone
    (tests/sitl/fresh.py): a loaded host delays the SITL's TCP reader while FC time goes on,
    and commands a host period apart then reach the FC in bursts, and after timeouts (one
    full run: 48 replies to 100 commands sent 20 ms apart)."""
    session = VirtualFcSession(sitl_binary, tmp_path, port_base=None, board=PACED, time_reply=True)
    with session, FspReader(session.fsp_url, decoder=StateDecoder("twoway")) as reader:
        fates = send_fresh(reader, COMMAND, MEASURED)
        truth = TrueClock(session.fc.log_path)
    status = reader.uplink_status
    assert status is not None and status.rejected == 0
    assert fates.answered >= ANSWERED_MIN
    wire = len(encode_command(CommandPacket(COMMAND)))
    assert wire >= COMMAND_LENGTH + 2
    waits = [truth.instant(trip.fc_received_us) - trip.obc_sent for trip in fates.trips]
    assert min(waits) >= wire_s(wire, DEFAULT_BAUDRATE) - 1e-6


def test_msp_replies_asked_for_at_once_arrive_one_after_another(
    sitl_binary: Path, tmp_path: Path
) -> None:
    """Each of BURSTS bursts: three replies' wire times between the first and the last, where
    unpaced all four come within two serial task periods (0.5 ms each). A host late for one
    reply moves its arrival, and that burst's span with it (one full run: 2.1 ms, the reader or
    the FC 4 ms late at the first; with both cores busy, 2 bursts of 20 under 4 ms); the FC
    paces every burst alike, so the median span is the FC's."""
    request = bytes([*b"$M<", 0, MSP_RAW_IMU, MSP_RAW_IMU])  # checksum: length ^ command
    session = VirtualFcSession(
        sitl_binary, tmp_path, port_base=None, board=PACED, msp_baud=MSP_BAUD
    )
    spans = []
    with session:
        with MspClient.open(session.msp_url) as msp:
            assert msp.pid_cycle_us() > 0  # the FC answers at the new baud rate
        host, port = session.msp_url.removeprefix("socket://").rsplit(":", 1)
        assert host == LOOPBACK
        with socket.create_connection((host, int(port)), timeout=2) as link:
            for _ in range(BURSTS):
                link.sendall(request * 4)
                received, done = b"", []
                while len(done) < 4:
                    received += link.recv(4096)
                    while len(received) >= RAW_IMU_REPLY * (len(done) + 1):
                        done.append(time.monotonic())
                assert len(received) == 4 * RAW_IMU_REPLY
                assert received[:3] == b"$M>" and received[4] == MSP_RAW_IMU
                spans.append(done[-1] - done[0])
    assert statistics.median(spans) >= 2 * wire_s(RAW_IMU_REPLY, MSP_BAUD), spans
