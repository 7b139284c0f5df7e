"""The verify dashboard: one rich renderable built from a summary, the latest frame and verdict."""

from __future__ import annotations

from rich.console import Group, RenderableType
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from wftool.fsp import SensorFrame
from wftool.verify.criteria import Verdict
from wftool.verify.monitor import IntervalSummary, StreamSummary


def _num(value: float | None, fmt: str = ".1f") -> str:
    return "–" if value is None else format(value, fmt)


def _rates(summary: StreamSummary) -> Table:
    table = Table(title="Rate", title_justify="left", expand=True)
    for column in ("", "current", "average", "FC source", "expected"):
        table.add_column(column, justify="right")
    expected = summary.expected_rate_hz
    table.add_row(
        "frames/s",
        _num(summary.current_frame_rate_hz),
        _num(summary.frame_rate_hz),
        _num(summary.source_rate_hz),
        _num(expected),
    )
    table.add_row(
        "packets/s",
        _num(summary.current_frame_rate_hz / 2),
        _num(summary.packet_rate_hz),
        _num(summary.source_rate_hz / 2 if summary.source_rate_hz else None),
        _num(expected / 2 if expected else None),
    )
    return table


def _intervals(summary: StreamSummary) -> Table:
    table = Table(title="Intervals (µs)", title_justify="left", expand=True)
    for column in ("", "mean", "P1", "P50", "P99", "P99−P1", "count"):
        table.add_column(column, justify="right")

    def row(name: str, interval: IntervalSummary | None) -> None:
        if interval is None:
            table.add_row(name, *["–"] * 6)
            return
        table.add_row(
            name,
            _num(interval.mean_us),
            _num(interval.p1_us, ".0f"),
            _num(interval.p50_us, ".0f"),
            _num(interval.p99_us, ".0f"),
            _num(interval.spread_us, ".0f"),
            f"{interval.count:,}",
        )

    row("FC sample", summary.fc_interval)
    row("OBC arrival (packet)", summary.arrival_interval)
    return table


def _integrity(summary: StreamSummary) -> Text:
    rejected = "  ".join(f"{cause} {count}" for cause, count in summary.rejected.items())
    e1 = {True: "on", False: "off (loss inferred from time gaps)", None: "–"}[summary.e1]
    return Text.from_markup(
        f"[b]loss[/] {summary.lost_frames} frames ({summary.loss_pct:.3f} %)   "
        f"[b]FC drops[/] {summary.fc_drops}   [b]E1[/] {e1}\n"
        f"[b]rejected[/] {rejected}   (joining mid-stream: {summary.sync_rejected})\n"
        f"[b]FC resets[/] {summary.resets}   [b]clock wraps[/] {summary.wraps}   "
        f"[b]reconnects[/] {summary.reconnects}"
    )


def _clock(summary: StreamSummary) -> Text:
    clock = summary.clock
    if clock is None:
        return Text("clock alignment: –")
    state = "locked" if clock.locked else "acquiring"
    residual = "–" if clock.residual_s != clock.residual_s else f"{clock.residual_s * 1e3:+.3f} ms"
    return Text.from_markup(
        f"[b]clock[/] {state}   rate {clock.rate_ppm:+.1f} ppm   "
        f"offset {clock.offset_s:.6f} s   residual {residual}   "
        f"updates {clock.updates}   re-inits {clock.reinits}"
    )


def _values(frame: SensorFrame | None) -> Table:
    table = Table(title="Latest frame", title_justify="left", expand=True, show_header=False)
    table.add_column(style="bold")
    table.add_column()
    if frame is None:
        table.add_row("", "no frame yet")
        return table

    def vec(values, fmt: str) -> str:
        return "  ".join(format(v, fmt) for v in values)

    table.add_row("acc (g)", vec(frame.acc_g, "+.3f"))
    table.add_row("gyro (deg/s)", vec(frame.gyro_dps, "+8.2f"))
    table.add_row(
        "attitude (deg)", "roll {:+.1f}  pitch {:+.1f}  yaw {:.1f}".format(*frame.euler_deg)
    )
    table.add_row("RC", vec(frame.rc, "d") + "   (roll pitch yaw throttle aux3 aux4)")
    table.add_row("RPM", vec(frame.rpm, "d"))
    table.add_row("vbat (V)", f"{frame.vbat_v:.2f}")
    return table


def _uplink(summary: StreamSummary) -> Text | None:
    uplink = summary.uplink
    if uplink is None:
        return None
    return Text.from_markup(
        f"[b]uplink[/] sent {uplink.commands_sent} commands, {uplink.steps_sent} steps, "
        f"echoed {uplink.steps_echoed}   RTT P50 {_num(uplink.rtt_p50_ms)} ms  "
        f"P99 {_num(uplink.rtt_p99_ms)} ms  max {_num(uplink.rtt_max_ms)} ms"
    )


def _verdict(verdict: Verdict) -> Text:
    text = Text()
    text.append(
        "PASS" if verdict.passed else "FAIL", style="bold green" if verdict.passed else "bold red"
    )
    for check in verdict.checks:
        mark, style = ("✓", "green") if check.passed else ("✗", "red")
        text.append(f"\n {mark} ", style=style)
        text.append(check.describe())
    return text


def render(
    summary: StreamSummary, latest: SensorFrame | None, verdict: Verdict | None
) -> RenderableType:
    """The whole dashboard."""
    state = "[green]connected[/]" if summary.connected else "[red]disconnected[/]"
    parts: list[RenderableType] = [
        _rates(summary),
        _intervals(summary),
        _integrity(summary),
        _clock(summary),
        _values(latest),
    ]
    uplink = _uplink(summary)
    if uplink is not None:
        parts.append(uplink)
    if verdict is not None:
        parts.append(_verdict(verdict))
    title = f"FSP {summary.port} — {state} — {summary.duration_s:.1f} s — {summary.frames:,} frames"
    return Panel(Group(*parts), title=title, title_align="left")
