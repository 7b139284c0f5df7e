"""The verify dashboard: one rich renderable built from a summary, the latest frame and verdict.

Laid out as fixed-width text rather than rich tables: it is redrawn four times a second
for as long as a run lasts, and text renders in a tenth of the time (about 1 ms), which
keeps verify well under its CPU budget.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from rich.console import Group, RenderableType
from rich.panel import Panel
from rich.text import Text

from wftool.display import printable
from wftool.fsp import SensorFrame, UplinkFlag, UplinkStatus
from wftool.verify.criteria import Verdict
from wftool.verify.monitor import OUTLIER, IntervalSummary, StreamSummary

LABEL = 21
CELL = 9
"""Label and cell widths: a label and six cells fit an 80-column terminal inside the panel."""


def _num(value: float | None, fmt: str = ".1f") -> str:
    return (
        "–"
        if value is None or (isinstance(value, float) and math.isnan(value))
        else format(value, fmt)
    )


def _row(label: str, cells: Iterable[str], style: str = "") -> Text:
    return Text(f"{label:<{LABEL}}" + "".join(f"{cell:>{CELL}}" for cell in cells), style=style)


def _section(title: str) -> Text:
    return Text(title, style="bold")


def _rates(summary: StreamSummary) -> list[Text]:
    expected, source = summary.expected_rate_hz, summary.source_rate_hz
    return [
        _section("Rate"),
        _row("", ("current", "average", "FC rate", "expected"), "dim"),
        _row(
            "frames/s",
            (
                _num(summary.current_frame_rate_hz),
                _num(summary.frame_rate_hz),
                _num(source),
                _num(expected),
            ),
        ),
        _row(
            "packets/s",
            (
                _num(summary.current_frame_rate_hz / 2),
                _num(summary.packet_rate_hz),
                _num(source / 2 if source else None),
                _num(expected / 2 if expected else None),
            ),
        ),
    ]


def _intervals(summary: StreamSummary) -> list[Text]:
    def row(name: str, interval: IntervalSummary | None) -> Text:
        if interval is None:
            return _row(name, ["–"] * 6)
        return _row(
            name,
            (
                _num(interval.mean_us),
                _num(interval.p1_us, ".0f"),
                _num(interval.p50_us, ".0f"),
                _num(interval.p99_us, ".0f"),
                _num(interval.spread_us, ".0f"),
                f"{interval.count:,}",
            ),
        )

    return [
        _section("Intervals (µs)"),
        _row("", ("mean", "P1", "P50", "P99", "P99−P1", "count"), "dim"),
        row("FC sample", summary.fc_interval),
        row("OBC arrival (packet)", summary.arrival_interval),
    ]


def _integrity(summary: StreamSummary) -> Text:
    rejected = "  ".join(
        f"{cause} {count}" for cause, count in summary.rejected.items() if cause != OUTLIER
    )
    e1 = {True: "on", False: "off (loss inferred from time gaps)", None: "–"}[summary.e1]
    return Text.from_markup(
        f"[b]loss[/] {summary.lost_frames} frames ({summary.loss_pct:.3f} %)   "
        f"[b]FC drops[/] {summary.fc_drops}   [b]E1[/] {e1}\n"
        f"[b]rejected[/] {rejected}  [b]outliers[/] {summary.rejected.get(OUTLIER, 0)}   "
        f"(cut by joining: {summary.sync_rejected})\n"
        f"[b]FC resets[/] {summary.resets}   [b]clock wraps[/] {summary.wraps}   "
        f"[b]reconnects[/] {summary.reconnects} ({summary.outage_s:.1f} s gone)"
    )


def _clock(summary: StreamSummary) -> Text:
    clock = summary.clock
    if clock is None:
        return Text(f"clock alignment ({summary.clock_estimator}): –")
    state = "locked" if clock.locked else "acquiring"
    if clock.locked and not math.isnan(clock.lock_time_s):
        state += f" in {clock.lock_time_s:.1f} s"
    return Text.from_markup(
        f"[b]clock[/] {summary.clock_estimator} {state}  rate {clock.rate_ppm:+.1f} ppm  "
        f"offset {clock.offset_s:.3f} s\n"
        f"  residual {_ms(clock.residual_s, '+.3f')}  ± {_ms(clock.uncertainty_s, '.3f')}  "
        f"re-inits {clock.reinits}  steps {clock.steps}  rejected {clock.rejected}"
    )


def _ms(seconds: float, fmt: str) -> str:
    return "–" if math.isnan(seconds) else f"{seconds * 1e3:{fmt}} ms"


def _values(frame: SensorFrame | None) -> list[Text]:
    if frame is None:
        return [_section("Latest frame"), Text("no frame yet")]

    def vec(values: Iterable[float], fmt: str) -> str:
        return "  ".join(format(v, fmt) for v in values)

    roll, pitch, yaw = frame.euler_deg
    lines = [
        ("acc (g)", vec(frame.acc_g, "+.3f")),
        ("gyro (deg/s)", vec(frame.gyro_dps, "+.2f")),
        ("attitude (deg)", f"roll {roll:+.1f}  pitch {pitch:+.1f}  yaw {yaw:.1f}"),
        ("RC (R P Y T A3 A4)", vec(frame.rc, "d")),
        ("RPM", vec(frame.rpm, "d")),
        ("vbat (V)", f"{frame.vbat_v:.2f}"),
    ]
    return [_section("Latest frame")] + [Text(f"{name:<{LABEL}}{text}") for name, text in lines]


def _uplink(summary: StreamSummary) -> Text | None:
    uplink = summary.uplink
    if uplink is None:
        return None
    return Text.from_markup(
        f"[b]uplink[/] sent {uplink.commands_sent} commands, {uplink.steps_sent} steps, "
        f"echoed {uplink.steps_echoed}   RTT P50 {_num(uplink.rtt_p50_ms)} ms  "
        f"P99 {_num(uplink.rtt_p99_ms)} ms  max {_num(uplink.rtt_max_ms)} ms"
    )


STALE_UPLINK_S = 0.5
"""An FC uplink status older than this is shown with its age: the FC sends one every 100 ms."""
UPLINK_FLAGS = (
    ("live", UplinkFlag.LIVE, "green"),
    ("override", UplinkFlag.OVERRIDE, "green"),
    ("OBC receiver", UplinkFlag.OBC_RECEIVER, "yellow"),
    ("RX loss", UplinkFlag.RX_LOSS, "bold red"),
    ("armed", UplinkFlag.ARMED, "yellow"),
    ("ARM switch held", UplinkFlag.ARM_SWITCH, "yellow"),
)
"""The flags of an uplink status as the dashboard names them, and the style of each when on."""


def who_flies(status: UplinkStatus) -> str:
    """Who flies (spec §15) in words, and why the OBC last lost it; "not reported" by
    firmware without the authority fields."""
    if status.authority is None:
        return "not reported by this firmware"
    words = status.authority.name.lower()
    if status.exit is not None and status.exit:
        words += f" (last exit: {status.exit.name.lower().replace('_', ' ')})"
    return words


def _fc_uplink(summary: StreamSummary) -> Text | None:
    """What the FC made of the commands (E3, spec §12), once it says."""
    report = summary.fc_uplink
    if report is None:
        return None
    status = report.status
    text = Text.from_markup(
        f"[b]FC uplink[/] accepted {status.accepted:,}  stale {status.stale:,}  "
        f"rejected {status.rejected:,}  timeouts {status.timeouts:,} "
        f"({status.timeout_ms} ms)"
    )
    age = summary.fc_uplink_age_s
    if age is not None and age > STALE_UPLINK_S:
        text.append(f"  as of {age:.1f} s ago", style="yellow")
    text.append("\n  on: ")  # only the flags that are: the line fits 80 columns
    on = [(name, style) for name, flag, style in UPLINK_FLAGS if status.has(flag)]
    for index, (name, style) in enumerate(on):
        text.append(name, style=style)
        text.append(", " if index < len(on) - 1 else "")
    if not on:
        text.append("–")
    phase = status.failsafe_phase_name
    text.append(f"   failsafe {phase}", style="" if status.failsafe_phase == 0 else "bold red")
    if status.authority is not None:
        text.append("\n  who flies: ")
        text.append(who_flies(status), style="green" if status.steering else "")
    return text


def _timed(summary: StreamSummary) -> Text | None:
    """When timed commands acted, by the FC's own reports (E4, spec §13)."""
    timed = summary.timed
    if timed is None:
        return None
    apply = timed.apply
    text = f"[b]timed[/] {timed.reports:,} reports: "
    if apply is None:
        text += "none applied on time"
    else:
        text += (
            f"applied − asked P1 {apply.p1_us:.0f} µs  P50 {apply.p50_us:.0f} µs  P99 "
            f"{apply.p99_us:.0f} µs  (P99−P1 {apply.spread_us:.0f} µs, {apply.count:,} on time)"
        )
    latest = "–" if timed.latest_us is None else f"{timed.latest_us / 1e3:.3f} ms"
    text += (
        f"\n  late {timed.late}  refused {timed.refused}  dropped {timed.dropped}  "
        f"reports lost {timed.lost_reports}  latest {latest}"
    )
    return Text.from_markup(text)


