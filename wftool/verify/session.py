"""The verify API: judge an FSP stream, live or recorded; the CLI only renders what it returns.

    session = VerifySession("socket://127.0.0.1:5762", duration_s=10,
                            expected_rate_hz=1000.0)
    result = session.run()
    print(result.verdict.passed, result.summary.frames)
    result.check()   # raises VerificationFailed naming the failed checks

`VerifySession` wires what a run needs — the monitor (which decodes), the uplink pattern,
the recording — runs the live loop and returns the summary with its verdict. `replay`
does the same for a recording. `criteria_for` turns a user's limits into `Criteria`.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from wftool.errors import VerificationFailed
from wftool.fc.msp import MspClient
from wftool.fsp import DEFAULT_BAUDRATE, ESTIMATORS, SensorFrame, StatePacket
from wftool.fsp.schedule import frame_rate_hz
from wftool.interrupts import stop_on_signals
from wftool.verify.criteria import Criteria, Verdict, judge
from wftool.verify.foxglove import DEFAULT_HOST, FoxgloveLive
from wftool.verify.live import LiveOptions, run_live
from wftool.verify.monitor import StreamMonitor, StreamSummary
from wftool.verify.recording import (
    RECORD_FORMATS,
    Recorder,
    RecordingReader,
    replay_recording,
    run_metadata,
)
from wftool.verify.uplink import UplinkTracker, check_uplink_rate


def fc_frame_rate_hz(msp_url: str, fsp_rate_hz: float) -> float:
    """The frame rate an FC configured with `fsp_rate_hz` streams: from its PID looptime,
    asked over MSP on `msp_url` (its MSP port, not the FSP port)."""
    with MspClient.open(msp_url) as msp:
        return frame_rate_hz(fsp_rate_hz, msp.pid_looptime_us())


def criteria_for(
    *,
    uplink: bool = False,
    min_rate_hz: float | None = None,
    max_spread_ms: float | None = None,
    max_loss_pct: float | None = None,
    max_drops_pct: float | None = None,
    max_errors: int | None = None,
    max_outage_s: float | None = None,
) -> Criteria:
    """The criteria for a user's limits: a limit left at None takes the default. A board and
    the virtual FC are judged alike."""
    defaults = Criteria()

    def pick(value: Any, default: Any) -> Any:
        return default if value is None else value

    return Criteria(
        min_rate_hz=pick(min_rate_hz, defaults.min_rate_hz),
        max_spread_ms=pick(max_spread_ms, defaults.max_spread_ms),
        max_loss_pct=pick(max_loss_pct, defaults.max_loss_pct),
        max_drops_pct=pick(max_drops_pct, defaults.max_drops_pct),
        max_errors=pick(max_errors, defaults.max_errors),
        max_outage_s=pick(max_outage_s, defaults.max_outage_s),
        uplink=uplink,
    )


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

    `uplink_rate_hz` sends the uplink pattern (None sends nothing); `criteria.uplink` is
    what judges it (`criteria_for(uplink=True)`). `record_path` (in `record_format`, see
    `wftool.verify.recording`) and `csv_path` are created here, so a path that cannot be
    written fails before the run, and finished when the run ends, however it ends
    (`close()` them when the session is never run). `foxglove_port` serves the stream live
    to Foxglove on `foxglove_host` (port 0: any free one; `live_view.url` says which),
    from now until `close()`. `clock` names the estimator of the frames' OBC times
    (`wftool.fsp.ESTIMATORS`; None: the default).
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
        record_path: Path | None = None,
        csv_path: Path | None = None,
        clock: str | None = None,
        record_format: str = RECORD_FORMATS[0],
        foxglove_port: int | None = None,
        foxglove_host: str = DEFAULT_HOST,
    ) -> None:
        clock = clock or ESTIMATORS[0]
        if uplink_rate_hz is not None:
            check_uplink_rate(uplink_rate_hz)
        self.options = LiveOptions(url, baudrate, duration_s, uplink_rate_hz)
        self.criteria = criteria or criteria_for(uplink=uplink_rate_hz is not None)
        uplink = UplinkTracker() if uplink_rate_hz is not None else None
        self.monitor = StreamMonitor(url, expected_rate_hz, uplink=uplink, clock=clock)
        self._recorder: Recorder | None = None
        self.live_view: FoxgloveLive | None = None
        if foxglove_port is not None:  # first: a server closes without a trace, files do not
            self.live_view = FoxgloveLive(foxglove_port, foxglove_host)
        if record_path or csv_path:
            metadata = run_metadata(url, baudrate, expected_rate_hz, uplink_rate_hz, clock)
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
        with stop_on_signals(stop):
            try:
                summary = run_live(
                    self.options, self.monitor, self._recorder, on_refresh, stop,
                    on_packets=on_packets, live_view=self.live_view,
                )  # fmt: skip
            finally:
                self.close()
        return self.result(summary)

    def close(self) -> None:
        """Stop the live view, then finish the recording files (if any)."""
        live_view, recorder = self.live_view, self._recorder
        self.live_view = self._recorder = None
        try:
            if live_view is not None:
                live_view.close()
        finally:
            if recorder is not None:
                recorder.close()

    def judge(self, summary: StreamSummary) -> Verdict:
        return judge(summary, self.criteria)

    def result(self, summary: StreamSummary | None = None) -> VerifyResult:
        """The result of what the run has seen so far (or of `summary`)."""
        summary = summary if summary is not None else self.monitor.summary()
        return VerifyResult(summary, self.judge(summary), self.monitor.latest)


def replay(
    path: Path,
    expected_rate_hz: float | None = None,
    criteria: Criteria | None = None,
    clock: str | None = None,
) -> VerifyResult:
    """The result of a `verify --record` recording (either format; a rosbag2 directory or
    an MCAP file), computed again. The uplink is judged
    when the recorded run sent it, whatever `criteria.uplink` says; `clock` None uses the
    recorded run's estimator."""
    recording = RecordingReader(path)
    monitor = replay_recording(recording, expected_rate_hz, clock)
    criteria = replace(criteria or Criteria(), uplink=monitor.uplink is not None)
    summary = monitor.summary()
    verdict = judge(summary, criteria)
    if recording.cut is not None:  # judged as far as it goes; the end of the run is missing
        note = f"recording {recording.path.name} was {recording.cut.describe()}"
        verdict = replace(verdict, notes=(*verdict.notes, note))
    return VerifyResult(summary, verdict, monitor.latest)
