"""Fig. 4: spectrograms of the acceleration of a recording or an `.npz` series, the motor
fundamentals drawn over them (the paper's STFT; the series format: docs/analysis.md).

    series = read_series(Path("run"))
    draw(series, spectrogram(series, "sum"), Path("fig4.png"))
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wftool.errors import UsageError

SERIES_FORMAT = "wftool.acc-series/1"
WINDOW_S = 0.2
OVERLAP = 0.5
AXIS_MODES = ("sum", "x", "y", "z", "norm")
"""sum: PSD of x + y + z (all vibration, whatever its direction); x/y/z: one axis;
norm: PSD of |a| (what a magnitude-based detector sees; mixes axes non-linearly)."""
DYNAMIC_RANGE_DB = 80.0
GAP_FACTOR = 5.0
"""A step between samples longer than this many median intervals is a gap."""

_MCAP_MAGIC = b"\x89MCAP0\r\n"
_ZIP_MAGIC = b"PK\x03\x04"


@dataclass(frozen=True)
class Panel:
    label: str
    title: str
    acc_g: np.ndarray
    """N × 3."""


@dataclass(frozen=True)
class AccSeries:
    """Uniformly sampled acceleration panels with the motor fundamentals."""

    source: str
    time_s: np.ndarray
    motor_hz: np.ndarray
    panels: list[Panel]
    notes: list[str] = field(default_factory=list)

    @property
    def sample_rate_hz(self) -> float:
        return (self.time_s.size - 1) / (self.time_s[-1] - self.time_s[0])


@dataclass(frozen=True)
class Spectrogram:
    frequencies_hz: np.ndarray
    times_s: np.ndarray
    power: np.ndarray
    """P × F × T power spectral density, g²/Hz."""
    axis: str

    def mean_db(self, panel: int) -> np.ndarray:
        """The panel's PSD averaged over time, dB re 1 g²/Hz."""
        return 10 * np.log10(self.power[panel].mean(axis=1) + 1e-30)


def read_series(path: Path) -> AccSeries:
    """A recording (MCAP file or rosbag2 directory) or an .npz series; anything else is a
    one-line UsageError."""
    if path.is_dir():
        return _read_recording(path)
    try:
        with open(path, "rb") as handle:
            head = handle.read(8)
    except OSError as exc:
        raise UsageError(f"cannot read {path}: {exc.strerror or exc}") from None
    if not head:
        raise UsageError(f"{path} is empty")
    if head.startswith(_MCAP_MAGIC):
        return _read_recording(path)
    if head.startswith(_ZIP_MAGIC):
        return _read_npz(path)
    raise UsageError(
        f"{path} is neither an MCAP recording nor a {SERIES_FORMAT} .npz acceleration series"
    )


def write_series(path: Path, time_s: np.ndarray, motor_hz: np.ndarray, panels: list[Panel]) -> None:
    """Write PANELS in the .npz series format (docs/analysis.md)."""
    arrays = {
        "format": np.array(SERIES_FORMAT),
        "time_s": np.asarray(time_s, dtype=np.float64),
        "motor_hz": np.asarray(motor_hz, dtype=np.float32),
        "panels": np.array([panel.label for panel in panels]),
        "titles": np.array([panel.title for panel in panels]),
    }
    for panel in panels:
        arrays[f"acc_{panel.label}_g"] = np.asarray(panel.acc_g, dtype=np.float32)
    with open(path, "wb") as handle:
        # numpy's stubs read the arrays' names as its own keywords (allow_pickle)
        np.savez_compressed(handle, **arrays)  # type: ignore[arg-type]


