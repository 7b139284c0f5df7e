"""Table 1 and Figs. 2–3: how regularly samples reach the OBC, FSP (the FC's capture times)
against the MSP baseline (reception times), per recording and its longest segment
(docs/analysis.md).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from wftool import __version__
from wftool.analysis import markdown
from wftool.analysis.published import PAPER, TABLE1
from wftool.errors import UsageError
from wftool.fc.msp import Cmd
from wftool.fsp.columns import StateColumns, decode_columns
from wftool.fsp.packets import SEQ_MODULUS
from wftool.recording import msp as msp_recording
from wftool.recording import reader as recording
from wftool.recording.events import EVENT_TOPIC
from wftool.stats import DEFINITION, Distribution, quantile

GAP_MIN_S = 0.2
GAP_INTERVALS = 50
"""An interval longer than this many expected intervals (and than `GAP_MIN_S`) is a gap."""
_MCAP_MAGIC = b"\x89MCAP0\r\n"


def interval_stats(deltas_us: np.ndarray) -> Distribution:
    """Mean, median, P1 and P99 of `deltas_us` (at least one), as `verify` summarises the
    FC intervals of a stream (`wftool.stats`)."""
    deltas = np.asarray(deltas_us, dtype=np.float64)
    if deltas.size == 0:
        raise ValueError("no intervals")
    return Distribution.of_sorted(np.sort(deltas), float(deltas.mean()))


def stats_json(stats: Distribution) -> dict[str, float | None]:
    return {
        "intervals": stats.count,
        "mean_us": stats.mean_us,
        "median_us": stats.p50_us,
        "p1_us": stats.p1_us,
        "p99_us": stats.p99_us,
        "spread_us": stats.spread_us,
        "rate_hz": stats.rate_hz,
    }


@dataclass(frozen=True)
class Segment:
    """A stretch of one stream without a reconnection, FC reset or gap."""

    start_s: float
    """From the recording's first sample."""
    duration_s: float
    samples: int
    stats: Distribution | None
    """None for a single sample."""
    cut: str
    """What ends it: "end", "reconnection", "FC reset" or "gap of … s"."""

    def as_json(self) -> dict[str, Any]:
        return {
            "start_s": self.start_s,
            "duration_s": self.duration_s,
            "samples": self.samples,
            "ends_with": self.cut,
            "stats": stats_json(self.stats) if self.stats else None,
        }


@dataclass(frozen=True)
class TimingSeries:
    """One recording's sample times: the analysed (longest) segment and all segments."""

    label: str
    source: str
    protocol: str
    """"FSP" or "MSP"."""
    clock: str
    """What the times are: "FC sample time" or "OBC reception time"."""
    expected_us: float | None
    times_s: np.ndarray
    """The analysed segment's sample times, s from its first sample."""
    deltas_us: np.ndarray
    """Its intervals that count (see `Samples.counts`), µs..."""
    delta_times_s: np.ndarray
    """... and when each ended, s from the segment's first sample."""
    stats: Distribution
    segments: list[Segment]
    analysed: int
    """Index of the analysed segment in `segments`."""
    notes: list[str] = field(default_factory=list)

    def as_json(self) -> dict[str, Any]:
        return {
            "label": self.label,
            "source": self.source,
            "protocol": self.protocol,
            "clock": self.clock,
            "expected_us": self.expected_us,
            "samples": int(self.times_s.size),
            "duration_s": float(self.times_s[-1]),
            "stats": stats_json(self.stats),
            "analysed_segment": self.analysed,
            "segments": [segment.as_json() for segment in self.segments],
            "notes": self.notes,
        }


@dataclass(frozen=True)
class Samples:
    """Sample times of one recording before cutting: per sample, its time (µs, float64:
    exact for FC times), its stream (connection) and its FC epoch; per interval between
    consecutive samples, whether it `counts`: False where it spans frames that never
    arrived (lost in transport or dropped on the FC, which `verify` leaves out too)."""

    protocol: str
    clock: str
    times_us: np.ndarray
    stream: np.ndarray
    epoch: np.ndarray
    counts: np.ndarray
    expected_us: float | None
    notes: list[str] = field(default_factory=list)


