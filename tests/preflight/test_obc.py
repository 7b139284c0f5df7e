"""The OBC player on the wire, against a stand-in FSP port (scaffolding): what each behaviour
writes — fresh commands numbered and stamped, the last packet again, older ones, garbage, a
new numbering, a twin, a clock step, a value out of range, a timed command — and what it
reads back by the FC clock; a lost link is one error naming the port; a guard stops it."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from tests.preflight.fsp_stand_in import FspStandIn
from wftool.errors import PortError, UsageError
from wftool.fsp.decoder import CommandDecoder
from wftool.fsp.packets import UplinkFlag
from wftool.preflight.obc import README_COMMAND, Obc

COMMAND = (1400, 1600, 1450, 1000, 2000, 2000)


@pytest.fixture
def fc() -> Iterator[FspStandIn]:
    with FspStandIn() as stand_in:
        yield stand_in


def until(condition, timeout: float = 5.0) -> None:  # type: ignore[no-untyped-def]
    """Wait for the stand-in (another thread, which notifies nobody) to show `condition`."""
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "the stand-in never showed it"
        time.sleep(0.01)


def test_fresh_commands_are_numbered_and_stamped_and_answered(fc: FspStandIn) -> None:
    with Obc(fc.url) as obc:
        obc.behave("fresh", COMMAND)
        until(lambda: len(fc.commands) >= 5)
        last = obc.behave("stopped")
        assert last is not None and last.packet.rc == COMMAND
        taken = obc.taken_us(last)
        assert taken is not None  # its time reply, by the stand-in's clock
        frame = obc.frame_after(taken - 5000, lambda f: f.rc == COMMAND, 2.0)
        assert frame is not None and frame.sticks == COMMAND[:4]
    seqs = [command.seq for command in fc.commands]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    stamps = [command.tx_time_us for command in fc.commands]
    assert stamps == sorted(stamps) and (stamps[-1] - stamps[0]) / 1e4 / (len(stamps) - 1) > 0.8


def test_stuck_replay_and_garbage_send_nothing_new(fc: FspStandIn) -> None:
    with Obc(fc.url) as obc:
        obc.behave("fresh", COMMAND)
        until(lambda: len(fc.commands) >= 10)
        last = obc.behave("stuck")
        assert last is not None
        # Every fresh command was written before `last`: once it is in, so are they (a loaded
        # host's stand-in reads late; those still on their way are fresh all the same).
        until(lambda: any(c.seq == last.packet.seq for c in fc.commands))
        fresh = {(c.seq, c.tx_time_us) for c in fc.commands}
        stuck = len(fc.commands)
        until(lambda: len(fc.commands) >= stuck + 5)
        assert all(c.seq == last.packet.seq for c in fc.commands[stuck - 1 :])
        obc.behave("replay")
        until(lambda: len(fc.commands) >= 25)
        assert all((c.seq, c.tx_time_us) in fresh for c in fc.commands)
        assert any(c.seq < last.packet.seq for c in fc.commands[-5:])
        obc.behave("garbage")
        size = len(fc.received)
        until(lambda: len(fc.received) > size + 300)
        decoder = CommandDecoder()
        assert decoder.feed(b"\0" + bytes(fc.received[size:])) == []
        assert sum(decoder.rejected.values()) >= 10


def test_a_restart_a_twin_and_a_clock_step(fc: FspStandIn) -> None:
    with Obc(fc.url) as obc:
        obc.behave("fresh", COMMAND)
        until(lambda: len(fc.commands) >= 5)
        old = obc.restart(README_COMMAND)
        assert old is not None
        until(lambda: fc.commands[-1].rc == README_COMMAND and len(fc.commands) > 8)
        first = next(c for c in fc.commands if c.rc == README_COMMAND)
        assert first.seq == 0 < old.packet.seq  # a new program numbers from the start
        other = (1500, 1500, 1500, 1100, 1000, 1000)
        count = len(fc.commands)
        obc.twin(other)
        until(lambda: len(fc.commands) > count + 10)
        obc.twin(None)
        twins = [c for c in fc.commands[count:] if c.rc == other]
        mine = [c for c in fc.commands[count:] if c.rc == README_COMMAND]
        assert twins and mine and twins[0].sender != mine[0].sender
        assert any(c.seq == twins[0].seq - 1 for c in mine)  # just ahead: a program started before
        before = obc.step_clock(-5.0, COMMAND)  # the last command stamped before the step
        assert before is not None
        until(lambda: obc.last_fresh is not None and obc.last_fresh.packet.seq > before.packet.seq)
        after = obc.last_fresh
        until(lambda: after.packet in fc.commands)  # the FC took it as it was written
        assert after.packet.rc == COMMAND
        # On the wire the stamp went back 5 s, less the host time between the two writes
        # (however long a loaded host took to write the next one)
        went_back_s = (before.packet.tx_time_us - after.packet.tx_time_us) % 2**32 * 1e-6
        assert went_back_s + (after.written - before.written) == pytest.approx(5.0, abs=0.1)


def test_one_command_out_of_range_or_timed(fc: FspStandIn) -> None:
    with Obc(fc.url) as obc:
        bad = (1500, 1500, 1500, 2215, 1000, 1000)
        with pytest.raises(ValueError):
            obc.send_once((1500, 1500, 1500, 2300, 1000, 1000))  # the sender refuses it
        sent = obc.send_once(bad, unchecked=True)
        timed = obc.send_once(COMMAND, at_us=123_456)
        until(lambda: len(fc.commands) >= 2)
        assert fc.commands[0].rc == bad and fc.commands[0].seq == sent.packet.seq
        assert fc.commands[1].at_us == 123_456 and fc.commands[1].seq == timed.packet.seq


def test_every_uplink_status_is_kept(fc: FspStandIn) -> None:
    """Two statuses in one read: the decoder keeps the newest only; the player keeps both."""
    with Obc(fc.url) as obc:
        start = obc.statuses.end
        fc.status(UplinkFlag.LIVE)
        fc.status(0, timeouts=1)
        gone = obc.statuses.wait(lambda s: s.timeouts == 1, start, 5.0)
        assert gone is not None
        assert [s.flags for s in obc.statuses.since(start)] == [UplinkFlag.LIVE, 0]


def test_killed_the_port_closes_and_another_connection_reads_on(fc: FspStandIn) -> None:
    with Obc(fc.url) as obc:
        obc.behave("fresh", COMMAND)
        until(lambda: len(fc.commands) >= 3)
        last = obc.kill()
        assert last is not None and obc.taken_us(last) is not None  # answered before it closed
        until(lambda: fc.connections == 2)
        count = len(fc.commands)
        start = obc.frames.end
        assert obc.frames.wait(lambda f: True, start, 2.0) is not None  # reading on
        assert len(fc.commands) == count  # silent


def test_a_lost_link_is_one_error_naming_the_port(fc: FspStandIn) -> None:
    obc = Obc(fc.url).start()
    try:
        obc.behave("fresh", COMMAND)
        until(lambda: len(fc.commands) >= 3)
        fc.hang_up()
        with pytest.raises(PortError, match=f"^{fc.url}: the FSP link was lost mid-run"):
            obc.frames.wait(lambda f: False, obc.frames.end, 10.0)
        with pytest.raises(PortError, match=f"^{fc.url}"):
            obc.behave("stopped")
    finally:
        obc.stop()


def test_the_guard_stops_every_write(fc: FspStandIn) -> None:
    allowed = True

    def guard() -> None:
        if not allowed:
            raise UsageError("armed")

    with Obc(fc.url, guard=guard) as obc:
        obc.behave("fresh", COMMAND)
        until(lambda: len(fc.commands) >= 3)
        allowed = False
        with pytest.raises(UsageError, match="armed"):
            obc.frames.wait(lambda f: False, obc.frames.end, 5.0)
        count = len(fc.received)
        time.sleep(0.1)
        assert len(fc.received) == count


def test_a_stall_of_its_own_thread_is_recorded(fc: FspStandIn) -> None:
    stalled = [False]

    def guard() -> None:  # called before each write: once, the thread sleeps
        if not stalled[0] and len(fc.commands) >= 3:
            stalled[0] = True
            time.sleep(0.06)

    with Obc(fc.url, guard=guard) as obc:
        obc.behave("fresh", COMMAND)
        stall = obc.stalls.wait(lambda gap: True, 0, 5.0)
        assert stall is not None and stall >= 0.06  # written late, and so taken late
        obc.behave("stopped")
        stalls = obc.stalls.end
        time.sleep(0.5)
        obc.behave("fresh", COMMAND)  # a pause it meant is no stall
        until(lambda: len(fc.commands) >= 15)
        assert max(obc.stalls.since(stalls), default=0.0) < 0.4


def test_commands_the_fc_took_late_are_a_stall_too(fc: FspStandIn) -> None:
    """Written on time, taken late (the FC's time replies): the link stalled."""
    with Obc(fc.url) as obc:
        obc.behave("fresh", COMMAND)
        until(lambda: len(fc.commands) >= 3)
        fc.pause(0.08)
        stall = obc.stalls.wait(lambda gap: True, 0, 5.0)
        assert stall is not None and stall >= 0.07
        stalls = obc.stalls.end
        fc.pause(0.5)  # the old program's last and the new one's first commands taken late:
        obc.restart(COMMAND)  # a new program, a new link, no stall across the two
        until(lambda: len(fc.commands) >= 20)
        assert max(obc.stalls.since(stalls), default=0.0) < 0.4
