"""The live loop's dispatch: every event to every sink and the monitor, each read's packets
to the sinks with a health snapshot; a sink given to a session is closed with it."""

from __future__ import annotations

import time

from tests.fsp.test_decoder import stream
from tests.verify.fake_fc import FakeFc
from wftool.recording.events import Event, StreamHealth
from wftool.verify.live import Dispatcher
from wftool.verify.monitor import StreamMonitor
from wftool.verify.session import VerifySession

RC = (1100, 1500, 1500, 1000, 1000, 1000)


class ListSink:
    """Keeps what it is handed, in order, as a ROS 2 node would publish it."""

    def __init__(self) -> None:
        self.seen: list[object] = []
        self.closed = False

    def event(self, event: Event) -> None:
        self.seen.append(event)

    def packets(self, packets, health: StreamHealth | None) -> None:
        self.seen.append((len(packets), health))

    def close(self) -> None:
        self.closed = True


def test_every_event_goes_to_every_sink_then_to_the_monitor():
    first, second = ListSink(), ListSink()
    monitor = StreamMonitor("test")
    dispatch = Dispatcher(monitor, [first, second]).event
    wire = stream(range(20), e1=True)
    events = [Event("connected", 1.0), Event("bytes", 1.1, wire[:1000]),
              Event("command", 1.12, rc=RC), Event("bytes", 1.15, wire[1000:]),
              Event("disconnected", 1.3)]  # fmt: skip
    decoded = [len(dispatch(event)) for event in events]
    assert first.seen == second.seen
    assert [e for e in first.seen if isinstance(e, Event)] == events
    reads = [e for e in first.seen if isinstance(e, tuple) and not isinstance(e, Event)]
    assert [n for n, _ in reads] == [decoded[1], decoded[3]] and sum(decoded) == 20
    health = reads[0][1]
    assert health is not None and health.packets == reads[0][0] and health.t == 1.1
    assert reads[1][1] is health  # the same snapshot until 0.1 s have passed
    assert monitor.summary().frames == 40 and monitor.uplink is None


def test_a_session_closes_the_sinks_it_was_given():
    sink = ListSink()
    session = VerifySession("socket://127.0.0.1:9", duration_s=1.0, sinks=[sink])
    session.close()
    assert sink.closed


class SlowSink(ListSink):
    """Takes its time over each read's bytes, as a recorder writing a chunk or a loaded host
    does; notes when it was done with the read before each command."""

    def __init__(self) -> None:
        super().__init__()
        self.done_at = 0.0
        self.commands: list[tuple[float, float]] = []
        """(the command's time, when the sink was done with the read before it)"""

    def event(self, event: Event) -> None:
        super().event(event)
        if event.kind == "bytes":
            # Longer than the fake FC's 5 ms between writes: every read finds bytes waiting,
            # so the read after which a command is due has bytes for the sinks too.
            time.sleep(0.006)
            self.done_at = time.monotonic()
        elif event.kind == "command":
            self.commands.append((event.t, self.done_at))


def test_a_command_is_stamped_when_it_is_sent_not_when_the_read_before_it_returned():
    """A read's bytes go to the sinks before the command due then is sent: the command's
    time (its `tx_time_us`, and what a timed command's lead counts from) comes after that."""
    sink = SlowSink()
    with FakeFc() as fc:
        VerifySession(fc.url, duration_s=1.0, uplink_rate_hz=50.0, sinks=[sink]).run()
    assert len(sink.commands) >= 10
    assert all(sent >= done for sent, done in sink.commands), sink.commands