def load_timing(
    path: Path,
    expected_rate_hz: float | None = None,
    label: str | None = None,
    obc_clock: str | None = None,
) -> TimingSeries:
    """`path`'s sample intervals: a recording (FSP or MSP, a bag directory or MCAP file) or
    a raw FSP capture. Empty, damaged or foreign input is a one-line `UsageError`; a
    recording whose writer was killed is analysed as far as it goes, and says so.
    `obc_clock` (an FSP recording): the frames' capture times on the OBC clock as that
    estimator aligns them (`wftool.fsp.estimators`), instead of the FC's own."""
    samples = read_samples(path, obc_clock)
    expected_us = 1e6 / expected_rate_hz if expected_rate_hz else samples.expected_us
    return analyse(samples, str(path), label or f"{samples.protocol}: {path.name}", expected_us)


def read_samples(path: Path, obc_clock: str | None = None) -> Samples:
    """The sample times in `path`, whatever kind of input it is (see `load_timing`)."""
    if path.is_dir():
        return _recording_samples(path, obc_clock)
    try:
        with open(path, "rb") as handle:
            head = handle.read(len(_MCAP_MAGIC))
    except OSError as exc:
        raise UsageError(f"cannot read {path}: {exc.strerror or exc}") from None
    if not head:
        raise UsageError(f"{path} is empty")
    if head == _MCAP_MAGIC:
        return _recording_samples(path, obc_clock)
    if obc_clock is not None:
        raise UsageError(f"{path} is a capture without arrival times: no OBC clock to align")
    return _capture_samples(path)


def _recording_samples(path: Path, obc_clock: str | None = None) -> Samples:
    topics = recording.recording_topics(path)
    if EVENT_TOPIC in topics:
        reader = recording.RecordingReader(path)
        columns = recording.recording_columns(reader, obc_clock)
        if not len(columns):
            raise UsageError(f"{path} holds no FSP frames")
        expected_us = _rate_us(reader.metadata.get("expected_rate_hz"))
        samples = _fsp_samples(path, columns, expected_us, obc_clock)
    elif obc_clock is not None:
        raise UsageError(f"{path} is no FSP recording: no FC times to align to the OBC clock")
    elif msp_recording.EVENT_TOPIC in topics:
        reader = recording.RecordingReader(
            path, msp_recording.EVENT_TOPIC, msp_recording.METADATA_NAME
        )
        _, connections = msp_recording.msp_replies(reader)
        times = [
            np.array([r.t for r in replies if r.cmd == Cmd.RAW_IMU and not r.error]) * 1e6
            for replies in connections
        ]
        times = [t for t in times if t.size]
        if not times:
            raise UsageError(f"{path} holds no MSP_RAW_IMU replies")
        count = sum(t.size for t in times)
        samples = Samples(
            "MSP",
            "OBC reception time",
            np.concatenate(times),
            np.concatenate([np.full(t.size, i) for i, t in enumerate(times)]),
            np.zeros(count, np.int64),
            np.ones(count - 1, bool),
            _rate_us(reader.metadata.get("expected_rate_hz")),
        )
    else:
        raise UsageError(
            f"{path} is an MCAP file but no wftool recording (it has no "
            f"{EVENT_TOPIC} or {msp_recording.EVENT_TOPIC})"
        )
    span_us = float(np.nanmax(samples.times_us) - np.nanmin(samples.times_us))
    cut_short = reader.cut_short(span_us * 1e-6)
    if cut_short is not None:
        samples.notes.append(f"the recording was {cut_short}; analysed what it holds")
    return samples