def _two_way(summary: StreamSummary) -> Text | None:
    """Round trips and the offset's uncertainty, when the FC answers commands (spec §10)."""
    trip, two_way = summary.round_trip, summary.two_way
    if trip is None:
        return None
    text = (
        f"[b]two-way[/] round trip P50 {trip.p50_us / 1e3:.3f} ms  P99 {trip.p99_us / 1e3:.3f} ms"
        f"  ({trip.count:,})"
    )
    if two_way is None:
        text += "   offset ± with --clock twoway"
    elif two_way.active:
        low, high = two_way.delay_bounds_s
        text += (
            f"   offset ± {_ms(two_way.uncertainty_s, '.3f')}\n"
            f"  d_min {_ms(two_way.delay_s, '.3f')} (between {_ms(low, '.3f')} and "
            f"{_ms(high, '.3f')})  steps {two_way.steps}"
        )
    else:
        text += "   offset: acquiring"
    if summary.round_trip_rejected:
        unused = "  ".join(f"{cause} {n}" for cause, n in summary.round_trip_rejected.items())
        text += f"\n  not used: {unused}"
    return Text.from_markup(text)


def _verdict(verdict: Verdict) -> Text:
    text = Text()
    text.append(
        "PASS" if verdict.passed else "FAIL", style="bold green" if verdict.passed else "bold red"
    )
    for check in verdict.checks:
        mark, style = ("✓", "green") if check.passed else ("✗", "red")
        text.append(f"\n {mark} ", style=style)
        text.append(printable(check.describe()))
    for note in verdict.notes:
        text.append(f"\n - {printable(note)}", style="yellow")
    return text


def render(
    summary: StreamSummary, latest: SensorFrame | None, verdict: Verdict | None
) -> RenderableType:
    """The whole dashboard."""
    state = ("connected", "green") if summary.connected else ("disconnected", "red")
    parts: list[RenderableType] = [
        *_rates(summary),
        Text(),
        *_intervals(summary),
        Text(),
        _integrity(summary),
        _clock(summary),
        Text(),
        *_values(latest),
    ]
    for line in (_uplink(summary), _fc_uplink(summary), _timed(summary), _two_way(summary)):
        if line is not None:
            parts += [Text(), line]
    if verdict is not None:
        parts += [Text(), _verdict(verdict)]
    title = Text.assemble(
        "FSP ",
        printable(summary.port),
        " — ",
        state,
        f" — {summary.duration_s:.1f} s — {summary.frames:,} frames",
    )
    return Panel(Group(*parts), title=title, title_align="left")