def _read_npz(path: Path) -> AccSeries:
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise UsageError(f"cannot read {path}: {exc}") from None
    if str(arrays.get("format", "")) != SERIES_FORMAT:
        raise UsageError(f"{path} is a .npz file but not a {SERIES_FORMAT} series (no format)")
    try:
        time_s = np.asarray(arrays["time_s"], dtype=np.float64)
        motor_hz = np.asarray(arrays["motor_hz"], dtype=np.float64)
        labels = [str(label) for label in arrays["panels"]]
        titles = [str(t) for t in arrays.get("titles", labels)]
        panels = [
            Panel(label, title, np.asarray(arrays[f"acc_{label}_g"], dtype=np.float64))
            for label, title in zip(labels, titles)
        ]
    except (KeyError, ValueError, TypeError) as exc:
        raise UsageError(f"{path}: {SERIES_FORMAT} series without {exc}") from None
    count = time_s.size
    if count < 2:
        raise UsageError(f"{path}: the series has fewer than two samples")
    if not panels:
        raise UsageError(f"{path}: the series has no acceleration panels")
    if motor_hz.ndim != 2 or motor_hz.shape[0] != count:
        raise UsageError(f"{path}: motor_hz must be N × motors for N = {count} samples")
    for panel in panels:
        if panel.acc_g.shape != (count, 3):
            raise UsageError(f"{path}: acc_{panel.label}_g must be {count} × 3")
    if count > 1:
        steps = np.diff(time_s)
        if np.any(steps <= 0) or steps.max() > 1.01 * steps.min():
            raise UsageError(f"{path}: time_s is not uniformly spaced")
    return AccSeries(str(path), time_s, motor_hz, panels)


def _read_recording(path: Path) -> AccSeries:
    """The recording's frames, decoded from its raw bytes by the columnar decoder."""
    from wftool.recording.reader import RecordingReader, recording_columns

    recording = RecordingReader(path)
    run = recording_columns(recording)
    booked = np.repeat(~run.outlier, 2)  # an outlier's time is no sample time
    if not booked.any():
        raise UsageError(f"{path} holds no FSP frames")
    acc_g = run.acc_g[booked]
    if np.isnan(acc_g).all():
        raise UsageError(f"{path}: the FSP frames carry no acceleration (acc_1g is 0)")
    time_s = run.time_us[booked] * 1e-6
    motors = run.rpm[booked] / 60.0
    series = _continuous(str(path), np.repeat(run.epoch, 2)[booked], time_s, acc_g, motors)
    cut_short = recording.cut_short(float(np.nanmax(time_s) - np.nanmin(time_s)))
    if cut_short is not None:
        series.notes.append(f"the recording was {cut_short}")
    return series


def _continuous(
    source: str, epochs: np.ndarray, time_s: np.ndarray, acc_g: np.ndarray, motor_hz: np.ndarray
) -> AccSeries:
    """The longest stretch without a gap or FC reset, resampled onto a uniform grid."""
    steps = np.diff(time_s)
    positive = steps[steps > 0]
    if positive.size == 0:
        raise UsageError(f"{source}: fewer than two distinct sample times")
    period = float(np.median(positive))
    breaks = np.flatnonzero((np.diff(epochs) != 0) | (steps <= 0) | (steps > GAP_FACTOR * period))
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks + 1, [time_s.size]])
    longest = int(np.argmax(time_s[ends - 1] - time_s[starts]))
    part = slice(starts[longest], ends[longest])
    notes = []
    if breaks.size:
        total = float(np.sum(time_s[ends - 1] - time_s[starts]))
        kept = float(time_s[ends[longest] - 1] - time_s[starts[longest]])
        notes.append(
            f"{breaks.size} gap(s)/FC reset(s): showing the longest continuous stretch, "
            f"{kept:.1f} s of {total:.1f} s"
        )
    t = time_s[part]
    grid = t[0] + period * np.arange(int((t[-1] - t[0]) / period) + 1)
    acc = np.stack([np.interp(grid, t, acc_g[part, a]) for a in range(3)], axis=1)
    motors = (
        np.stack([np.interp(grid, t, motor_hz[part, m]) for m in range(motor_hz.shape[1])], axis=1)
        if motor_hz.size
        else np.zeros((grid.size, 0))
    )
    panel = Panel("fsp", "FSP acceleration (as streamed: after the FC's RPM filter)", acc)
    return AccSeries(source, grid - grid[0], motors, [panel], notes)


