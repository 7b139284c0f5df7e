"""`wftool analyze accfilter`: the accelerometer RPM filter quantified with the firmware's own
code (attenuation, motion delay, CPU cost on the host and the Cortex-M7), its report and
Fig. 4's series (docs/analysis.md).
"""

from __future__ import annotations

import json
import statistics
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from wftool import __version__
from wftool.analysis import markdown, sources
from wftool.analysis.flight import BAND_HZ, HARMONICS, Flight, FlightSpec, synthesize
from wftool.analysis.harness import (
    FilterSettings,
    HostHarness,
    compile_host_library,
    host_flags,
)
from wftool.analysis.m7 import CLOCK_HZ, LONG_INSTRUCTIONS, M7_FLAGS, M7Harness, build_image
from wftool.analysis.spectrum import Panel, write_series
from wftool.stats import median

SETTLE_S = 0.5
"""Samples before this are left out of every figure (the filter starts from rest)."""
BIN_WIDTH_HZ = 50.0
MOTION_FREQUENCIES_HZ = (1.0, 2.0, 5.0, 10.0, 20.0, 50.0)
MOTION_RANGE_HZ = (1.0, 50.0)
WELCH_SECONDS = 2.0
TIMING_CHUNK = 500
"""Samples per timed chunk on the host."""
M7_WINDOWS = 4
M7_WINDOW_SAMPLES = 50


@dataclass(frozen=True)
class HostCost:
    update_ns_per_sample: float
    """accRpmFilterSetMotorFrequencies(), once per sample for all axes."""
    process_ns_per_sample_axis: float
    total_ns_per_sample_axis: float
    """(update + process) / 3: what one axis of one sample costs."""
    notch_ns: float
    """One svfNotchApply() (Betaflight's notch, one sample of one axis), the reference timed
    in the same run."""
    notches: float
    """The cost per sample and axis in svfNotchApply() calls (median of the chunks)."""
    repeats: int


@dataclass(frozen=True)
class M7Cost:
    update_instructions: float
    process_instructions: float
    cycles_per_sample: float
    us_per_sample: float
    cpu_percent: float
    """Share of the core at this sample rate."""
    max_deviation: float
    """Largest |emulated − host| output, relative to the input's peak."""


@dataclass(frozen=True)
class RateResult:
    sample_rate_hz: int
    attenuation_db: list[list[float | None]]
    """[harmonic][fundamental band]; None where that harmonic is above fs/2 (not sampled)."""
    vibration_reduction_db: float
    motion_gain_db: list[float]
    motion_phase_deg: list[float]
    motion_group_delay_ms: list[float]
    """At MOTION_FREQUENCIES_HZ."""
    group_delay_mean_ms: float
    group_delay_max_ms: float
    """Over MOTION_RANGE_HZ."""
    fixed_group_delay_ms: list[list[float]]
    """[operating point][MOTION_FREQUENCIES_HZ]: notches held at the flight's start, middle
    and end motor frequencies, by sine probes."""
    host: HostCost
    m7: M7Cost | None


@dataclass(frozen=True)
class ConfigResult:
    settings: FilterSettings
    rates: list[RateResult]


@dataclass
class Evaluation:
    """Everything `wftool analyze accfilter` reports."""

    provenance: dict[str, object]
    flight: FlightSpec
    bands_hz: list[tuple[float, float]]
    motion_frequencies_hz: list[float]
    configs: list[ConfigResult]
    m7_check: dict[str, Any] | None
    flights: dict[int, Flight] = field(default_factory=dict, repr=False)
    filtered: dict[tuple[str, int], np.ndarray] = field(default_factory=dict, repr=False)
    """(config name, rate) -> the filtered raw acceleration (for Fig. 4)."""

    def as_json(self) -> dict[str, object]:
        return {
            "provenance": self.provenance,
            "flight": self.flight.as_dict(),
            "bands_hz": [list(band) for band in self.bands_hz],
            "motion_frequencies_hz": self.motion_frequencies_hz,
            "settle_s": SETTLE_S,
            "m7_check": self.m7_check,
            "configs": [
                {
                    "settings": config.settings.as_dict(),
                    "rates": [asdict(rate) for rate in config.rates],
                }
                for config in self.configs
            ],
        }


