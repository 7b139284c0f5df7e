"""The command gate: one publisher at a time, only fresh (by the node's monotonic clock),
in-range commands newer than its last pass, each once, and every command offered is counted
by what became of it."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.tiers import examples
from wftool.fsp import ArmingAction, CommandSender
from wftool.fsp.packets import RC_PULSE_US
from wftool.ros2.commands import CommandCounts, CommandGate, Taken

MS = 1_000_000
S = 1000 * MS
RC_MIN, RC_MAX = RC_PULSE_US  # what the library lets a command carry before the FC says
RC = (1500, 1500, 1500, 1000, 1000, 1000)
WALL = 1_700_000_000 * S
"""A publisher's stamps (its ROS clock): only their order counts."""
MONO = 5_000 * S
"""The node's monotonic clock: arrivals and takes."""
A, B = b"publisher-a", b"publisher-b"


def test_a_fresh_command_is_taken_once():
    gate = CommandGate(50 * MS)
    assert gate.offer(RC, WALL, A, MONO) is None
    assert gate.take(MONO + 1 * MS) == Taken(RC)
    gate.sent()
    assert gate.take(MONO + 2 * MS) is None  # never again, however long the sender is silent
    assert gate.take(MONO + 500 * MS) is None
    assert gate.counts == CommandCounts(received=1, sent=1, links=1)


@pytest.mark.parametrize(
    "rc",
    [
        (RC_MIN - 1, 1500, 1500, 1000, 1000, 1000),
        (1500, 1500, 1500, 1000, 1000, RC_MAX + 1),
        (1500, 1500, 1500, 1000, 1000),
        (*RC, 1500),
        (0, 0, 0, 0, 0, 0),  # an unset message
        (-32768, 1500, 1500, 1000, 1000, 1000),
        (1500, 1500, 1500, 1000, 1000, 1000.0),  # not whole microseconds
        (True, 1500, 1500, 1000, 1000, 1000),
        "150015001500",
    ],
)
def test_out_of_range_is_dropped(rc):
    gate = CommandGate()
    assert gate.offer(rc, WALL, A, MONO) == "out_of_range"
    assert gate.take(MONO) is None
    assert gate.counts == CommandCounts(received=1, out_of_range=1)
    assert gate.latched(MONO) is None  # a refused command latches no one


def test_the_fc_pulse_range_replaces_betaflight_widest_once_known():
    gate = CommandGate()
    assert gate.offer((RC_MIN, RC_MAX, RC_MIN, RC_MAX, RC_MIN, RC_MAX), WALL, A, MONO) is None
    gate.pulse_range = (885, 2115)  # the FC said (its uplink status); the pending one is out
    assert gate.take(MONO) is None
    assert gate.offer((884, *RC[1:]), WALL + 1, A, MONO + 1) == "out_of_range"
    assert gate.offer((885, 2115, 885, 2115, 885, 2115), WALL + 2, A, MONO + 2) is None
    assert gate.counts.out_of_range == 2


def test_unstamped_is_dropped():
    gate = CommandGate()
    assert gate.offer(RC, 0, A, MONO) == "unstamped"
    assert gate.offer(RC, -5, A, MONO) == "unstamped"
    assert gate.counts == CommandCounts(received=2, unstamped=2)


def test_stamps_far_from_the_node_clock_are_fine_they_only_order():
    """Another host's clock, or one hours off: freshness is the arrival, not the stamp."""
    gate = CommandGate(50 * MS)
    assert gate.offer(RC, 3 * S, A, MONO) is None  # boot time of some other machine
    assert gate.take(MONO + 10 * MS) == Taken(RC)


def test_repeats_and_older_commands_are_dropped():
    """A stuck sender repeating its last message, or replaying old ones, sends nothing."""
    gate = CommandGate(50 * MS)
    assert gate.offer(RC, WALL, A, MONO) is None
    assert gate.take(MONO) == Taken(RC)
    for i in range(5):
        assert gate.offer(RC, WALL, A, MONO + (i + 1) * MS) == "not_newer"  # the same stamp
    assert gate.offer((1600, *RC[1:]), WALL - 20 * MS, A, MONO + 7 * MS) == "not_newer"  # older
    assert gate.take(MONO + 8 * MS) is None
    assert gate.counts.not_newer == 6


def test_a_second_publisher_is_foreign_while_the_first_is_live():
    gate = CommandGate(50 * MS)
    assert gate.offer(RC, WALL, A, MONO) is None
    assert gate.offer((1200, *RC[1:]), WALL + 5 * MS, B, MONO + 5 * MS) == "foreign"
    assert gate.take(MONO + 6 * MS) == Taken(RC)
    for i in range(1, 10):  # both at 100 Hz: only A's pass
        t = MONO + i * 10 * MS
        assert gate.offer((1100 + i, *RC[1:]), WALL + i * 10 * MS, A, t) is None
        assert gate.offer((1200 + i, *RC[1:]), WALL + i * 10 * MS, B, t + 1) == "foreign"
        assert gate.take(t + 2) == Taken((1100 + i, *RC[1:]))
    assert gate.latched(MONO + 95 * MS) == A
    assert gate.counts.foreign == 10 and gate.counts.links == 1


