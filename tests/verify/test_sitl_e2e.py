"""`wftool verify --stream` end to end against the patched SITL (a real Betaflight).

The virtual FC runs with FSP on UART2 and synthetic motion, and is judged as a board is:
the default limits, the frame rate against what fsp_rate_hz gives at the PID looptime the FC
reports over MSP (`--fsp-rate` with `--fc`).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.conftest import run_cli
from tests.recording.test_rosbag import read_bag
from tests.waits import wait_for
from wftool.bench.latency import STEP_SETTLE_S
from wftool.fsp import Authority, StateDecoder
from wftool.fsp.clock import EnvelopeClockEstimator
from wftool.fsp.timed import REFUSED
from wftool.recording.reader import RecordingReader
from wftool.sitl.process import free_port_base
from wftool.sitl.session import Motion, VirtualFcSession
from wftool.sitl.truth import Anchor, TrueClock
from wftool.verify.live import LiveOptions, run_live
from wftool.verify.monitor import StreamMonitor

RELOCK_S = STEP_SETTLE_S + EnvelopeClockEstimator.LOCK_SPAN_S
"""The longest verify's clock takes to lock again after a step of the FC clock: the step
confirmed, then the rate learnt again."""


@pytest.fixture
def fsp_fc(sitl_binary: Path, tmp_path: Path) -> Iterator[VirtualFcSession]:
    with VirtualFcSession(sitl_binary, tmp_path / "fc", motion=Motion(), port_base=None) as session:
        yield session


def expected(fc: VirtualFcSession) -> tuple[str, ...]:
    """Where verify learns the rate to expect: the FC's setting and its MSP port."""
    return ("--fsp-rate", str(fc.rate_hz), "--fc", fc.msp_url)


def re_anchors(log_path: Path) -> list[Anchor]:
    """The virtual FC's re-anchors (its log): its clock stood still while its host stalled it
    (more than 50 ms), then went on from there, which the OBC sees as a step of the FC clock.
    A board's clock does not step."""
    return [a for a in TrueClock(log_path).anchors if a.reason == "host-lag"]


def settling(fc: VirtualFcSession, ended: float) -> list[Anchor]:
    """The virtual FC's re-anchors within `RELOCK_S` before host time `ended`: a clock that
    followed it may not have locked again by then."""
    return [a for a in re_anchors(fc.fc.log_path) if a.monotonic_ns / 1e9 > ended - RELOCK_S]


def verify_json(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, dict, str]:
    code, out, err = run_cli(capsys, *args, "--json")
    return code, json.loads(out), err