def _capture_samples(path: Path) -> Samples:
    """A raw capture: the bytes of an FSP port, decoded as one read (FC times only)."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise UsageError(f"cannot read {path}: {exc.strerror or exc}") from None
    columns = decode_columns(data)
    if not len(columns):
        raise UsageError(
            f"{path} is neither a wftool recording nor an FSP capture "
            f"(no FSP frame in its {len(data)} bytes)"
        )
    return _fsp_samples(path, columns, None)


def _fsp_samples(
    path: Path, columns: StateColumns, expected_us: float | None, obc_clock: str | None = None
) -> Samples:
    """The frames of the packets the decoder booked (outliers are not the stream's), and
    which intervals are the FC's own: all within a packet; between packets, those of one
    epoch with, under E1, the next `seq` and no frame dropped between (as `verify`). With
    `obc_clock`, their times on the OBC clock (intervals from a frame not yet aligned do not
    count)."""
    booked = np.flatnonzero(~columns.outlier)
    if booked.size == 0:
        raise UsageError(f"{path}: no FSP packet follows the stream (all are outliers)")
    frames = (2 * booked[:, None] + np.arange(2)).reshape(-1)
    epoch, seq = columns.epoch[booked], columns.seq[booked].astype(np.int64)
    e1, drops = columns.e1[booked], columns.drops[booked]
    follows = (epoch[1:] == epoch[:-1]) & (
        ~(e1[1:] & e1[:-1])
        | (((seq[1:] - seq[:-1]) % SEQ_MODULUS == 1) & (drops[1:] == drops[:-1]))
    )
    counts = np.ones(frames.size - 1, bool)
    counts[1::2] = follows  # odd intervals run from one packet's second frame to the next's first
    notes = []
    if outliers := int(np.count_nonzero(columns.outlier)):
        notes.append(f"{outliers} outlier packet(s) (not following the stream) left out")
    clock, times = "FC sample time", columns.time_us[frames].astype(np.float64)
    if obc_clock is not None:
        clock, times = f"OBC time ({obc_clock})", columns.obc_time[frames] * 1e6
        aligned = np.isfinite(times)
        counts &= aligned[1:] & aligned[:-1]
        times = np.where(aligned, times, np.nan)
        if not aligned.any():
            raise UsageError(f"{path}: no frame has an OBC time (no arrival times recorded)")
    return Samples(
        "FSP",
        clock,
        times,
        np.zeros(frames.size, np.int64),
        np.repeat(epoch, 2),
        counts,
        expected_us,
        notes,
    )


def _rate_us(text: str | None) -> float | None:
    try:
        rate = float(text or "nan")
    except ValueError:
        return None
    return 1e6 / rate if rate > 0 else None


def analyse(samples: Samples, source: str, label: str, expected_us: float | None) -> TimingSeries:
    """Cut `samples` into segments and take the statistics of the longest (of the intervals
    that count)."""
    times = samples.times_us
    if times.size < 2:
        raise UsageError(f"{source}: fewer than two samples")
    deltas = np.diff(times)
    new_stream = np.diff(samples.stream) != 0
    reset = ~new_stream & (np.diff(samples.epoch) != 0)
    within = ~new_stream & ~reset
    counted = within & samples.counts
    median_us = float(np.median(deltas[counted])) if counted.any() else 0.0
    nominal_us = expected_us or median_us
    gap = within & (deltas > max(GAP_MIN_S * 1e6, GAP_INTERVALS * nominal_us))
    cuts = np.flatnonzero(new_stream | reset | gap)
    starts = np.concatenate([[0], cuts + 1])
    ends = np.concatenate([cuts + 1, [times.size]])
    segments = []
    for start, end, cut in zip(starts, ends, [*cuts, None]):
        part = deltas[start : end - 1][counted[start : end - 1]]
        if cut is None:
            reason = "end"
        elif new_stream[cut]:
            reason = "reconnection"
        elif reset[cut]:
            reason = "FC reset"
        else:
            reason = f"gap of {deltas[cut] * 1e-6:.3g} s"
        segments.append(
            Segment(
                float(times[start] - times[0]) * 1e-6,
                float(times[end - 1] - times[start]) * 1e-6,
                int(end - start),
                interval_stats(part) if part.size else None,
                reason,
            )
        )
    longest = max(range(len(segments)), key=lambda i: (segments[i].duration_s, -i))
    start, end = starts[longest], ends[longest]
    if segments[longest].stats is None:
        raise UsageError(f"{source}: no two consecutive samples without a cut between them")
    notes = list(samples.notes)
    if len(segments) > 1:
        causes = [s.cut for s in segments[:-1]]
        counts = {c: causes.count(c) for c in ("reconnection", "FC reset")}
        counts["gap"] = sum(c.startswith("gap") for c in causes)
        what = ", ".join(f"{n} {name}{'s' if n > 1 else ''}" for name, n in counts.items() if n)
        total = sum(s.duration_s for s in segments)
        notes.append(
            f"split at {what} into {len(segments)} segments; analysed the longest, "
            f"segment {longest + 1} ({segments[longest].duration_s:.1f} s of {total:.1f} s)"
        )
    left_out = int(np.count_nonzero(~samples.counts[start : end - 1]))
    if left_out:
        notes.append(
            f"{left_out} interval(s) spanning frames lost in transport or dropped on the FC "
            "left out of the analysed segment's statistics"
        )
    part = times[start:end]
    counted_here = samples.counts[start : end - 1]
    deltas_us = np.diff(part)[counted_here]
    times_s = (part - part[0]) * 1e-6
    return TimingSeries(
        label,
        source,
        samples.protocol,
        samples.clock,
        expected_us,
        times_s,
        deltas_us,
        times_s[1:][counted_here],
        interval_stats(deltas_us),
        segments,
        longest,
        notes,
    )


# -- Table 1 ----------------------------------------------------------------------------------

COLUMNS = (
    "recording", "time base", "samples", "expected (µs)", "mean (µs)", "median (µs)",
    "P1 (µs)", "P99 (µs)", "P99−P1 (µs)", "rate (Hz)",
)  # fmt: skip


def _us(value: float | None) -> str:
    return "—" if value is None else f"{value:.1f}"


def table_rows(series: list[TimingSeries], paper: bool = False) -> list[dict[str, str]]:
    """Table 1 as rows of strings (`COLUMNS`); with `paper`, each recording's row is
    followed by the paper's row for its protocol (`wftool.analysis.published`) and by ours
    minus the paper's."""
    rows = []
    for one in series:
        stats = one.stats
        ours = (
            one.expected_us, stats.mean_us, stats.p50_us, stats.p1_us, stats.p99_us,
            stats.spread_us, stats.rate_hz,
        )  # fmt: skip
        rows.append(
            dict(zip(COLUMNS, (one.label, one.clock, str(one.times_s.size), *map(_us, ours))))
        )
        published = TABLE1.get(one.protocol) if paper else None
        if published is None:
            continue
        figures = [*published.figures().values(), published.rate_hz]
        theirs = tuple(figure.value for figure in figures)
        paper_row = (f"{published.protocol}: the paper", published.setup, "—", *map(_us, theirs))
        rows.append(dict(zip(COLUMNS, paper_row)))
        differences = [None if a is None else a - b for a, b in zip(ours, theirs)]
        rows.append(
            dict(zip(COLUMNS, (f"{one.label} − the paper", "", "", *map(_signed, differences))))
        )
    return rows


def _signed(value: float | None) -> str:
    return "—" if value is None else f"{value:+.1f}"


def table_notes(series: list[TimingSeries], paper: bool = False) -> list[str]:
    """What the table's reader needs to know: cuts, and where the paper's values stand."""
    notes = [f"{one.label}: {note}" for one in series for note in one.notes]
    if paper:
        for protocol in dict.fromkeys(one.protocol for one in series):
            row = TABLE1.get(protocol)
            if row is not None:
                notes.append(
                    f"the paper's {protocol} row: {PAPER}, {row.expected_us.source} (ms, given "
                    f"to three decimals); its rate: {row.rate_hz.source}"
                )
    return notes


def render_markdown(series: list[TimingSeries], paper: bool = False) -> str:
    rows = table_rows(series, paper)
    lines = [
        "# Table 1: sample-interval statistics",
        "",
        "Intervals between consecutive samples: FSP by the FC's sample times, MSP by the "
        f"OBC's reception times of MSP_RAW_IMU replies. Percentiles: {DEFINITION}.",
        "",
        *markdown.table(COLUMNS, [list(row.values()) for row in rows], "ll" + "r" * 8),
    ]
    notes = table_notes(series, paper)
    if notes:
        lines += ["", *(f"- {note}" for note in notes)]
    return "\n".join(lines) + "\n"


def write_table(
    series: list[TimingSeries], out_dir: Path, stem: str = "timing", paper: bool = False
) -> tuple[Path, Path]:
    """`stem`.md and `stem`.json in `out_dir` (created); returns their paths."""
    markdown, data = out_dir / f"{stem}.md", out_dir / f"{stem}.json"
    document: dict[str, Any] = {
        "wftool": __version__,
        "percentile_method": DEFINITION,
        "gap_rule": {"min_s": GAP_MIN_S, "expected_intervals": GAP_INTERVALS},
        "recordings": [one.as_json() for one in series],
    }
    if paper:
        document["paper"] = {
            protocol: {
                "setup": row.setup,
                **{
                    name: {"value": figure.value, "source": figure.cite()}
                    for name, figure in {**row.figures(), "rate_hz": row.rate_hz}.items()
                },
            }
            for protocol, row in TABLE1.items()
        }
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        markdown.write_text(render_markdown(series, paper))
        data.write_text(json.dumps(document, indent=1) + "\n")
    except OSError as exc:
        raise UsageError(f"cannot write to {out_dir}: {exc.strerror or exc}") from None
    return markdown, data


# -- Figs. 2 and 3 ----------------------------------------------------------------------------

HISTOGRAM_BINS = 200
_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")


def _axis_top_us(series: list[TimingSeries]) -> float:
    """A shared axis end that shows every distribution's body and P99 (not every outlier)."""
    top = 0.0
    for one in series:
        p999 = quantile(np.sort(one.deltas_us), 0.999)
        top = max(top, 1.2 * p999, 1.5 * one.stats.p99_us, 2.0 * (one.expected_us or 0.0))
    return top or 1.0


def _save(figure: Any, out: Path) -> None:
    try:
        figure.savefig(out, dpi=120)
    except OSError as exc:
        raise UsageError(f"cannot write {out}: {exc.strerror or exc}") from None


def draw_histograms(series: list[TimingSeries], out: Path) -> None:
    """Fig. 2: one histogram of the intervals per recording, shared axis, log counts, with
    the mean, P1 and P99 (and the expected interval) marked."""
    from matplotlib.figure import Figure

    top = _axis_top_us(series)
    figure = Figure(figsize=(10, 1.2 + 2.6 * len(series)), layout="constrained")
    axes = figure.subplots(len(series), 1, sharex=True, squeeze=False)[:, 0]
    edges = np.linspace(0.0, top, HISTOGRAM_BINS + 1)
    for index, (ax, one) in enumerate(zip(axes, series)):
        stats = one.stats
        beyond = int(np.count_nonzero(one.deltas_us > top))
        ax.hist(np.clip(one.deltas_us, 0.0, top), bins=edges, color=_COLOURS[index % 6], alpha=0.8)
        ax.set_yscale("log")
        marks = [
            (stats.mean_us, "-", "black", f"mean {stats.mean_us:.1f} µs"),
            (stats.p1_us, "--", "dimgray", f"P1 {stats.p1_us:.1f} µs"),
            (stats.p99_us, "--", "crimson", f"P99 {stats.p99_us:.1f} µs"),
        ]
        if one.expected_us:
            marks.append((one.expected_us, ":", "green", f"expected {one.expected_us:.1f} µs"))
        for value, style, colour, text in marks:
            ax.axvline(value, linestyle=style, color=colour, linewidth=1.2, label=text)
        title = f"{one.label} — {one.clock}, {stats.count} intervals"
        if beyond:
            title += f" ({beyond} beyond {top:.0f} µs in the last bin)"
        ax.set_title(title, fontsize=10)
        ax.set_ylabel("count")
        ax.legend(loc="upper right", fontsize=8, framealpha=0.7)
    axes[-1].set_xlabel("interval between consecutive samples (µs)")
    axes[-1].set_xlim(0.0, top)
    figure.suptitle("Fig. 2: distribution of sample intervals", fontsize=11)
    _save(figure, out)


def draw_intervals(series: list[TimingSeries], out: Path) -> None:
    """Fig. 3: each interval against time, one panel per recording, shared axes."""
    from matplotlib.figure import Figure

    top = _axis_top_us(series)
    figure = Figure(figsize=(10, 1.2 + 2.4 * len(series)), layout="constrained")
    axes = figure.subplots(len(series), 1, sharey=True, squeeze=False)[:, 0]
    for index, (ax, one) in enumerate(zip(axes, series)):
        t = one.delta_times_s
        deltas = one.deltas_us
        over = deltas > top
        ax.plot(t[~over], deltas[~over], ".", markersize=1.5, color=_COLOURS[index % 6], zorder=3)
        if over.any():
            ax.plot(
                t[over], np.full(int(over.sum()), top), "^", markersize=3, color="crimson",
                label=f"{int(over.sum())} above {top:.0f} µs",
            )  # fmt: skip
        if one.expected_us:
            ax.axhline(
                one.expected_us, linestyle=":", color="green", linewidth=1.2, zorder=2,
                label=f"expected {one.expected_us:.1f} µs",
            )  # fmt: skip
        ax.set_title(f"{one.label} — {one.clock}", fontsize=10)
        ax.set_ylabel("interval (µs)")
        ax.set_xlim(0.0, float(one.times_s[-1]) or 1.0)
        ax.legend(loc="upper right", fontsize=8, framealpha=0.7)
    axes[0].set_ylim(0.0, top * 1.03)
    axes[-1].set_xlabel("time in the analysed segment (s)")
    figure.suptitle("Fig. 3: sample intervals over time", fontsize=11)
    _save(figure, out)