def spectrogram(series: AccSeries, axis: str = "sum") -> Spectrogram:
    """The STFT power of every panel: 0.2 s Hann windows, 50 % overlap."""
    from scipy import signal

    if axis not in AXIS_MODES:
        raise UsageError(f"axis must be one of {', '.join(AXIS_MODES)}")
    rate = series.sample_rate_hz
    segment = round(WINDOW_S * rate)
    if series.time_s.size < segment or segment < 4:
        raise UsageError(
            f"{series.source}: {series.time_s.size} samples at {rate:.0f} Hz is shorter than "
            f"one {WINDOW_S:g} s window"
        )
    powers = []
    for panel in series.panels:
        if axis == "norm":
            channels = [np.linalg.norm(panel.acc_g, axis=1)]
        elif axis == "sum":
            channels = [panel.acc_g[:, a] for a in range(3)]
        else:
            channels = [panel.acc_g[:, "xyz".index(axis)]]
        total = None
        for channel in channels:
            frequencies, times, power = signal.spectrogram(
                np.nan_to_num(channel),
                fs=rate,
                window="hann",
                nperseg=segment,
                noverlap=int(segment * OVERLAP),
                detrend="constant",
                scaling="density",
                mode="psd",
            )
            total = power if total is None else total + power
        assert total is not None  # every axis mode has a channel
        powers.append(total)
    return Spectrogram(frequencies, times + series.time_s[0], np.stack(powers), axis)


def dominant_peaks(spec: Spectrogram, panel: int, count: int = 3) -> list[tuple[float, float]]:
    """The COUNT strongest peaks of the time-averaged spectrum: (Hz, dB), strongest first.

    Peaks more than DYNAMIC_RANGE_DB below the strongest bin are numerical dust, not peaks.
    """
    from scipy import signal

    level = spec.mean_db(panel)
    level[spec.frequencies_hz < 1.5 / WINDOW_S] = level.min()  # not the DC bins
    indices, _ = signal.find_peaks(level, prominence=6.0)
    floor = level.max() - DYNAMIC_RANGE_DB
    ranked = sorted((i for i in indices if level[i] >= floor), key=lambda i: -level[i])[:count]
    return [(float(spec.frequencies_hz[i]), float(level[i])) for i in ranked]


def draw(series: AccSeries, spec: Spectrogram, out: Path) -> None:
    """Fig. 4 as a PNG: one spectrogram per panel, one colour scale, fundamentals overlaid."""
    from matplotlib.figure import Figure

    count = len(series.panels)
    figure = Figure(figsize=(10, 1.0 + 3.2 * count), layout="constrained")
    axes = figure.subplots(count, 1, sharex=True, sharey=True, squeeze=False)[:, 0]
    level = 10 * np.log10(spec.power + 1e-30)
    top = float(level.max())
    image = None
    stride = max(1, series.time_s.size // 4000)
    for index, (ax, panel) in enumerate(zip(axes, series.panels)):
        image = ax.pcolormesh(
            spec.times_s,
            spec.frequencies_hz,
            level[index],
            shading="nearest",
            cmap="magma",
            vmin=top - DYNAMIC_RANGE_DB,
            vmax=top,
            rasterized=True,
        )
        for motor in range(series.motor_hz.shape[1]):
            line = np.where(
                series.motor_hz[::stride, motor] > 0, series.motor_hz[::stride, motor], np.nan
            )
            ax.plot(
                series.time_s[::stride],
                line,
                color="cyan",
                linewidth=0.7,
                linestyle="--",
                alpha=0.9,
                label="motor fundamentals" if motor == 0 else None,
            )
        ax.set_title(panel.title, fontsize=10)
        ax.set_ylabel("frequency (Hz)")
        ax.set_ylim(0, spec.frequencies_hz[-1])
        if index == 0 and np.any(series.motor_hz > 0):
            ax.legend(loc="upper left", fontsize=8, framealpha=0.6)
    axes[-1].set_xlabel("time (s)")
    axes[-1].set_xlim(series.time_s[0], series.time_s[-1])
    axis_name = {"sum": "x + y + z", "norm": "|a|"}.get(spec.axis, spec.axis)
    figure.suptitle(
        f"Acceleration spectrogram ({axis_name}; STFT, {WINDOW_S:g} s Hann, "
        f"{OVERLAP:.0%} overlap, {series.sample_rate_hz:.0f} Hz) — {Path(series.source).name}",
        fontsize=10,
    )
    assert image is not None  # a series has a panel
    figure.colorbar(image, ax=list(axes), label="PSD (dB re 1 g²/Hz)")
    try:
        figure.savefig(out, dpi=120)
    except OSError as exc:
        raise UsageError(f"cannot write {out}: {exc.strerror or exc}") from None
