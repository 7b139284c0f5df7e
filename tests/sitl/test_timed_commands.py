"""Timed commands (E4) on the real firmware (the patched SITL, the OBC flying alone).

Each command acts at its FC time: the FC's own report says which PID iteration applied it,
within one PID period of the time asked for, and the stream shows its RC value from then on,
never before. Late and too-far commands are counted; a stuck OBC repeating a timed packet, a
command far in the future, a flood of them, and an OBC that dies with commands queued never
keep the aircraft under OBC control past the timeout. A firmware built without E4 rejects a
timed command by its length and never applies it.

Times are the FC's own (E2 replies, E3 statuses, E4 reports, frame sample times): the host's
are a loaded machine's.
"""

from __future__ import annotations

import random
import shutil
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from tests.waits import wait_for
from wftool.fc.msp import MspClient
from wftool.firmware import BuildOptions, build
from wftool.firmware.manifest import BuildFlags
from wftool.firmware.project import Project
from wftool.fsp import (
    CommandOutcome,
    CommandPacket,
    CommandReport,
    FspReader,
    StateDecoder,
    UplinkFlag,
    UplinkStatus,
    encode_command,
)
from wftool.fsp.twoway import RoundTrip, TwoWayClockEstimator
from wftool.sitl.session import VirtualFcSession

TIMEOUT_US = 50_000
"""The FC's fsp_cmd_timeout_ms (the default)."""
NEVER_S = 5.0
"""The FC reports a timed command once it acts or is refused, and its counts every 100 ms."""
RELOCK_S = 30.0
"""Only bounds "never": the clock locks again from the frames alone, in seconds."""
LEAD_S = 0.020
"""How far ahead of its instant the OBC sends a command: more than its link's worst delay, as
an OBC should lead. Here the link is the host's scheduler, which a loaded host stretches to
several ms (with 5 ms, 38 of 300 commands came late in a full suite run on a loaded host)."""
APART_S = 1e-5
"""Commands written together are stamped this far apart: a `tx_time_us` ahead whatever the
rounding."""


