"""The virtual FC's simulated radio, heard on a UDP socket as SITL's RC input hears it."""

from __future__ import annotations

import ctypes
import itertools
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import pytest

from wftool.fsp import Authority, AuthorityExit, UplinkFlag, UplinkStatus
from wftool.sitl.radio import (
    _RC_PACKET,
    HIGH,
    LOW,
    MID,
    RX_LOSS_MS,
    STALL_S,
    SYNC_S,
    EngagingPilot,
    SimulatedRadio,
    channel_index,
)


@pytest.fixture
def rc_input() -> Iterator[socket.socket]:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(2.0)
        yield sock


def frame(sock: socket.socket) -> tuple[float, tuple[int, ...]]:
    """The next frame: the transmitter's clock (s), the channels."""
    sent, *channels = _RC_PACKET.unpack(sock.recv(_RC_PACKET.size))
    return sent, tuple(channels)


def test_frames_come_at_the_rate_and_carry_what_was_set(rc_input: socket.socket) -> None:
    with SimulatedRadio(rc_input.getsockname()[1], rate_hz=100.0) as radio:
        _, channels = frame(rc_input)
        assert channels[channel_index("roll")] == MID
        radio.set(roll=1234, aux2=2000)
        for _ in range(100):  # up to a second of frames: the transmitter takes the new values
            _, channels = frame(rc_input)
            if channels[channel_index("roll")] != MID:
                break
        assert channels[channel_index("roll")] == 1234 and channels[channel_index("aux2")] == 2000
        assert radio.channels == channels
        times = [frame(rc_input)[0] for _ in range(50)]
        gaps = [b - a for a, b in itertools.pairwise(times)]
        assert sum(gaps) / len(gaps) == pytest.approx(0.010, abs=0.001)


def test_a_transmitter_off_is_silent_until_on_again(rc_input: socket.socket) -> None:
    with SimulatedRadio(rc_input.getsockname()[1]) as radio:
        frame(rc_input)
        radio.transmitting(False)
        rc_input.settimeout(5 * radio.frame_period_s)
        with pytest.raises(TimeoutError):  # what was on its way, until the transmitter is off
            for _ in range(200):
                rc_input.recv(_RC_PACKET.size)
        rc_input.settimeout(0.3)
        with pytest.raises(TimeoutError):
            rc_input.recv(_RC_PACKET.size)
        radio.transmitting(True)
        rc_input.settimeout(1.0)
        frame(rc_input)


def test_the_radio_keeps_sending_while_its_holder_stalls(rc_input: socket.socket) -> None:
    """A radio does not stall when the program holding it does: one C call holding the
    interpreter's lock for 0.3 s (as a garbage collection late in a long session can) left
    the FC without frames past its 150 ms RX loss limit when the radio was a thread."""
    with SimulatedRadio(rc_input.getsockname()[1]) as radio:
        times = [frame(rc_input)[0]]
        start = time.monotonic()
        ctypes.PyDLL(None).usleep(300_000)  # a C call that keeps the lock (PyDLL: no release)
        stalled = time.monotonic() - start
        while times[-1] < times[0] + stalled + radio.frame_period_s:  # its frames past the stall
            times.append(frame(rc_input)[0])
    assert stalled > RX_LOSS_MS / 1e3, "the stall was too short to tell"
    # Frames all through the stall, none missing long enough for the FC's RX loss: the gaps
    # are the host's scheduling of a process of its own (up to ~60 ms at load 8 on two
    # cores), never the holder's stall.
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert max(gaps) < RX_LOSS_MS / 1e3, (max(gaps), stalled)


