"""The live loop's dispatch: every event to every sink and the monitor, each read's packets
to the sinks with a health snapshot; a sink given to a session is closed with it."""

from __future__ import annotations

from tests.fsp.test_decoder import stream
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
