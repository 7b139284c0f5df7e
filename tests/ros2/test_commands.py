"""The command gate: only fresh, in-range, newer commands pass, each once, and every command
offered is counted by what became of it."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wftool.fsp import CommandSender
from wftool.fsp.packets import RC_PULSE_US
from wftool.ros2.commands import FUTURE_TOLERANCE_NS, CommandCounts, CommandGate

MS = 1_000_000
RC_MIN, RC_MAX = RC_PULSE_US  # what the library lets a command carry, and nothing else
RC = (1500, 1500, 1500, 1000, 1000, 1000)
NOW = 1_700_000_000 * 1_000_000_000


def test_a_fresh_command_is_taken_once():
    gate = CommandGate(50 * MS)
    assert gate.offer(RC, NOW - 1 * MS, NOW) is None
    assert gate.take(NOW + 1 * MS) == RC
    gate.sent()
    assert gate.take(NOW + 2 * MS) is None  # never again, however long the sender is silent
    assert gate.take(NOW + 500 * MS) is None
    assert gate.counts == CommandCounts(received=1, sent=1)


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
    assert gate.offer(rc, NOW, NOW) == "out_of_range"
    assert gate.take(NOW) is None
    assert gate.counts == CommandCounts(received=1, out_of_range=1)


def test_the_range_ends_are_in():
    gate = CommandGate()
    assert gate.offer((RC_MIN, RC_MAX, RC_MIN, RC_MAX, RC_MIN, RC_MAX), NOW, NOW) is None


def test_stale_future_and_unstamped_are_dropped():
    gate = CommandGate(50 * MS)
    assert gate.offer(RC, NOW - 50 * MS - 1, NOW) == "stale"
    assert gate.offer(RC, 0, NOW) == "stale"  # header.stamp never set
    assert gate.offer(RC, NOW + FUTURE_TOLERANCE_NS + 1, NOW) == "future"
    assert gate.offer(RC, NOW + 3600 * 1000 * MS, NOW) == "future"
    assert gate.take(NOW) is None
    assert gate.counts == CommandCounts(received=4, stale=2, future=2)
    assert gate.offer(RC, NOW - 50 * MS, NOW) is None  # the limit itself is fresh
    assert gate.offer((1600, *RC[1:]), NOW + FUTURE_TOLERANCE_NS, NOW) is None


def test_repeats_and_older_commands_are_dropped():
    """A stuck sender repeating its last message, or replaying old ones, sends nothing."""
    gate = CommandGate(50 * MS)
    assert gate.offer(RC, NOW - 10 * MS, NOW) is None
    assert gate.take(NOW) == RC
    for _ in range(5):
        assert gate.offer(RC, NOW - 10 * MS, NOW + 1 * MS) == "not_newer"  # the same stamp
    assert gate.offer((1600, *RC[1:]), NOW - 20 * MS, NOW + 1 * MS) == "not_newer"  # older
    assert gate.take(NOW + 2 * MS) is None
    assert gate.counts.not_newer == 6


def test_the_newest_supersedes_one_waiting():
    gate = CommandGate(50 * MS)
    first, second = (1100, *RC[1:]), (1200, *RC[1:])
    assert gate.offer(first, NOW - 2 * MS, NOW) is None
    assert gate.offer(second, NOW - 1 * MS, NOW) is None
    assert gate.take(NOW) == second
    assert gate.counts == CommandCounts(received=2, superseded=1)


def test_a_command_that_waited_too_long_is_not_sent():
    """No port to send it on (a reconnect), and by the time there is, it is stale."""
    gate = CommandGate(50 * MS)
    assert gate.offer(RC, NOW, NOW) is None
    assert gate.take(NOW + 51 * MS) is None
    assert gate.counts == CommandCounts(received=1, stale=1)


def test_a_limit_must_be_positive():
    with pytest.raises(ValueError):
        CommandGate(0)


values = st.integers(RC_MIN - 50, RC_MAX + 50)
offers = st.lists(
    st.tuples(
        st.tuples(values, values, values, values, values, values),
        st.integers(-80 * MS, 10 * MS),  # stamp relative to the clock: stale ... future
        st.integers(0, 30 * MS),  # time passing before the offer
        st.booleans(),  # the loop takes (and sends) after it
    ),
    max_size=60,
)


@settings(max_examples=500)
@given(offers)
def test_what_passes_is_fresh_in_range_newer_and_once(steps):
    gate = CommandGate(50 * MS)
    now = NOW
    taken: list[tuple[tuple[int, ...], int, int]] = []  # (rc, its stamp, taken at)
    offered: dict[tuple[int, ...], list[int]] = {}
    for rc, relative, elapse, take in steps:
        now += elapse
        stamp = now + relative
        if gate.offer(rc, stamp, now) is None:
            offered.setdefault(rc, []).append(stamp)
        if take:
            command = gate.take(now)
            if command is not None:
                gate.sent()
                stamps = [s for s in offered[command] if now - s <= 50 * MS]
                taken.append((command, max(stamps), now))
    stamps = [stamp for _, stamp, _ in taken]
    assert stamps == sorted(set(stamps))  # strictly newer each time: nothing sent twice
    for rc, stamp, at in taken:
        assert all(RC_MIN <= v <= RC_MAX for v in rc)
        assert at - stamp <= 50 * MS
    counts = gate.counts
    assert counts.sent == len(taken)
    assert counts.received == len(steps)
    assert counts.received == counts.sent + counts.dropped + gate.pending


@settings(max_examples=300)
@given(st.lists(st.integers(RC_MIN - 100, RC_MAX + 100), min_size=5, max_size=7))
def test_the_gate_refuses_exactly_what_the_library_would_not_send(rc):
    """One definition of a command's values: what `CommandSender` (the library an OBC
    program uses) sends, the gate passes; what it refuses, the gate counts out of range."""
    try:
        CommandSender().next(rc)
        sendable = True
    except (TypeError, ValueError):
        sendable = False
    assert (CommandGate().offer(rc, NOW, NOW) != "out_of_range") == sendable