class TimedObc:
    """wftool as an OBC sending timed commands, reading everything the FC says."""

    def __init__(self, url: str) -> None:
        self.decoder = StateDecoder("twoway")
        assert self.decoder.round_trips is not None
        self.decoder.round_trips.on_round_trip = self._answered
        self.reader = FspReader(url, decoder=self.decoder).open()
        self.reports: dict[int, CommandReport] = {}
        """By seq."""
        self.frames: list[tuple[int, int]] = []
        """(FC time, roll) of every frame."""
        self.statuses: list[UplinkStatus] = []
        self.taken_us: dict[int, int] = {}
        """seq → FC time the FC took the command (its time reply)."""
        self.newest_taken_us = 0
        """FC time the FC took the newest command `lock()` sent."""
        self._seq_of: dict[float, int] = {}
        self._rng = random.Random(7)

    def close(self) -> None:
        self.reader.close()

    def _answered(self, trip: RoundTrip) -> None:
        seq = self._seq_of.get(trip.obc_sent)
        if seq is not None:
            self.taken_us[seq] = trip.fc_received_us

    def pump(self, seconds: float) -> None:
        until = time.monotonic() + seconds
        while (left := until - time.monotonic()) > 0:
            self.read(min(left, 0.001))

    def read(self, timeout: float) -> None:
        data = self.reader.read_bytes(timeout)
        if data:
            for packet in self.decoder.feed(data, time.monotonic()):
                self.frames += [(f.time_us or 0, f.rc[0]) for f in packet.frames]
            for report in self.decoder.take_command_reports():
                self.reports[report.command_seq] = report
            status = self.decoder.uplink_status
            if status is not None and (not self.statuses or self.statuses[-1] is not status):
                self.statuses.append(status)

    def send(self, roll: int, at: float | None = None) -> CommandPacket:
        now = time.monotonic()
        packet = self.reader.send_command((roll, 1500, 1500, 1000, 1000, 1000), now, at=at)
        self._seq_of[now] = packet.seq
        return packet

    def latest_fc_us(self) -> int:
        """The FC time of the newest frame read."""
        self.read(0.0)
        assert self.frames, "no frame read yet"
        return self.frames[-1][0]

    def send_at_fc(self, roll: int, after_us: int, since_us: int | None = None) -> CommandPacket:
        """A timed command due `after_us` after FC time `since_us` (default: the newest
        frame's): in the FC's own clock, whatever the OBC's clock makes of it (a loaded host's
        virtual FC re-anchors its lockstep clock, a step the OBC's clock learns only later)."""
        packet = self.at_fc(roll, after_us, since_us)
        self.reader.port.write(encode_command(packet))
        return packet

    def at_fc(
        self, roll: int, after_us: int, since_us: int | None = None, now: float | None = None
    ) -> CommandPacket:
        """`send_at_fc`'s command, not sent (stamped `now`, default: now)."""
        since_us = self.latest_fc_us() if since_us is None else since_us
        at_us = (since_us + after_us) & 0xFFFFFFFF
        return self.reader.sender.next((roll, 1500, 1500, 1000, 1000, 1000), now, at_us=at_us)

    def pump_until(self, condition: Callable[[], bool], never_s: float = NEVER_S) -> bool:
        """Read until `condition()` holds: whether it did within `never_s` (a bound on
        "never")."""
        return wait_for(lambda: condition() or self.pump(0.01), never_s, poll=0.0)

    def lock(self) -> None:
        """Immediate commands at about 100 Hz until the two-way clock is in use and the FC
        has answered the newest (it took it fresh, at `taken_us`)."""
        clock = self.decoder.clock
        assert isinstance(clock, TwoWayClockEstimator)
        deadline = time.monotonic() + 60.0
        newest = None
        while not (clock.state.locked and clock.two_way.active and newest in self.taken_us):
            assert time.monotonic() < deadline, (
                f"the two-way clock never locked: {clock.state}; {clock.two_way}"
            )
            newest = self.send(1500).seq
            self.pump(self._rng.uniform(0.005, 0.015))
        self.newest_taken_us = self.taken_us[newest]

    def books(self) -> UplinkStatus:
        """The FC's books once its link to the OBC has timed out after the newest command
        `lock()` sent: the uplink status it sends then counts every packet sent so far, and
        the next packet starts a new link (it is stale: the candidate, spec §11)."""

        def ended() -> UplinkStatus | None:
            status = self.decoder.uplink_status
            timed_out = status is not None and status.timed_out_at_us is not None
            return status if timed_out and status.timed_out_at_us > self.newest_taken_us else None

        assert self.pump_until(lambda: ended() is not None), "the OBC's link never timed out"
        status = ended()
        assert status is not None
        return status

    def stream(self, count: int, rate_hz: float, lead_s: float, roll: Callable[[int], int]):
        """`count` timed commands at `rate_hz`, each sent `lead_s` before its instant; the
        packets sent. A host that kept the OBC from sending one `lead_s` ahead moves the
        schedule on from then, as an OBC sends no command for an instant it has missed (sent
        at once after a stall of 0.46 s, 40 of 300 were expired on arrival); one whose clock
        unlocked (the virtual FC re-anchored) sends again once it has locked again (the
        stream raised `ClockError` in a loaded full run)."""
        sent = []
        slot = time.monotonic() + lead_s
        for k in range(count):
            while (left := slot - lead_s - time.monotonic()) > 0:
                self.read(min(left, 0.0005))
            if not self.decoder.clock_state.locked:  # a re-anchor: no FC time to send for
                assert self.pump_until(lambda: self.decoder.clock_state.locked, RELOCK_S), (
                    f"the FC clock did not lock again: {self.decoder.clock_state}"
                )
            slot = max(slot, time.monotonic() + lead_s)
            sent.append(self.send(roll(k), at=slot + self._rng.uniform(0.0, 0.001)))
            slot += 1 / rate_hz
        return sent

    def wait_reports(self, packets: list[CommandPacket], timeout: float = 2.0) -> None:
        deadline = time.monotonic() + timeout
        while any(p.seq not in self.reports for p in packets) and time.monotonic() < deadline:
            self.pump(0.01)

    def rolls(self) -> set[int]:
        return {roll for _, roll in self.frames}

    def first_status(self, holds: Callable[[UplinkStatus], bool], after_us: int) -> int | None:
        """FC time of the first uplink status after `after_us` for which `holds`."""
        times = [
            s.sent_us for s in self.statuses if s.sent_us and s.sent_us > after_us and holds(s)
        ]
        return min(times, default=None)


