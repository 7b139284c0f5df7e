"""The verify API: judge an FSP stream, live or recorded; the CLI only renders what it returns.

session = VerifySession("socket://127.0.0.1:5762", duration_s=10, expected_rate_hz=1000.0)
result = session.run()
print(result.verdict.passed, result.summary.frames)
result.check()   # raises VerificationFailed naming the failed checks
replay(Path("run")).verdict   # the same for a recording
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, replace
from pathlib import Path

from wftool.errors import UsageError, VerificationFailed
from wftool.fc.msp import MspClient
from wftool.fsp import DEFAULT_BAUDRATE, ESTIMATORS, SensorFrame, StatePacket
from wftool.fsp.schedule import frame_rate_hz
from wftool.interrupts import stop_on_signals
from wftool.recording.events import Event, Sink, StreamHealth, run_metadata
from wftool.recording.reader import RecordingReader
from wftool.recording.recorder import RECORD_FORMATS, Recorder
from wftool.verify.criteria import Criteria, Verdict, criteria_for, judge
from wftool.verify.foxglove import DEFAULT_HOST, FoxgloveLive
from wftool.verify.live import Commander, LiveOptions, run_live
from wftool.verify.monitor import StreamMonitor, StreamSummary
from wftool.verify.uplink import UplinkTracker, check_uplink_rate


def fc_frame_rate_hz(msp_url: str, fsp_rate_hz: float) -> float:
    """The frame rate an FC configured with `fsp_rate_hz` streams: from its PID looptime,
    asked over MSP on `msp_url` (its MSP port, not the FSP port)."""
    with MspClient.open(msp_url) as msp:
        return frame_rate_hz(fsp_rate_hz, msp.pid_looptime_us())


@dataclass(frozen=True)
class VerifyResult:
    """What a run saw, and whether it passes."""

    summary: StreamSummary
    verdict: Verdict
    latest: SensorFrame | None
    """The newest frame, for a dashboard."""

    def as_json(self) -> dict:
        return {**self.summary.as_json(), "verdict": self.verdict.as_json()}

    def check(self) -> None:
        """Raise `VerificationFailed` naming the failed checks, unless the verdict passed."""
        if not self.verdict.passed:
            failed = "; ".join(c.describe() for c in self.verdict.checks if not c.passed)
            raise VerificationFailed(f"stream verification failed: {failed}")


class VerifySession:
    """One verify run on a port: `run()` until the duration is up, then the result.

    `uplink_rate_hz` sends the uplink pattern (None sends nothing), as timed commands
    `uplink_lead_s` ahead if given (E4: the FC reports when each acted, `summary.timed`);
    `criteria.uplink` is what judges it (`criteria_for(uplink=True)`), and timed commands
    are judged whenever they are sent (`criteria.timed`). `record_path` (in
    `record_format`, see `wftool.recording.reader`) and `csv_path` are created here, so a
    path that cannot be written fails before the run, and finished when the run ends,
    however it ends (`close()` them when the session is never run). `foxglove_port` serves
    the stream live to Foxglove on `foxglove_host` (port 0: any free one; `live_view.url`
    says which), from now until `close()`. `clock` names the estimator of the frames' OBC times
    (`wftool.fsp.ESTIMATORS`; None: the default). `sinks` get the run as the recording
    does (`wftool.recording.events.Sink`; a ROS 2 node, say), and are closed with it;
    `commander` sends commands instead of the uplink pattern (`wftool.verify.live.Commander`).
    """

    def __init__(
        self,
        url: str,
        baudrate: int = DEFAULT_BAUDRATE,
        duration_s: float | None = None,
        *,
        criteria: Criteria | None = None,
        expected_rate_hz: float | None = None,
        uplink_rate_hz: float | None = None,
        uplink_lead_s: float | None = None,
        record_path: Path | None = None,
        csv_path: Path | None = None,
        clock: str | None = None,
        record_format: str = RECORD_FORMATS[0],
        foxglove_port: int | None = None,
        foxglove_host: str = DEFAULT_HOST,
        sinks: Sequence[Sink] = (),
        commander: Commander | None = None,
    ) -> None:
        clock = clock or ESTIMATORS[0]
        if commander is not None and uplink_rate_hz is not None:
            raise UsageError("the uplink pattern and another commander cannot both send commands")
        self._commander = commander
        if uplink_rate_hz is not None:
            check_uplink_rate(uplink_rate_hz)
        self.options = LiveOptions(url, baudrate, duration_s, uplink_rate_hz, uplink_lead_s)
        self.criteria = criteria or criteria_for(uplink=uplink_rate_hz is not None)
        if uplink_lead_s is not None:
            self.criteria = replace(self.criteria, timed=True)
        uplink = UplinkTracker() if uplink_rate_hz is not None else None
        self.monitor = StreamMonitor(url, expected_rate_hz, uplink=uplink, clock=clock)
        self._recorder: Recorder | None = None
        self._sinks = list(sinks)
        self.live_view: FoxgloveLive | None = None
        if foxglove_port is not None:  # first: a server closes without a trace, files do not
            self.live_view = FoxgloveLive(foxglove_port, foxglove_host)
        if record_path or csv_path:
            metadata = run_metadata(
                url, baudrate, expected_rate_hz, uplink_rate_hz, clock, uplink_lead_s, duration_s
            )
            try:
                self._recorder = Recorder(record_path, csv_path, metadata, record_format)
            except BaseException:
                self.close()
                raise

    def run(
        self,
        on_refresh: Callable[[StreamSummary], None] | None = None,
        stop: threading.Event | None = None,
        on_packets: Callable[[Sequence[StatePacket], float], None] | None = None,
    ) -> VerifyResult:
        """Verify until the duration is up or `stop` is set; `on_refresh` gets a summary
        four times a second. On the main thread SIGINT, SIGTERM and SIGHUP stop the run
        where it can stop (`wftool.interrupts`): the recording is finished, then the signal
        propagates (`KeyboardInterrupt`, `Terminated`) and `result()` judges what was seen."""
        stop = stop if stop is not None else threading.Event()
        sinks: list[Sink] = [s for s in (self._recorder, self.live_view) if s is not None]
        sinks += self._sinks
        if on_packets is not None:
            sinks.append(_PacketCallback(on_packets))
        with stop_on_signals(stop):
            try:
                summary = run_live(
                    self.options, self.monitor, sinks, on_refresh, stop, commander=self._commander
                )
            finally:
                self.close()
        return self.result(summary)

    def close(self) -> None:
        """Stop the live view, then finish the recording files, then close the other sinks
        (each of them, whatever fails: the first failure is raised)."""
        sinks = [s for s in (self.live_view, self._recorder) if s is not None] + self._sinks
        self.live_view, self._recorder, self._sinks = None, None, []
        with ExitStack() as closing:
            for sink in reversed(sinks):  # an ExitStack closes the last pushed first
                closing.callback(sink.close)

    def judge(self, summary: StreamSummary) -> Verdict:
        return judge(summary, self.criteria)

    def result(self, summary: StreamSummary | None = None) -> VerifyResult:
        """The result of what the run has seen so far (or of `summary`)."""
        summary = summary if summary is not None else self.monitor.summary()
        return VerifyResult(summary, self.judge(summary), self.monitor.latest)


class _PacketCallback:
    """`on_packets` as a sink: each read's packets, if any, and the time the read returned."""

    def __init__(self, on_packets: Callable[[Sequence[StatePacket], float], None]) -> None:
        self._on_packets = on_packets
        self._t = 0.0

    def event(self, event: Event) -> None:
        self._t = event.t

    def packets(self, packets: Sequence[StatePacket], health: StreamHealth | None) -> None:
        if packets:
            self._on_packets(packets, self._t)

    def close(self) -> None:
        pass