def test_a_dead_publisher_hands_over_after_one_age_limit():
    gate = CommandGate(50 * MS)
    assert gate.offer(RC, WALL, A, MONO) is None  # A's last command
    assert gate.take(MONO) == Taken(RC)
    assert gate.offer((1200, *RC[1:]), WALL, B, MONO + 50 * MS) == "foreign"  # the limit itself
    assert gate.latched(MONO + 50 * MS) == A
    assert gate.offer((1201, *RC[1:]), WALL, B, MONO + 50 * MS + 1) is None  # A is gone
    assert gate.latched(MONO + 50 * MS + 1) == B
    assert gate.counts.links == 2


def test_a_clock_step_back_costs_one_age_limit_not_the_step():
    """A publisher's clock stepping back 30 s: its commands are not newer than the newest
    taken until the link ends (the age limit of silence), then they start a new link."""
    gate = CommandGate(50 * MS)
    t, stamp = MONO, WALL
    for _ in range(10):  # 100 Hz
        assert gate.offer(RC, stamp, A, t) is None
        assert gate.take(t) is not None
        t, stamp = t + 10 * MS, stamp + 10 * MS
    stamp -= 30 * S
    verdicts = []
    while len(verdicts) < 20:
        verdicts.append(gate.offer(RC, stamp, A, t))
        gate.take(t)
        t, stamp = t + 10 * MS, stamp + 10 * MS
    lost = verdicts.index(None)
    assert verdicts[:lost] == ["not_newer"] * lost and lost == 5  # 50 ms at 100 Hz
    assert all(v is None for v in verdicts[lost:])
    assert gate.counts.links == 2


def test_a_publisher_without_an_identity_is_never_taken():
    gate = CommandGate()
    assert gate.offer(RC, WALL, None, MONO) == "foreign"
    assert gate.take(MONO) is None


def test_the_newest_supersedes_one_waiting_and_keeps_its_arming_request():
    gate = CommandGate(50 * MS)
    first, second, third = (1100, *RC[1:]), (1200, *RC[1:]), (1300, *RC[1:])
    assert gate.offer(first, WALL, A, MONO, ArmingAction.ARM) is None
    assert gate.offer(second, WALL + 1, A, MONO + 1) is None
    assert gate.take(MONO + 2) == Taken(second, ArmingAction.ARM)  # asked, and still asked
    assert gate.offer(third, WALL + 2, A, MONO + 3, ArmingAction.ARM) is None
    assert gate.offer(first, WALL + 3, A, MONO + 4, ArmingAction.DISARM) is None
    assert gate.take(MONO + 5) == Taken(first, ArmingAction.DISARM)  # the newest asked wins
    assert gate.counts == CommandCounts(received=4, superseded=2, links=1)


def test_a_command_that_waited_too_long_is_not_sent():
    """No port to send it on (a reconnect), and by the time there is, it is stale."""
    gate = CommandGate(50 * MS)
    assert gate.offer(RC, WALL, A, MONO) is None
    assert gate.take(MONO + 51 * MS) is None
    assert gate.counts == CommandCounts(received=1, stale=1, links=1)


def test_a_limit_must_be_positive():
    with pytest.raises(ValueError):
        CommandGate(0)


values = st.integers(RC_MIN - 50, RC_MAX + 50)
offers = st.lists(
    st.tuples(
        st.tuples(values, values, values, values, values, values),
        st.sampled_from([A, B]),
        st.integers(-30 * MS, 20 * MS),  # the stamp's step from the publisher's last
        st.integers(0, 60 * MS),  # time passing before the offer
        st.booleans(),  # the loop takes (and sends) after it
    ),
    max_size=80,
)


@settings(max_examples=examples(500))
@given(offers)
def test_what_passes_is_fresh_in_range_newer_one_publisher_at_a_time_and_once(steps):
    gate = CommandGate(50 * MS)
    now = MONO
    stamps = {A: WALL, B: WALL}
    accepted: list[tuple[bytes, int, int]] = []  # (publisher, stamp, arrival) of each taken in
    pending: dict[tuple[int, ...], int] = {}  # values -> the newest accepted with them
    sent: list[tuple[int, int]] = []  # (index in accepted, taken at)
    for rc, publisher, step, elapse, take in steps:
        now += elapse
        stamps[publisher] += step
        if gate.offer(rc, stamps[publisher], publisher, now) is None:
            accepted.append((publisher, stamps[publisher], now))
            pending[rc] = len(accepted) - 1
        if take:
            taken = gate.take(now)
            if taken is not None:
                gate.sent()
                sent.append((pending[taken.rc], now))
    for index, at in sent:
        assert at - accepted[index][2] <= 50 * MS  # fresh by the node's clock
    for before, after in itertools.pairwise(sent):
        assert after[0] > before[0]  # each once, in order
    for before, after in itertools.pairwise(accepted):
        if after[0] != before[0]:  # another publisher only after the first fell silent
            assert after[2] - before[2] > 50 * MS
        elif after[2] - before[2] <= 50 * MS:
            assert after[1] > before[1]  # within a link, strictly newer
    counts = gate.counts
    assert counts.sent == len(sent)
    assert counts.received == len(steps)
    assert counts.received == counts.sent + counts.dropped + gate.pending


@settings(max_examples=examples(300))
@given(st.lists(st.integers(RC_MIN - 100, RC_MAX + 100), min_size=5, max_size=7))
def test_the_gate_refuses_exactly_what_the_library_would_not_send(rc):
    """One definition of a command's values: what `CommandSender` (the library an OBC
    program uses) sends, the gate passes; what it refuses, the gate counts out of range."""
    try:
        CommandSender().next(rc)
        sendable = True
    except (TypeError, ValueError):
        sendable = False
    assert (CommandGate().offer(rc, WALL, A, MONO) != "out_of_range") == sendable