def test_a_transmitter_its_host_stalled_says_so_and_one_taken_away_does_not(
    rc_input: socket.socket,
) -> None:
    """A gap between frames long enough for the FC's RX loss, which nobody meant (the host
    stopped the transmitter), is reported with its length; the radio switched off is not."""
    with SimulatedRadio(rc_input.getsockname()[1]) as radio:
        assert radio._process is not None
        start = time.monotonic()
        frame(rc_input)
        radio.transmitting(False)
        time.sleep(2 * STALL_S)
        radio.transmitting(True)
        frame(rc_input)
        os.kill(radio._process.pid, signal.SIGSTOP)  # the host does not run it
        time.sleep(2 * STALL_S)
        os.kill(radio._process.pid, signal.SIGCONT)
        frame(rc_input)
        stalls = radio.stalls_since(start)  # the answer waits for the report
        assert len(stalls) == 1 and 2 * STALL_S <= stalls[0] < 2 * STALL_S + 1.0, stalls
        assert radio.stalls_since(time.monotonic()) == []


def test_a_stall_going_on_when_asked_is_in_the_answer(rc_input: socket.socket) -> None:
    """Asked while its host has stopped it, the transmitter answers once it runs again, its
    stall in the answer; stopped for longer than `SYNC_S`, the answer counts the wait."""
    with SimulatedRadio(rc_input.getsockname()[1]) as radio:
        assert radio._process is not None
        pid = radio._process.pid
        start = time.monotonic()
        frame(rc_input)
        os.kill(pid, signal.SIGSTOP)
        resume = threading.Timer(2 * STALL_S, os.kill, (pid, signal.SIGCONT))
        resume.start()
        stalls = radio.stalls_since(start)
        resume.join()
        assert len(stalls) == 1 and 2 * STALL_S <= stalls[0] < SYNC_S, stalls

        start = time.monotonic()
        os.kill(pid, signal.SIGSTOP)
        try:
            stalls = radio.stalls_since(start)
        finally:
            os.kill(pid, signal.SIGCONT)
        assert len(stalls) == 1 and stalls[0] >= SYNC_S, stalls
        frame(rc_input)
        assert max(radio.stalls_since(start)) >= SYNC_S


def test_the_transmitter_ends_when_its_holder_is_killed(rc_input: socket.socket) -> None:
    port = rc_input.getsockname()[1]
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import sys, time\nfrom wftool.sitl.radio import SimulatedRadio\n"
         f"radio = SimulatedRadio({port}).start()\n"
         "print(radio._process.pid, flush=True)\ntime.sleep(60)\n"],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert holder.stdout is not None
    transmitter = int(holder.stdout.readline())
    frame(rc_input)
    os.kill(holder.pid, signal.SIGKILL)
    holder.wait()
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        try:
            os.kill(transmitter, 0)
        except ProcessLookupError:
            break
        time.sleep(0.02)
    else:
        pytest.fail("the transmitter outlived the program holding it")


def test_a_held_switch_goes_out_held_however_late_the_transmitter_runs(
    rc_input: socket.socket,
) -> None:
    """A switch turned off for three frames and at once on again, while the host does not run
    the transmitter: the off goes out in three frames, then the on; values set without a hold
    in the meantime go out as the newest only (no burst of stale frames)."""
    switch, roll = channel_index("aux2"), channel_index("roll")
    with SimulatedRadio(rc_input.getsockname()[1]) as radio:
        radio.set(aux2=HIGH)
        while frame(rc_input)[1][switch] != HIGH:
            pass
        assert radio._process is not None
        os.kill(radio._process.pid, signal.SIGSTOP)  # the host runs it late
        try:
            radio.set(roll=1100)
            radio.set(roll=1200, aux2=LOW, hold_frames=3)
            radio.set(aux2=HIGH)
            radio.set(roll=1300)
            radio.set(roll=1400)
        finally:
            os.kill(radio._process.pid, signal.SIGCONT)
        sent: list[tuple[int, int]] = []
        while not sent or sent[-1] != (1400, HIGH):
            channels = frame(rc_input)[1]
            sent.append((channels[roll], channels[switch]))
    while sent[0] == (MID, HIGH):  # what went out before it was stopped
        sent.pop(0)
    assert sent == [(1200, LOW)] * 3 + [(1400, HIGH)]