@pytest.fixture(scope="module")
def alone(sitl_binary: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple]:
    """A virtual FC the OBC flies alone (RX_MSP), with time replies, and its PID period."""
    workdir = tmp_path_factory.mktemp("timed")
    with VirtualFcSession(sitl_binary, workdir, port_base=None, time_reply=True) as fc:
        with MspClient.open(fc.msp_url) as msp:
            pid_us = msp.pid_looptime_us()
        yield fc, pid_us


@pytest.fixture
def obc(alone: tuple) -> Iterator[TimedObc]:
    fc, _ = alone
    link = TimedObc(fc.fsp_url)
    try:
        link.lock()
        yield link
    finally:
        link.pump(0.1)  # what it queued has acted or expired before the next test
        link.close()


def test_timed_commands_act_at_their_fc_time_within_one_pid_period(alone, obc) -> None:
    """Every timed command the FC takes fresh is reported on; one it does not (the first after
    a gap of more than `fsp_cmd_timeout_ms` by its clock only starts a new link, spec §11) is
    counted stale in its uplink status (E3). The stream starts such a link: it is sent once
    the FC has timed out the link `lock()` used, so the FC's books before it are that
    timeout's status."""
    _, pid_us = alone
    before = obc.books()
    sent = obc.stream(300, 100.0, LEAD_S, roll=lambda k: 1100 + k)

    def books() -> tuple[int, int]:  # the FC's books of the stream: fresh, stale
        status = obc.decoder.uplink_status
        assert status is not None
        return status.accepted - before.accepted, status.stale - before.stale

    def reported() -> list[CommandReport]:
        return [obc.reports[p.seq] for p in sent if p.seq in obc.reports]

    obc.pump_until(lambda: sum(books()) >= len(sent) and len(reported()) >= books()[0])
    obc.pump(0.05)
    taken, stale = books()
    reports = reported()
    newest = max(reports, key=lambda r: r.event_time_us or 0, default=None)
    assert (len(reports), len(sent) - len(reports)) == (taken, stale), (
        "every timed command is reported on or counted stale; not reported: "
        f"{[p.seq for p in sent if p.seq not in obc.reports]}; the FC's books: {taken} fresh, "
        f"{stale} stale, at the newest report {newest and newest.counts}; the stream: "
        f"{obc.decoder.stats}"
    )
    on_time = [r for r in reports if r.outcome == CommandOutcome.ON_TIME]
    late = [r for r in reports if r.outcome == CommandOutcome.LATE]
    assert len(on_time) >= 0.9 * len(reports), [CommandOutcome(r.outcome).name for r in reports]
    # None refused; one the FC dropped was superseded by a newer one it applied at the same
    # PID iteration (several due at one iteration: a loaded host's virtual FC read them in one
    # FSP task run, after their time), or expired: due after the FC timed the OBC out (spec
    # §13), as the FC reports when a loaded host kept the OBC from sending for the timeout.
    order = {p.seq: k for k, p in enumerate(sent)}
    applied_at = {r.event_time_us: order[r.command_seq] for r in on_time + late}
    superseded = [r for r in reports if r.outcome == CommandOutcome.SUPERSEDED]
    for report in superseded:
        newer = applied_at.get(report.event_time_us)
        assert newer is not None and newer > order[report.command_seq], report
    others = [r for r in reports if r not in on_time and r not in late and r not in superseded]
    assert all(r.outcome == CommandOutcome.EXPIRED for r in others), others
    status = obc.decoder.uplink_status
    timed_out = status is not None and status.timeouts > before.timeouts
    assert not others or timed_out, (others, before, status)
    for report in on_time:
        assert report.delay_us is not None and 0 <= report.delay_us < pid_us, report
    # the stream shows each value from the PID iteration that applied it on, never before,
    # and never one the FC did not apply
    rolls = obc.rolls()
    for packet in sent:
        report = obc.reports.get(packet.seq)
        if report is None or report not in on_time + late:
            assert packet.rc[0] not in rolls, (packet, report)
            continue
        assert report.event_time_us is not None
        shown = [t for t, roll in obc.frames if roll == packet.rc[0]]
        assert shown, f"roll {packet.rc[0]} never in the stream"
        assert min(shown) >= report.event_time_us, (min(shown), report)