def replay_recording(
    path: Path | RecordingReader, expected_rate_hz: float | None = None, clock: str | None = None
) -> StreamMonitor:
    """A monitor that has seen exactly what the recorded run saw; `clock` None takes the
    recorded run's estimator."""
    recording = path if isinstance(path, RecordingReader) else RecordingReader(path)
    metadata = recording.metadata
    if expected_rate_hz is None:
        expected_rate_hz = recording.expected_rate_hz()
    uplink = UplinkTracker() if metadata.get("uplink_rate_hz") else None
    clock = clock or metadata.get("clock") or ESTIMATORS[0]
    monitor = StreamMonitor(
        metadata.get("port", str(recording.path)), expected_rate_hz, uplink=uplink, clock=clock
    )
    for event in recording.events():
        monitor.apply(event)
    return monitor


def replay(
    path: Path,
    expected_rate_hz: float | None = None,
    criteria: Criteria | None = None,
    clock: str | None = None,
) -> VerifyResult:
    """The result of a `verify --record` recording (either format; a rosbag2 directory or
    an MCAP file), computed again. The uplink is judged when the recorded run sent it, and
    its timed commands when it sent them, whatever `criteria` says; `clock` None uses the
    recorded run's estimator."""
    recording = RecordingReader(path)
    monitor = replay_recording(recording, expected_rate_hz, clock)
    summary = monitor.summary()
    timed = bool(recording.metadata.get("uplink_lead_ms")) or summary.timed is not None
    criteria = replace(criteria or Criteria(), uplink=monitor.uplink is not None, timed=timed)
    verdict = judge(summary, criteria)
    cut_short = recording.cut_short(summary.duration_s)
    if cut_short is not None:  # judged as far as it goes; the end of the run is missing
        verdict = replace(verdict, notes=(*verdict.notes, f"the recording was {cut_short}"))
    return VerifyResult(summary, verdict, monitor.latest)