def status(
    authority: Authority, arrival: float, exit: AuthorityExit = AuthorityExit.NONE,
    override: bool = True,
) -> UplinkStatus:  # fmt: skip
    """The FC's uplink status saying who flies, read at OBC time `arrival`, and whether its
    override switch is on."""
    flags = UplinkFlag.LIVE | (UplinkFlag.OVERRIDE if override else 0)
    reported = UplinkStatus(
        1, 0, 1, 0, 0, 0, 50, flags, 0, 0, authority, exit, 500, 0, 7, 0, 0, 0, 885, 2115
    )
    reported.arrival_time = arrival
    return reported


def test_the_pilot_engages_when_the_fc_says_ready_and_says_so(rc_input: socket.socket) -> None:
    """Ready with the switch on (on before): off, and on once a status read after shows it
    off; PROVING engages nothing; a status still showing it off, however late it is read, is
    one from before the FC read it on; the pilot says when the OBC steers and when it lost
    the sticks, and why."""
    said: list[str] = []
    clock = [100.0]
    with SimulatedRadio(rc_input.getsockname()[1]) as radio:
        pilot = EngagingPilot(radio, 2, say=said.append, now=lambda: clock[0])
        switch = channel_index("aux2")
        radio.set(aux2=HIGH)  # on before the OBC was ready: engages nothing
        pilot.observe(None)
        pilot.observe(status(Authority.PROVING, 100.0))
        assert radio.channels[switch] == HIGH and pilot.engagements == 0
        pilot.observe(status(Authority.READY, 100.0))
        assert radio.channels[switch] == LOW
        clock[0] += 0.05
        pilot.observe(status(Authority.READY, 100.0, override=False))  # read before the off
        pilot.observe(status(Authority.READY, clock[0]))  # the FC has not read it off yet
        pilot.observe(None)
        assert radio.channels[switch] == LOW
        clock[0] += 0.01
        pilot.observe(status(Authority.READY, clock[0], override=False))
        assert radio.channels[switch] == HIGH and pilot.engagements == 1
        clock[0] += 1.0  # a loaded host reads the FC's statuses late
        pilot.observe(status(Authority.READY, clock[0], override=False))
        assert radio.channels[switch] == HIGH and pilot.engagements == 1
        pilot.observe(status(Authority.ENGAGED, clock[0]))
        pilot.observe(status(Authority.PROVING, clock[0], AuthorityExit.TIMEOUT))
        assert radio.channels[switch] == HIGH and pilot.engagements == 1
    assert said == [
        "pilot: the OBC is ready; override switch AUX2 off …",
        "pilot: override switch AUX2 on: engaging the OBC",
        "pilot: the OBC is engaged: it steers the sticks",
        "pilot: the OBC lost the sticks (timeout): the pilot flies",
    ]


def test_a_switch_the_fc_reads_off_is_turned_on_and_a_refused_turn_made_again(
    rc_input: socket.socket,
) -> None:
    """Ready with the switch off as the FC reads it: on at once. Ready with it on after that
    (the FC took the turn while not ready: exit not_ready, spec §15): off and on again."""
    clock = [100.0]
    said: list[str] = []
    with SimulatedRadio(rc_input.getsockname()[1]) as radio:
        pilot = EngagingPilot(radio, 2, say=said.append, now=lambda: clock[0])
        switch = channel_index("aux2")
        pilot.observe(status(Authority.READY, 100.0, override=False))
        assert radio.channels[switch] == HIGH and pilot.engagements == 1
        clock[0] += 0.1
        pilot.observe(status(Authority.READY, clock[0], AuthorityExit.NOT_READY))
        assert radio.channels[switch] == LOW and pilot.engagements == 1
        clock[0] += 0.1
        pilot.observe(status(Authority.READY, clock[0], AuthorityExit.NOT_READY, override=False))
        assert radio.channels[switch] == HIGH and pilot.engagements == 2
    engaging = ["pilot: the OBC is ready; override switch AUX2 off …",
                "pilot: override switch AUX2 on: engaging the OBC"]  # fmt: skip
    assert said == engaging * 2