def test_stream_passes_with_no_errors_no_loss_and_replays_identically(
    fsp_fc: VirtualFcSession, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    recording = tmp_path / "run"  # a rosbag2 directory (the default ros2 format)
    code, live, err = verify_json(
        capsys, "verify", "--stream", "--port", fsp_fc.fsp_url, "--duration", "8",
        "--max-loss", "0", "--max-fc-drops", "0", *expected(fsp_fc), "--record", str(recording),
    )  # fmt: skip
    ended = time.monotonic()
    assert code == 0, err
    assert live["verdict"]["passed"]
    assert live["expected_rate_hz"] == pytest.approx(fsp_fc.expected_rate_hz)
    checks = {check["name"]: check for check in live["verdict"]["checks"]}
    assert checks["frame rate"]["passed"] and checks["FC interval spread"]["passed"]
    assert live["fc_drops"] == 0
    assert live["rejected"] == {"cobs": 0, "length": 0, "version": 0, "crc": 0, "outlier": 0}
    assert (live["lost_frames"], live["lost_packets"], live["e1"]) == (0, 0, True)
    assert live["frames"] > 500
    # the rate the OBC received is the rate the FC captured at
    assert live["frame_rate_hz"] == pytest.approx(live["source_rate_hz"], rel=0.05)
    clock = live["clock"]
    assert abs(clock["rate_ppm"]) < 2000
    assert clock["locked"] or settling(fsp_fc, ended), clock

    code, replayed, _ = verify_json(
        capsys, "replay", str(recording), "--max-loss", "0", "--max-fc-drops", "0"
    )
    assert code == 0
    assert replayed == live


def test_uplink_pattern_comes_back_in_the_stream(
    fsp_fc: VirtualFcSession, capsys: pytest.CaptureFixture[str]
) -> None:
    code, summary, err = verify_json(
        capsys, "verify", "--stream", "--port", fsp_fc.fsp_url, "--duration", "6",
        "--uplink", "--uplink-rate", "50", *expected(fsp_fc),
    )  # fmt: skip
    assert code == 0, err
    uplink = summary["uplink"]
    assert uplink["commands_sent"] >= 250
    # the MSP receiver needs a few frames before it leaves failsafe: the first step may be missed
    assert uplink["steps_sent"] >= 50
    assert uplink["steps_echoed"] >= 0.9 * (uplink["steps_sent"] - 1)
    assert 0 < uplink["rtt_p50_ms"] < 200


def test_stream_without_the_uplink_check_fails_it_when_asked(
    fsp_fc: VirtualFcSession, capsys: pytest.CaptureFixture[str]
) -> None:
    """The verdict can fail: a stricter rate than the FC can give is reported, exit 1."""
    code, summary, err = verify_json(
        capsys, "verify", "--stream", "--port", fsp_fc.fsp_url, "--duration", "3",
        "--min-rate", "100000",
    )  # fmt: skip
    assert code == 1
    assert err.strip().splitlines()[-1].startswith("error: stream verification failed: frame rate")
    assert not summary["verdict"]["passed"]


def test_sitl_killed_and_restarted_mid_run_is_survived(fsp_fc: VirtualFcSession) -> None:
    monitor = StreamMonitor(fsp_fc.fsp_url)
    result = {}

    def verify() -> None:
        # long enough to re-lock (4 s of span) after the restart even if the loaded host makes
        # the FC re-anchor early on (a clock step: the rate is learnt again after it)
        result["summary"] = run_live(LiveOptions(fsp_fc.fsp_url, 2_000_000, 20.0), monitor)

    thread = threading.Thread(target=verify)
    thread.start()
    # its frames so far: the decoder's count (summary() is no call to make while it reads)
    stats = monitor.decoder.stats
    assert wait_for(lambda: stats.frames > 2000, 60)  # 2 s of stream
    before = stats.frames
    fsp_fc.fc.stop()  # the FC vanishes mid-run ...
    time.sleep(2)
    fsp_fc.fc.start()  # ... and comes back with its saved configuration
    thread.join(30)
    ended = time.monotonic()
    summary = result["summary"]
    assert before > 100
    assert summary.reconnects == 1
    assert summary.frames > before + 100  # streaming again after the restart
    assert summary.lost_frames == 0 and summary.errors == 0
    assert summary.clock is not None  # re-aligned on the new connection:
    assert summary.clock.locked or settling(fsp_fc, ended), summary.clock


def test_sitl_time_reply_verify_shows_round_trips_and_the_offset_uncertainty(
    sitl_binary: Path, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """`wftool sitl --time-reply`: the FC answers the uplink's commands; verify pairs the
    replies (none rejected as chunks) and, with the two-way clock it then uses, reports the
    offset's uncertainty; a recording replays to the same round trips."""
    recording = tmp_path / "run.mcap"
    code, live, err = verify_json(
        capsys, "sitl", "--binary", str(sitl_binary), "--workdir", str(tmp_path / "fc"),
        "--port-base", str(free_port_base()), "--no-motion", "--time-reply", "--uplink",
        "--verify", "10", "--record", str(recording),
    )  # fmt: skip
    assert code == 0, err
    assert live["clock_estimator"] == "twoway" and live["errors"] == 0
    assert live["round_trip"]["count"] >= 0.9 * live["uplink"]["commands_sent"]
    two_way = live["two_way"]
    assert two_way["active"] and two_way["uncertainty_s"] > 0
    assert live["clock"]["uncertainty_s"] == two_way["uncertainty_s"]
    code, replayed, _ = verify_json(capsys, "replay", str(recording))
    assert code == 0 and replayed["round_trip"] == live["round_trip"]
    assert replayed["two_way"] == two_way


def test_what_the_fc_made_of_the_commands_is_shown_recorded_and_replayed(
    sitl_binary: Path, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """`wftool sitl --pilot --uplink --verify`: the FC reports what it made of the uplink
    pattern's commands (E3); the simulated pilot engages the OBC once the FC says it is
    ready; the dashboard and --json show its newest report (commands in effect, engaged by
    the pilot's override, the pilot's radio its receiver, disarmed), the recording keeps
    its reports in the order who flies changed, and replay shows the same."""
    recording = tmp_path / "run"
    code, live, err = verify_json(
        capsys, "sitl", "--binary", str(sitl_binary), "--workdir", str(tmp_path / "fc"),
        "--port-base", str(free_port_base()), "--pilot", "--uplink", "--verify", "5",
        "--record", str(recording),
    )  # fmt: skip
    assert code == 0, err
    fc, sent = live["fc_uplink"], live["uplink"]["commands_sent"]
    assert fc is not None and sent >= 200
    assert sent - 15 <= fc["accepted"] <= sent  # the newest report: at most 100 ms old
    assert fc["rejected"] == 0 and fc["timeout_ms"] == 50 and 0 <= fc["age_s"] < 0.5
    flags = {name: fc[name] for name in ("live", "override", "obc_receiver", "rx_loss", "armed")}
    assert flags == {"live": True, "override": True, "obc_receiver": False, "rx_loss": False,
                     "armed": False}  # fmt: skip
    assert fc["failsafe_phase"] == "IDLE" and fc["authority"] == "engaged"
    shown = " ".join(err.replace("│", " ").split())  # the last dashboard (stderr with --json)
    assert f"FC uplink accepted {fc['accepted']:,} stale {fc['stale']:,}" in shown
    assert "on: live, override failsafe IDLE who flies: engaged" in shown
    assert "pilot: the OBC is ready; override switch AUX2 off" in err
    assert "pilot: the OBC is engaged: it steers the sticks" in err

    statuses = [m for _, m in read_bag(recording)["/fsp/uplink_status"]]
    assert len(statuses) >= 5 * 10 * 0.8  # about every one the FC sent, at 10 Hz
    assert not any(m.obc_receiver for m in statuses)
    who = [m.authority for m in statuses]
    who = [a for a, b in zip(who, [None, *who]) if a != b]  # each change once
    assert who[-3:] == [Authority.PROVING, Authority.READY, Authority.ENGAGED], who
    # engaged only with the pilot's switch on, and each time only once it was off since the
    # sticks were last the pilot's (a loaded host's uplink pattern can miss the timeout: the
    # pilot then engages the OBC again, off -> on; the FC reports each switch change)
    assert all(m.override for m in statuses if m.authority == Authority.ENGAGED)
    for i, m in enumerate(statuses):
        if m.authority == Authority.ENGAGED and statuses[i - 1].authority != Authority.ENGAGED:
            pilots = [j for j in range(i) if statuses[j].authority == Authority.PILOT]
            since = pilots[-1] if pilots else 0
            assert any(not s.override for s in statuses[since:i]), (i, statuses[since : i + 1])
    accepted = [m.accepted for m in statuses]
    assert accepted == sorted(accepted) and accepted[-1] <= fc["accepted"]
    code, replayed, _ = verify_json(capsys, "replay", str(recording))
    assert code == 0 and replayed["fc_uplink"] == fc


def test_sitl_verify_with_timed_commands_reports_when_they_acted(
    sitl_binary: Path, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """`--uplink-lead`: the pattern goes out as timed commands once the clock locks; the FC's
    reports say each acted within one PID period of its time, and the verdict judges them (on
    time, late, refused); a recording replays to the same figures and verdict (they come from
    the FC's reports in the stream). The lead, 20 ms, is longer than a loaded host's delivery
    delay (tests/sitl/test_timed_commands.py)."""
    recording = tmp_path / "run.mcap"
    code, live, err = verify_json(
        capsys, "sitl", "--binary", str(sitl_binary), "--workdir", str(tmp_path / "fc"),
        "--port-base", str(free_port_base()), "--no-motion", "--time-reply", "--uplink",
        "--uplink-rate", "100", "--uplink-lead", "20", "--verify", "12", "--record",
        str(recording),
    )  # fmt: skip
    stalls = [a.fc_us for a in re_anchors(tmp_path / "fc" / "sitl.log")]
    refused = refused_at(recording)
    # The virtual FC's clock stands still while its host stalls it (then re-anchors): the
    # OBC's clock runs on, so what it sends then arrives too far ahead by the FC's clock and is
    # refused, rightly. A board's clock does not stand still. Nothing else is refused.
    assert all(any(0 <= at - stall < 200_000 for stall in stalls) for at in refused), refused
    failed = {c["name"] for c in live["verdict"]["checks"] if not c["passed"]}
    assert failed == ({"timed commands refused"} if refused else set()), err
    assert code == (1 if refused else 0), err
    timed = live["timed"]
    applied = timed["apply"]
    assert applied["count"] >= 200  # ~1 s of commands went out immediate, before the lock
    assert applied["p1_us"] >= 0 and applied["p99_us"] < 125  # one PID period at 8 kHz
    assert timed["outcomes"]["ON_TIME"] >= 0.9 * timed["reports"]
    assert live["uplink"]["steps_echoed"] >= 0.9 * live["uplink"]["steps_sent"]
    judged = [c["name"] for c in live["verdict"]["checks"] if c["name"].startswith("timed")]
    assert judged == ["timed commands on time", "timed commands late", "timed commands refused"]
    code, replayed, _ = verify_json(capsys, "replay", str(recording))
    assert code == (1 if refused else 0) and replayed["timed"] == timed
    assert replayed["verdict"] == live["verdict"]


def refused_at(recording: Path) -> list[int]:
    """The FC time of each refusal of a timed command (its report's event time), from the
    recorded stream."""
    decoder = StateDecoder(time_replies=True)
    refused = []
    for event in RecordingReader(recording).events():
        if event.kind == "bytes":
            decoder.feed(event.data, event.t)
            for report in decoder.take_command_reports():
                if report.outcome in REFUSED and report.event_time_us is not None:
                    refused.append(report.event_time_us)
    return refused


def test_sitl_verify_with_timed_commands_sent_too_late_fails_naming_them(
    sitl_binary: Path, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """Lead 0: each timed command is due when it is sent, so the FC takes it after its time
    and applies it late. The run fails, and says so: the late commands, how many, how late.
    Timed commands go out once the clock locks (`LOCK_SPAN_S`, 4 s); the run is long enough
    for a host stall's re-anchor and the lock again after it (`RELOCK_S`), as its sibling's."""
    code, live, err = verify_json(
        capsys, "sitl", "--binary", str(sitl_binary), "--workdir", str(tmp_path / "fc"),
        "--port-base", str(free_port_base()), "--no-motion", "--uplink", "--uplink-lead", "0",
        "--verify", "12",
    )  # fmt: skip
    assert code == 1, err
    checks = {check["name"]: check for check in live["verdict"]["checks"]}
    assert "timed commands late" in checks, (err, re_anchors(tmp_path / "fc" / "sitl.log"))
    late = checks["timed commands late"]
    assert not late["passed"] and late["value"] > 90, late
    assert live["timed"]["outcomes"]["LATE"] >= 20  # 50 Hz once the clock locked
    error = err.strip().splitlines()[-1]
    assert error.startswith("error: stream verification failed: ") and "Traceback" not in err
    assert f"timed commands late: {late['value']:g} % (limit ≤ 1 %): " in error, error
    assert " applied late, the latest " in error


def test_a_lead_the_fc_would_refuse_is_said_in_one_line(
    sitl_binary: Path, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """A lead of 100 ms (the option allows up to 150) on an FC whose command timeout is 50 ms
    (`fsp_cmd_timeout_ms`, E3): it would refuse every timed command as too far ahead. The
    run stops once the FC says its timeout, with one line naming both (exit 2)."""
    code, out, err = run_cli(
        capsys, "sitl", "--binary", str(sitl_binary), "--workdir", str(tmp_path / "fc"),
        "--port-base", str(free_port_base()), "--no-motion", "--uplink", "--uplink-lead", "100",
        "--verify", "6",
    )  # fmt: skip
    assert code == 2, out + err
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1] == (
        "error: the uplink lead of 100 ms is at least the FC's command timeout (50 ms, "
        "fsp_cmd_timeout_ms): the FC refuses every timed command due that far ahead; lead by "
        "less than 50 ms"
    )


def test_an_uplink_lead_out_of_range_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    for lead in ("-1", "200", "nan"):
        code, _, err = run_cli(
            capsys, "verify", "--stream", "--port", "loop://", "--uplink", "--uplink-lead", lead
        )
        assert code == 2 and "--uplink-lead must be 0 to 150 ms" in err, err
        assert "Traceback" not in err
    code, _, err = run_cli(capsys, "verify", "--stream", "--port", "loop://", "--uplink-lead", "5")
    assert code == 2 and "send the pattern too" in err, err
