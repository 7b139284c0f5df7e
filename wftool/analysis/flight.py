"""A synthetic flight for the accelerometer RPM filter: what the IMU would see (motor
vibration, the vehicle's motion, sensor noise), in parts kept apart (docs/analysis.md).

    flight = synthesize(FlightSpec(), sample_rate_hz=800)
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

MOTORS = 4
HARMONICS = 3
BAND_HZ = (0.5, 55.0)


@dataclass(frozen=True)
class FlightSpec:
    """The synthetic flight's parameters (defaults: the evaluation's flight)."""

    duration_s: float = 30.0
    start_hz: float = 100.0
    end_hz: float = 400.0
    hold_s: float = 1.0
    """At the start and at the end the fundamentals hold still."""
    motor_ratio: tuple[float, ...] = (0.97, 0.99, 1.01, 1.03)
    wobble: float = 0.02
    """Relative amplitude of each motor's 0.7 Hz speed wobble (the control loop at work)."""
    vibration_g: tuple[float, ...] = (0.5, 0.25, 0.12)
    """Vibration amplitude per harmonic, in g, per motor and axis at a 200 Hz fundamental."""
    motion_band_g: float = 0.05
    """RMS per axis of the flat motion band (0.5–55 Hz: it covers the 1–50 Hz evaluated)."""
    noise_g_per_sqrt_hz: float = 160e-6
    """BMI270 accelerometer noise density."""
    seed: int = 11

    def as_dict(self) -> dict[str, object]:
        return asdict(self)


@dataclass(frozen=True)
class Flight:
    """One synthetic flight at one sample rate; accelerations in g, N samples × 3 axes."""

    spec: FlightSpec
    sample_rate_hz: int
    time_s: np.ndarray
    motor_hz: np.ndarray
    """N × 4 motor fundamentals (what bidirectional DShot reports)."""
    motion: np.ndarray
    """Gravity and manoeuvres (the signal an estimator wants)."""
    band: np.ndarray
    """The flat 0.5–55 Hz part of the motion (also inside `motion`)."""
    vibration: np.ndarray
    """HARMONICS × N × 3: each harmonic's vibration, all motors summed."""
    tones: np.ndarray
    """HARMONICS × N × 3: the same tones at 1 g per motor and axis, for attenuation figures
    that weigh every moment of the flight alike (vibration grows with speed squared)."""
    noise: np.ndarray
    harmonic_present: np.ndarray = field(repr=False)
    """HARMONICS × N: whether harmonic k of at least one motor lies below fs/2."""

    @property
    def raw(self) -> np.ndarray:
        """What the accelerometer delivers: motion + vibration + noise."""
        return self.motion + self.vibration.sum(axis=0) + self.noise

    @property
    def mean_fundamental_hz(self) -> np.ndarray:
        return self.motor_hz.mean(axis=1)


def fundamental_profile(spec: FlightSpec, time_s: np.ndarray) -> np.ndarray:
    """The mean fundamental over time: hold, linear sweep, hold."""
    sweep_s = max(spec.duration_s - 2 * spec.hold_s, 1e-9)
    progress = np.clip((time_s - spec.hold_s) / sweep_s, 0.0, 1.0)
    return spec.start_hz + (spec.end_hz - spec.start_hz) * progress


def synthesize(spec: FlightSpec, sample_rate_hz: int) -> Flight:
    """The flight sampled at SAMPLE_RATE_HZ (same motors, phases and gains at every rate)."""
    rng = np.random.default_rng(spec.seed)
    count = round(spec.duration_s * sample_rate_hz)
    time_s = np.arange(count) / sample_rate_hz
    base = fundamental_profile(spec, time_s)
    wobble_phase = rng.uniform(0, 2 * np.pi, MOTORS)
    ratios = np.asarray(spec.motor_ratio[:MOTORS])
    motor_hz = (
        base[:, None]
        * ratios[None, :]
        * (1 + spec.wobble * np.sin(2 * np.pi * 0.7 * time_s[:, None] + wobble_phase[None, :]))
    )
    rotation = 2 * np.pi * np.cumsum(motor_hz, axis=0) / sample_rate_hz  # rotor angle, rad

    # per motor, harmonic and axis: a fixed phase and a gain (mount and arm geometry)
    phases = rng.uniform(0, 2 * np.pi, (MOTORS, HARMONICS, 3))
    gains = rng.uniform(0.5, 1.0, (MOTORS, HARMONICS, 3))
    vibration = np.zeros((HARMONICS, count, 3))
    tones = np.zeros((HARMONICS, count, 3))
    present = np.zeros((HARMONICS, count), dtype=bool)
    for harmonic in range(HARMONICS):
        order = harmonic + 1
        for motor in range(MOTORS):
            frequency = order * motor_hz[:, motor]
            below = anti_alias_gain(frequency, sample_rate_hz)
            present[harmonic] |= below > 0
            amplitude = spec.vibration_g[harmonic] * (motor_hz[:, motor] / 200.0) ** 2
            for axis in range(3):
                tone = below * np.sin(order * rotation[:, motor] + phases[motor, harmonic, axis])
                tones[harmonic, :, axis] += tone
                vibration[harmonic, :, axis] += gains[motor, harmonic, axis] * amplitude * tone

    band = np.stack([_flat_band(rng, count, sample_rate_hz, *BAND_HZ) for _ in range(3)], axis=1)
    band *= spec.motion_band_g / band.std(axis=0)
    manoeuvre = np.stack(
        [
            0.4 * np.sin(2 * np.pi * 0.3 * time_s) + 0.2 * np.sin(2 * np.pi * 1.1 * time_s + 1.0),
            0.3 * np.sin(2 * np.pi * 0.5 * time_s + 2.0) + 0.1 * np.sin(2 * np.pi * 2.3 * time_s),
            -1.0 + 0.3 * np.sin(2 * np.pi * 0.4 * time_s + 0.5),  # gravity and thrust changes
        ],
        axis=1,
    )
    noise = rng.normal(0.0, spec.noise_g_per_sqrt_hz * np.sqrt(sample_rate_hz / 2), (count, 3))
    return Flight(
        spec=spec,
        sample_rate_hz=sample_rate_hz,
        time_s=time_s,
        motor_hz=motor_hz,
        motion=manoeuvre + band,
        band=band,
        vibration=vibration,
        tones=tones,
        noise=noise,
        harmonic_present=present,
    )


def anti_alias_gain(frequency_hz: np.ndarray, sample_rate_hz: float) -> np.ndarray:
    """1 below 0.45 fs, a raised-cosine fade to 0 at 0.5 fs, 0 above."""
    start, stop = 0.45 * sample_rate_hz, 0.5 * sample_rate_hz
    progress = np.clip((frequency_hz - start) / (stop - start), 0.0, 1.0)
    return 0.5 * (1 + np.cos(np.pi * progress))


def _flat_band(
    rng: np.random.Generator, count: int, sample_rate_hz: float, low_hz: float, high_hz: float
) -> np.ndarray:
    """Gaussian noise with a flat spectrum between LOW_HZ and HIGH_HZ and nothing outside."""
    spectrum = np.fft.rfft(rng.normal(size=count))
    frequency = np.fft.rfftfreq(count, 1 / sample_rate_hz)
    spectrum[(frequency < low_hz) | (frequency > high_hz)] = 0
    return np.fft.irfft(spectrum, count)