def fundamental_bands(spec: FlightSpec) -> list[tuple[float, float]]:
    """BIN_WIDTH_HZ bands of the mean fundamental covering the sweep (one for a steady flight)."""
    low, high = sorted((spec.start_hz, spec.end_hz))
    edges = np.arange(low, high, BIN_WIDTH_HZ)
    if edges.size == 0:
        return [(float(low), float(high))]
    return [(float(edge), float(min(edge + BIN_WIDTH_HZ, high))) for edge in edges]


def evaluate(
    harness: HostHarness,
    configs: Sequence[FilterSettings],
    rates: Sequence[int],
    spec: FlightSpec,
    *,
    m7: M7Harness | None = None,
    repeat: int = 9,
    provenance: dict[str, object] | None = None,
    progress: Callable[[str], None] = lambda message: None,
) -> Evaluation:
    """Fly every configuration at every rate; the figures: docs/analysis.md."""
    bands = fundamental_bands(spec)
    flights = {rate: synthesize(spec, rate) for rate in rates}
    evaluation = Evaluation(
        provenance=dict(provenance or {}),
        flight=spec,
        bands_hz=bands,
        motion_frequencies_hz=list(MOTION_FREQUENCIES_HZ),
        configs=[],
        m7_check=m7_reference_check(m7) if m7 is not None else None,
        flights=flights,
    )
    for settings in configs:
        results = []
        for rate in rates:
            progress(f"{settings.name} at {rate} Hz")
            flight = flights[rate]
            results.append(_evaluate_rate(harness, settings, flight, bands, m7, repeat))
            evaluation.filtered[(settings.name, rate)] = _run(harness, settings, flight, flight.raw)
        evaluation.configs.append(ConfigResult(settings, results))
    return evaluation


def _evaluate_rate(
    harness: HostHarness,
    settings: FilterSettings,
    flight: Flight,
    bands: list[tuple[float, float]],
    m7: M7Harness | None,
    repeat: int,
) -> RateResult:
    settled = flight.time_s >= SETTLE_S
    fundamental = flight.mean_fundamental_hz
    attenuation: list[list[float | None]] = []
    for k in range(HARMONICS):
        tones_out = _run(harness, settings, flight, flight.tones[k])
        row: list[float | None] = []
        for index, (low, high) in enumerate(bands):
            last = index == len(bands) - 1
            in_band = (fundamental >= low) & (
                (fundamental <= high) if last else (fundamental < high)
            )
            mask = settled & in_band & flight.harmonic_present[k]
            row.append(_power_ratio_db(flight.tones[k][mask], tones_out[mask]))
        attenuation.append(row)
    vibration_out = np.stack(
        [_run(harness, settings, flight, flight.vibration[k]) for k in range(HARMONICS)]
    )
    noise_out = _run(harness, settings, flight, flight.noise)
    vibration_in = flight.vibration.sum(axis=0) + flight.noise
    reduction = _power_ratio_db(
        vibration_in[settled], (vibration_out.sum(axis=0) + noise_out)[settled]
    )
    band_out = _run(harness, settings, flight, flight.band)
    frequencies, response = motion_response(
        flight.band[settled], band_out[settled], flight.sample_rate_hz
    )
    gain_db, phase_deg, delay_ms = response_figures(frequencies, response)
    inside = (frequencies >= MOTION_RANGE_HZ[0]) & (frequencies <= MOTION_RANGE_HZ[1])
    points = operating_points(flight)
    return RateResult(
        sample_rate_hz=flight.sample_rate_hz,
        attenuation_db=attenuation,
        vibration_reduction_db=reduction or 0.0,
        motion_gain_db=_at(frequencies, gain_db),
        motion_phase_deg=_at(frequencies, phase_deg),
        motion_group_delay_ms=_at(frequencies, delay_ms),
        group_delay_mean_ms=float(delay_ms[inside].mean()),
        group_delay_max_ms=float(delay_ms[inside].max()),
        fixed_group_delay_ms=[
            [float(v) for v in fixed_group_delay_ms(harness, settings, flight.sample_rate_hz, m)]
            for m in points
        ],
        host=host_cost(harness, settings, flight, repeat),
        m7=m7_cost(m7, harness, settings, flight) if m7 is not None else None,
    )