def test_late_expired_and_too_far_commands_are_counted(obc: TimedObc) -> None:
    """Late by less than the command timeout (50 ms): applied at once; by the timeout or
    more: expired on arrival, never applied (spec §13); due the timeout or more ahead:
    refused."""
    # All in one write, after an immediate command that opens a link if the one `lock()` used
    # timed out: a loaded host that held the test between writes for the command timeout
    # (50 ms) had the next taken only as a new link's first, and reported on never (spec §11).
    now = time.monotonic()  # each stamped APART_S after the one before: ahead of it (spec §11)
    opener = obc.reader.sender.next((1500, 1500, 1500, 1000, 1000, 1000), now)
    stale = obc.at_fc(1304, -80_000, now=now + APART_S)
    far = obc.at_fc(1302, 200_000, now=now + 2 * APART_S)  # beyond the 50 ms timeout
    past = obc.at_fc(1301, -20_000, now=now + 3 * APART_S)  # acts at once
    gone = obc.at_fc(1303, round(LEAD_S * 1e6), now=now + 4 * APART_S)
    obc.reader.port.write(b"".join(encode_command(p) for p in (opener, stale, far, past, gone)))
    obc.wait_reports([past, stale, far, gone])
    obc.pump(0.05)
    late, expired, refused, applied = (obc.reports[p.seq] for p in (past, stale, far, gone))
    assert late.outcome == CommandOutcome.LATE and late.delay_us is not None
    assert 10_000 <= late.delay_us <= 30_000 + 1000 * 5  # asked for 20 ms before it came
    assert expired.outcome == CommandOutcome.EXPIRED and expired.delay_us is None
    assert refused.outcome == CommandOutcome.TOO_FAR
    assert applied.outcome == CommandOutcome.ON_TIME
    assert refused.counts[CommandOutcome.TOO_FAR] >= 1
    assert expired.counts[CommandOutcome.EXPIRED] >= 1
    rolls = obc.rolls()
    assert 1301 in rolls and 1304 not in rolls and 1302 not in rolls and 1303 in rolls


def test_an_obc_that_dies_with_commands_queued_is_gone_at_its_last_packets_timeout(
    obc: TimedObc,
) -> None:
    """100 Hz, each command 40 ms ahead; the OBC dies after the last: the queued ones act
    (they were fresh), and the FC's timeout comes 50 ms after the last command arrived,
    not 50 ms after the last one acted."""
    sent = obc.stream(50, 100.0, 0.040, roll=lambda k: 1400 + k)
    last = sent[-1]
    obc.pump(0.3)  # dead: it sends nothing more, and reads what the FC says
    taken = obc.taken_us.get(last.seq)
    assert taken is not None, "the last command was not answered"
    queued = [obc.reports[p.seq] for p in sent[-4:]]
    assert all(r.outcome == CommandOutcome.ON_TIME for r in queued), queued
    assert queued[-1].event_time_us is not None
    assert queued[-1].event_time_us - taken >= 35_000  # acted after the OBC was gone
    status = obc.decoder.uplink_status
    assert status is not None and status.timed_out_at_us is not None
    timed_out = status.timed_out_at_us - taken
    assert TIMEOUT_US <= timed_out <= TIMEOUT_US + 2000, timed_out  # one FSP task period late
    # the OBC flies alone: its receiver's signal ends then too, though a frame came 40 ms later
    lost = obc.first_status(lambda s: s.has(UplinkFlag.RX_LOSS), after_us=taken)
    assert lost is not None and lost - taken <= TIMEOUT_US + 2000, lost - taken
    assert not status.has(UplinkFlag.LIVE)