def motion_response(
    motion_in: np.ndarray, motion_out: np.ndarray, sample_rate_hz: float
) -> tuple[np.ndarray, np.ndarray]:
    """H(f) = Σ Pxy / Σ Pxx over the axes (Welch, 2 s Hann segments): the effective response."""
    from scipy import signal  # here, not at import: scipy.signal takes a second to import

    segment = int(WELCH_SECONDS * sample_rate_hz)
    cross = sum(
        signal.csd(motion_in[:, a], motion_out[:, a], fs=sample_rate_hz, nperseg=segment)[1]
        for a in range(3)
    )
    frequencies, _ = signal.welch(motion_in[:, 0], fs=sample_rate_hz, nperseg=segment)
    power = sum(
        signal.welch(motion_in[:, a], fs=sample_rate_hz, nperseg=segment)[1] for a in range(3)
    )
    return frequencies, cross / power


def response_figures(
    frequencies: np.ndarray, response: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gain (dB), phase (degrees) and group delay (ms) of a response estimated from data.

    The group delay −dφ/dω is taken from an odd polynomial (f, f³, f⁵: the phase of a real
    filter is odd) fitted to the phase over the motion band, since differentiating the
    estimated phase bin by bin would amplify the estimate's scatter.
    """
    phase = np.unwrap(np.angle(response))
    band = (frequencies >= BAND_HZ[0]) & (frequencies <= BAND_HZ[1])
    powers = np.stack([frequencies**p for p in (1, 3, 5)], axis=1)
    coefficients, *_ = np.linalg.lstsq(powers[band], phase[band], rcond=None)
    slope = sum(p * c * frequencies ** (p - 1) for p, c in zip((1, 3, 5), coefficients))
    delay_s = -slope / (2 * np.pi)
    return 20 * np.log10(np.abs(response)), np.degrees(phase), 1e3 * delay_s


def operating_points(flight: Flight) -> list[np.ndarray]:
    """The motor frequencies at the flight's start, middle and end (wobble left out)."""
    spec = flight.spec
    ratios = np.asarray(spec.motor_ratio)
    middle = (spec.start_hz + spec.end_hz) / 2
    return [base * ratios for base in (spec.start_hz, middle, spec.end_hz)]


def fixed_group_delay_ms(
    harness: HostHarness,
    settings: FilterSettings,
    sample_rate_hz: int,
    motor_hz: Sequence[float] | np.ndarray,
    frequencies_hz: Sequence[float] = MOTION_FREQUENCIES_HZ,
    step_hz: float = 0.25,
) -> np.ndarray:
    """Group delay at each frequency, notches held at MOTOR_HZ: −Δφ/Δω of probes f ± STEP."""
    probes = [f + d for f in frequencies_hz for d in (-step_hz, step_hz)]
    phase = np.angle(sine_response(harness, settings, sample_rate_hz, motor_hz, probes))
    below, above = phase[0::2], phase[1::2]
    return 1e3 * -np.angle(np.exp(1j * (above - below))) / (2 * np.pi * 2 * step_hz)


def sine_response(
    harness: HostHarness,
    settings: FilterSettings,
    sample_rate_hz: int,
    motor_hz: Sequence[float] | np.ndarray,
    frequencies_hz: Sequence[float],
    seconds: float = 4.0,
) -> np.ndarray:
    """Complex gain at each probe frequency, the notches held at MOTOR_HZ (x axis probed).

    Each probe runs through a fresh filter; the first half is left to settle, and the
    second half is fitted (least squares) with a·sin + b·cos of the probe: H = a + jb.
    """
    count = int(seconds * sample_rate_hz)
    time_s = np.arange(count) / sample_rate_hz
    motors = np.tile(np.asarray(motor_hz, dtype=np.float64), (count, 1))
    half = slice(count // 2, count)
    gains = []
    for frequency in frequencies_hz:
        phase = 2 * np.pi * frequency * time_s
        acc = np.zeros((count, 3))
        acc[:, 0] = np.sin(phase)
        out = harness.filter(settings, sample_rate_hz, len(motor_hz)).run(motors, acc)[:, 0]
        basis = np.stack([np.sin(phase[half]), np.cos(phase[half])], axis=1)
        (a, b), *_ = np.linalg.lstsq(basis, out[half], rcond=None)
        gains.append(complex(a, b))
    return np.asarray(gains)


def host_cost(
    harness: HostHarness, settings: FilterSettings, flight: Flight, repeat: int
) -> HostCost:
    """Median wall times per sample of the filter's two functions and of the reference.

    The flight is timed in chunks of TIMING_CHUNK samples, each chunk's update, process
    and reference notch back to back, REPEAT times over: on a shared machine a chunk
    (tens of µs) is rarely preempted, and the medians over all chunks drop those that
    were. The ratio to svfNotchApply() is the median of the per-chunk ratios.
    """
    motors = np.ascontiguousarray(flight.motor_hz, dtype=np.float32)
    raw = np.ascontiguousarray(flight.raw, dtype=np.float32)
    update, process, notch, ratios = [], [], [], []
    for _ in range(repeat):
        host_filter = harness.filter(settings, flight.sample_rate_hz, motors.shape[1])
        samples = raw.copy()
        reference = raw.ravel().copy()
        for start in range(0, motors.shape[0] - TIMING_CHUNK + 1, TIMING_CHUNK):
            part = slice(start, start + TIMING_CHUNK)
            update.append(host_filter.time_update_ns(motors[part]) / TIMING_CHUNK)
            process.append(host_filter.time_process_ns(samples[part]) / (3 * TIMING_CHUNK))
            one = harness.time_notch_ns(reference[3 * start : 3 * (start + TIMING_CHUNK)])
            notch.append(one / (3 * TIMING_CHUNK))
            ratios.append((update[-1] / 3 + process[-1]) / notch[-1])
    update_ns, process_ns = median(update), median(process)
    return HostCost(
        update_ns_per_sample=update_ns,
        process_ns_per_sample_axis=process_ns,
        total_ns_per_sample_axis=update_ns / 3 + process_ns,
        notch_ns=median(notch),
        notches=median(ratios),
        repeats=repeat,
    )


def m7_cost(
    m7: M7Harness, harness: HostHarness, settings: FilterSettings, flight: Flight
) -> M7Cost:
    """Instructions and cycles per sample on the emulated M7, over windows across the flight.

    Each window starts from a fresh filter on both sides, and the emulated output is
    compared with the host's for the same samples.
    """
    raw = flight.raw
    motors = flight.motor_hz
    count = raw.shape[0]
    update_instructions, process_instructions, cycles = [], [], []
    deviation = 0.0
    for window in range(M7_WINDOWS):
        start = int(count * (window + 1) / (M7_WINDOWS + 1))
        part = slice(start, start + M7_WINDOW_SAMPLES)
        m7.setup(settings, flight.sample_rate_hz, motors.shape[1])
        emulated = []
        for motor_row, sample in zip(motors[part], raw[part]):
            update = m7.update(motor_row)
            filtered, process = m7.process(sample)
            emulated.append(filtered)
            update_instructions.append(update.instructions)
            process_instructions.append(process.instructions)
            cycles.append(update.cycles + process.cycles)
        host = harness.filter(settings, flight.sample_rate_hz, motors.shape[1])
        expected = host.run(motors[part], raw[part])
        peak = float(np.abs(raw[part]).max())
        deviation = max(deviation, float(np.abs(np.asarray(emulated) - expected).max()) / peak)
    cycles_per_sample = statistics.fmean(cycles)
    us = cycles_per_sample / CLOCK_HZ * 1e6
    return M7Cost(
        update_instructions=statistics.fmean(update_instructions),
        process_instructions=statistics.fmean(process_instructions),
        cycles_per_sample=cycles_per_sample,
        us_per_sample=us,
        cpu_percent=us * flight.sample_rate_hz / 1e4,
        max_deviation=deviation,
    )


def m7_reference_check(m7: M7Harness) -> dict[str, object]:
    """svfNotchApply(): executed instructions against its straight-line disassembly."""
    executed = m7.notch_apply().instructions
    listed = m7.image.straight_line_length("svfNotchApply")
    return {
        "function": "svfNotchApply",
        "executed_instructions": executed,
        "disassembly_instructions": listed,
        "agrees": executed == listed,
        "gcc": m7.image.gcc_version,
        "clock_hz": CLOCK_HZ,
        "cycle_model": "1 cycle per instruction, plus "
        + ", ".join(f"{extra} for {name}" for name, extra in LONG_INSTRUCTIONS.items()),
    }


def _run(
    harness: HostHarness, settings: FilterSettings, flight: Flight, acc: np.ndarray
) -> np.ndarray:
    host_filter = harness.filter(settings, flight.sample_rate_hz, flight.motor_hz.shape[1])
    return host_filter.run(flight.motor_hz, acc)


def _power_ratio_db(before: np.ndarray, after: np.ndarray) -> float | None:
    power_in = float(np.sum(np.square(before)))
    if power_in == 0.0:
        return None
    return float(10 * np.log10(max(float(np.sum(np.square(after))), 1e-30) / power_in))


def _at(frequencies: np.ndarray, values: np.ndarray) -> list[float]:
    return [float(np.interp(f, frequencies, values)) for f in MOTION_FREQUENCIES_HZ]


# ---- rendering -------------------------------------------------------------------------


def summary_rows(evaluation: Evaluation) -> list[dict[str, str]]:
    """One row per configuration and rate: the comparison table's cells, formatted."""
    rows = []
    for config in evaluation.configs:
        for rate in config.rates:
            m7 = rate.m7
            rows.append(
                {
                    "config": config.settings.name,
                    "fs Hz": str(rate.sample_rate_hz),
                    **{
                        f"H{k + 1} dB (worst/median)": _worst_median(rate.attenuation_db[k])
                        for k in range(HARMONICS)
                    },
                    "vibration dB": f"{rate.vibration_reduction_db:.1f}",
                    "phase @10/50 Hz °": (
                        f"{rate.motion_phase_deg[3]:.1f} / {rate.motion_phase_deg[5]:.1f}"
                    ),
                    "delay 1–50 Hz ms (mean/max)": (
                        f"{rate.group_delay_mean_ms:.3f} / {rate.group_delay_max_ms:.3f}"
                    ),
                    "host ns/sample/axis": (
                        f"{rate.host.total_ns_per_sample_axis:.1f} "
                        f"({rate.host.notches:.1f} notches)"
                    ),
                    "M7 µs/sample (CPU)": (
                        f"{m7.us_per_sample:.2f} ({m7.cpu_percent:.2f} %)" if m7 else "–"
                    ),
                }
            )
    return rows


def _worst_median(values: list[float | None]) -> str:
    present = [value for value in values if value is not None]
    if not present:
        return "–"
    return f"{max(present):.1f} / {median(present):.1f}"


def render_markdown(evaluation: Evaluation) -> str:
    """The report: provenance, the comparison table, attenuation against RPM, delay, cost."""
    lines = ["# Accelerometer RPM filter, quantified", ""]
    source = evaluation.provenance
    lines += [f"- {key}: `{value}`" for key, value in source.items()]
    spec = evaluation.flight
    lines += [
        f"- flight: {spec.duration_s:g} s, mean fundamental {spec.start_hz:g} → "
        f"{spec.end_hz:g} Hz, motors ×{', ×'.join(f'{r:g}' for r in spec.motor_ratio)}, "
        f"vibration {', '.join(f'{g:g}' for g in spec.vibration_g)} g (H1–H3 at 200 Hz, ∝ "
        f"speed²), seed {spec.seed}; the first {SETTLE_S:g} s are left out",
        "",
        "Configurations:",
        "",
    ]
    lines += [f"- **{c.settings.name}**: {c.settings.describe()}" for c in evaluation.configs]
    rows = summary_rows(evaluation)
    lines += [
        "",
        "## Summary",
        "",
        *markdown.table(list(rows[0]), [list(r.values()) for r in rows]),
    ]
    lines += [
        "",
        "Hk dB: output/input power of the k-th harmonic's vibration, worst and median over the "
        "fundamental bands below; vibration dB: all vibration and sensor noise together. "
        "Phase and group delay: the effective response to the 1–50 Hz motion band "
        "(cross-spectrum over the whole flight). Host: medians over 500-sample chunks of "
        "repeated runs; ×notches: that cost in svfNotchApply() calls timed in the same run.",
        "",
        "## Attenuation (dB) against the mean motor fundamental",
        "",
    ]
    bands = [
        f"{low:g}–{high:g} Hz ({60 * low:.0f}–{60 * high:.0f} rpm)"
        for low, high in evaluation.bands_hz
    ]
    body = []
    for config in evaluation.configs:
        for rate in config.rates:
            for k in range(HARMONICS):
                cells = ["–" if v is None else f"{v:.1f}" for v in rate.attenuation_db[k]]
                body.append([config.settings.name, str(rate.sample_rate_hz), f"H{k + 1}", *cells])
    lines += markdown.table(["config", "fs Hz", "harmonic", *bands], body)
    lines += [
        "",
        "## Motion band (what an estimator feels)",
        "",
        "flight: the effective response over the whole flight (cross-spectrum of the 0.5–55 Hz "
        "motion band with its filtered self; group delay from an odd polynomial fitted to the "
        "phase). held at F: notches fixed at the motors' frequencies for a mean fundamental F, "
        "group delay from sine probes at ±0.25 Hz.",
        "",
    ]
    freqs = [f"{f:g} Hz" for f in evaluation.motion_frequencies_hz]
    body = []
    for config in evaluation.configs:
        for rate in config.rates:
            points = [
                f"{p:g} Hz" for p in (spec.start_hz, (spec.start_hz + spec.end_hz) / 2, spec.end_hz)
            ]
            for label, values, fmt in (
                ("flight: gain dB", rate.motion_gain_db, "{:.3f}"),
                ("flight: phase °", rate.motion_phase_deg, "{:.2f}"),
                ("flight: group delay ms", rate.motion_group_delay_ms, "{:.3f}"),
                *(
                    (f"held at {point}: group delay ms", delays, "{:.3f}")
                    for point, delays in zip(points, rate.fixed_group_delay_ms)
                ),
            ):
                body.append(
                    [config.settings.name, str(rate.sample_rate_hz), label]
                    + [fmt.format(v) for v in values]
                )
    lines += markdown.table(["config", "fs Hz", "", *freqs], body)
    lines += ["", "## CPU cost", ""]
    check = evaluation.m7_check
    if check:
        lines += [
            f"Cortex-M7 (arm-none-eabi-gcc {check['gcc']}, Betaflight's STM32F7 flags, "
            f"emulated): {check['cycle_model']}, at {int(check['clock_hz']) / 1e6:g} MHz. "
            f"Count check: {check['function']} executed {check['executed_instructions']} "
            f"instructions, its disassembly has {check['disassembly_instructions']}.",
            "",
        ]
    body = []
    for config in evaluation.configs:
        for rate in config.rates:
            host, m7 = rate.host, rate.m7
            body.append(
                [
                    config.settings.name,
                    str(rate.sample_rate_hz),
                    f"{host.update_ns_per_sample:.1f}",
                    f"{host.process_ns_per_sample_axis:.1f}",
                    f"{host.notch_ns:.2f}",
                    f"{host.notches:.1f}",
                    f"{m7.update_instructions:.0f}" if m7 else "–",
                    f"{m7.process_instructions:.0f}" if m7 else "–",
                    f"{m7.cycles_per_sample:.0f}" if m7 else "–",
                    f"{m7.us_per_sample:.2f}" if m7 else "–",
                    f"{m7.cpu_percent:.2f}" if m7 else "–",
                    f"{m7.max_deviation:.1e}" if m7 else "–",
                ]
            )
    lines += markdown.table(
        [
            "config",
            "fs Hz",
            "host update ns/sample",
            "host process ns/sample/axis",
            "host notch ns",
            "×notches",
            "M7 update instr",
            "M7 process instr",
            "M7 cycles/sample",
            "M7 µs/sample",
            "M7 CPU %",
            "M7 output − host output (max)",
        ],
        body,
    )
    return "\n".join(lines) + "\n"


def write_report(evaluation: Evaluation, out_dir: Path) -> tuple[Path, Path]:
    """accfilter.md and accfilter.json in OUT_DIR."""
    out_dir.mkdir(parents=True, exist_ok=True)
    markdown, data = out_dir / "accfilter.md", out_dir / "accfilter.json"
    markdown.write_text(render_markdown(evaluation))
    data.write_text(json.dumps(evaluation.as_json(), indent=2) + "\n")
    return markdown, data


def run(
    project_dir: Path | None,
    settings: Sequence[FilterSettings],
    rates: Sequence[int],
    spec: FlightSpec,
    out_dir: Path,
    *,
    repeat: int = 9,
    with_m7: bool = True,
    progress: Callable[[str], None] = lambda message: None,
) -> tuple[Evaluation, list[Path]]:
    """`wftool analyze accfilter` as a call: the series' filter code (betaflight/ of the
    project, fetched and patched if needed) compiled for the host (and, `with_m7`, the
    Cortex-M7), evaluated, and written to `out_dir`: the report (.md, .json), then one
    acceleration series (.npz, `wftool.analysis.spectrum`) per rate, before and after the
    first configuration's filter. Returns the evaluation and the paths written."""
    tree = sources.patched_tree(project_dir)
    with tempfile.TemporaryDirectory(prefix="wftool-accfilter-") as scratch:
        filter_sources = sources.filter_sources(tree, Path(scratch))
        harness = HostHarness(compile_host_library(filter_sources, Path(scratch) / "host"))
        provenance: dict[str, object] = {
            "wftool": __version__,
            "betaflight revision": filter_sources.revision,
            "filter sources": ", ".join(str(p.relative_to(tree)) for p in filter_sources.sources),
            "filter sources sha256": filter_sources.sha256,
            "host flags": " ".join(host_flags(filter_sources)),
        }
        m7 = None
        if with_m7:
            gcc = sources.arm_gcc(project_dir)
            m7 = M7Harness(build_image(filter_sources, Path(scratch) / "m7", gcc))
            provenance["m7 flags"] = " ".join(
                [*M7_FLAGS, *(f"-D{d}" for d in filter_sources.defines)]
            )
            provenance["m7 compiler"] = f"{gcc} {m7.image.gcc_version}"
        evaluation = evaluate(
            harness, settings, rates, spec,
            m7=m7, repeat=repeat, provenance=provenance, progress=progress,
        )  # fmt: skip
    written = list(write_report(evaluation, out_dir))
    first = settings[0]
    for rate, flight in evaluation.flights.items():
        path = out_dir / f"flight-{rate}hz.npz"
        write_series(
            path,
            flight.time_s,
            flight.motor_hz,
            [
                Panel("raw", f"before the RPM filter ({rate} Hz)", flight.raw),
                Panel(
                    "filtered",
                    f"after the RPM filter ({first.name}: {first.describe()})",
                    evaluation.filtered[(first.name, rate)],
                ),
            ],
        )
        written.append(path)
    return evaluation, written