def test_a_stuck_obc_repeating_a_timed_packet_acts_once(obc: TimedObc) -> None:
    obc.stream(20, 100.0, LEAD_S, roll=lambda k: 1500)
    packet = obc.send(1555, at=time.monotonic() + LEAD_S)
    before = obc.decoder.uplink_status
    assert before is not None
    wire = encode_command(packet)
    for _ in range(50):  # the same bytes at 100 Hz for half a second
        obc.reader.port.write(wire)
        obc.pump(0.01)
    obc.pump(0.1)
    report = obc.reports[packet.seq]
    assert report.outcome == CommandOutcome.ON_TIME
    status = obc.decoder.uplink_status
    assert status is not None and status.stale - before.stale >= 45
    taken = obc.taken_us[packet.seq]
    assert status.timed_out_at_us is not None
    assert TIMEOUT_US <= status.timed_out_at_us - taken <= TIMEOUT_US + 2000
    lost = obc.first_status(lambda s: s.has(UplinkFlag.RX_LOSS), after_us=taken)
    assert lost is not None and lost - taken <= TIMEOUT_US + 2000, lost - taken  # then failsafe


def test_a_far_future_command_never_acts(obc: TimedObc) -> None:
    far = obc.send(1666, at=time.monotonic() + 30.0)
    obc.wait_reports([far])
    obc.pump(0.1)
    assert obc.reports[far.seq].outcome == CommandOutcome.TOO_FAR
    assert 1666 not in obc.rolls()


def test_a_flood_fills_the_queue_and_the_rest_is_refused(obc: TimedObc) -> None:
    # in one burst, each due 1.2 ms after the one before (a frame shows each), the last
    # 45 ms ahead: the FC takes four a run, applies them as they fall due
    now_us = obc.latest_fc_us()  # in the FC's clock, as the late ones above
    flood = [obc.send_at_fc(1700 + k, 10_000 + 1200 * k, now_us) for k in range(30)]
    obc.wait_reports(flood)
    obc.pump(0.05)
    outcomes = [CommandOutcome(obc.reports[p.seq].outcome) for p in flood]
    applied = [p for p, o in zip(flood, outcomes, strict=True) if o == CommandOutcome.ON_TIME]
    refused = outcomes.count(CommandOutcome.QUEUE_FULL)
    assert refused >= 1 and len(applied) + refused == len(flood), outcomes
    assert len(applied) >= 8  # the queue's eight, and what came after room was made
    assert {p.rc[0] for p in applied} <= obc.rolls()
    last = obc.reports[flood[-1].seq]
    assert last.counts[CommandOutcome.QUEUE_FULL] >= refused


# -- a firmware without E4 ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def without_e4(
    fresh_clone: Project, sitl_build, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Path]:
    """The SITL built with -DFSP_NO_TIMED_COMMANDS, copied aside (the clone's build output
    is switched back to the default build after)."""
    flagged = build(
        fresh_clone,
        "sitl",
        BuildOptions(jobs=2, flags=BuildFlags(defines=("FSP_NO_TIMED_COMMANDS",))),
    )
    binary = tmp_path_factory.mktemp("no-e4") / flagged.firmware.name
    shutil.copy2(flagged.firmware, binary)
    build(fresh_clone, "sitl", BuildOptions(jobs=2))
    yield binary


def test_a_firmware_without_timed_commands_rejects_them_and_never_applies_them(
    without_e4: Path, tmp_path: Path
) -> None:
    with VirtualFcSession(without_e4, tmp_path, port_base=None, time_reply=True) as fc:
        obc = TimedObc(fc.fsp_url)
        try:
            obc.lock()
            before = obc.decoder.uplink_status
            assert before is not None
            sent = obc.stream(50, 100.0, LEAD_S, roll=lambda k: 1800 + k)
            obc.pump(0.3)
            status = obc.decoder.uplink_status
            assert status is not None
            assert status.rejected - before.rejected == len(sent)  # by length, each of them
            assert status.command_seq < sent[0].seq  # the newest fresh: an immediate one
            assert not obc.reports  # no command report: the FC knows none
            assert not {1800 + k for k in range(50)} & obc.rolls()
            # the immediate commands before were the last to steer: the uplink timed out
            assert status.timed_out_at_us is not None and status.has(UplinkFlag.RX_LOSS)
        finally:
            obc.close()
