"""FC time on the OBC: unwrapping the FC's u32 `micros()` and aligning it to the OBC clock.

Spec §7–§8. `FcClock` turns the wrapping counter into 64-bit time and tells a wrap (every
~71.6 min, not a reset) from a reboot. `ClockEstimator` is the interface the decoder talks
to; `KalmanClockEstimator` is the reference estimator of spec §8, made wrap-proof by working
on unwrapped time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

U32 = 1 << 32
_HALF_U32 = 1 << 31

RESET_SLACK_S = 1.0
"""How far the FC clock may run ahead of the OBC clock between two packets (read bursts)."""
RESET_SLACK_RATE = 1e-3
"""... plus this fraction of the OBC time elapsed (1000 ppm, beyond any crystal)."""
_ALWAYS_FORWARD_US = int(RESET_SLACK_S * 1e6)
"""A step this small is forward without a wrap in between, after a gap shorter than ..."""
_SHORT_GAP_S = 4000.0
"""... this, which leaves no room for a whole wrap (2^32 µs ≈ 4295 s)."""


class FcClock:
    """Unwraps FC `micros()` readings into monotonic 64-bit microseconds.

    A reading that is "behind" the previous one is a wrap when the OBC clock says enough time
    passed, and a reset (FC reboot) when the FC clock would have to have run faster than the
    OBC clock to get there. Without OBC times, a backwards step of more than half the
    counter's range is a reset and anything else is forward.
    """

    def __init__(self) -> None:
        self._last_raw: int | None = None
        self._last_time_us = 0
        self._last_obc: float | None = None
        self.wraps = 0
        self.resets = 0

    def unwrap(self, raw_us: int, obc_time: float | None = None) -> tuple[int, bool]:
        """(64-bit time of `raw_us`, whether a reset happened just before it)."""
        last_raw, last_obc = self._last_raw, self._last_obc
        self._last_raw, self._last_obc = raw_us, obc_time
        if last_raw is None:
            self._last_time_us = raw_us
            return raw_us, False
        delta = (raw_us - last_raw) % U32
        short_gap = obc_time is None or last_obc is None or obc_time - last_obc < _SHORT_GAP_S
        if delta < _ALWAYS_FORWARD_US and short_gap:  # a steady stream: nothing to decide
            time_us = self._last_time_us + delta
            if raw_us < last_raw:
                self.wraps += 1
            self._last_time_us = time_us
            return time_us, False
        if obc_time is None or last_obc is None:
            advance = delta if delta < _HALF_U32 else None
        else:
            elapsed_us = max(0.0, obc_time - last_obc) * 1e6
            bound = elapsed_us * (1.0 + RESET_SLACK_RATE) + RESET_SLACK_S * 1e6
            # The most whole wraps the OBC clock allows: a long gap may span several.
            advance = None if delta > bound else delta + int((bound - delta) // U32) * U32
        if advance is None:
            self.resets += 1
            self._last_time_us = raw_us
            return raw_us, True
        time_us = self._last_time_us + advance
        self.wraps += time_us // U32 - self._last_time_us // U32
        self._last_time_us = time_us
        return time_us, False


@dataclass(frozen=True)
class ClockState:
    """What an estimator believes, for display: t_obc = rate · t_fc + offset."""

    locked: bool
    """At least one measurement update since the last (re-)initialisation."""
    rate_ppm: float
    """(rate − 1) · 1e6: how much faster the OBC clock runs than the FC clock."""
    offset_s: float
    """OBC time at FC time zero of the current epoch."""
    residual_s: float
    """Measured minus predicted OBC time at the last update."""
    updates: int
    reinits: int


class ClockEstimator(Protocol):
    """Maps FC time (unwrapped µs) to OBC time (s). Swap in a better one through this."""

    def observe(self, fc_time_us: int, obc_time: float) -> None:
        """One received packet: its FC send time and the OBC time it was read."""

    def to_obc(self, fc_time_us: int) -> float | None:
        """The OBC time of an FC instant; None before the first observation."""

    def reset(self) -> None:
        """The FC rebooted: forget everything."""

    @property
    def state(self) -> ClockState: ...


class KalmanClockEstimator:
    """The reference estimator (spec §8) on x = [α, β] with t_obc = α·t_fc + β.

    Random-walk model Q = diag(1e-10, 1e-6), R = 1e-3, H = [t_fc, 1], times in seconds
    relative to the first packet; a measurement update with every 100th packet; it
    re-initialises when the residual exceeds 0.5 s. The spec leaves the initial covariance
    open: P0 = diag(1e-6, 1e-3) allows ±1000 ppm of skew and ±30 ms of first-packet delay.
    """

    Q = (1e-10, 1e-6)
    R = 1e-3
    UPDATE_EVERY = 100
    REINIT_RESIDUAL_S = 0.5
    P0 = (1e-6, 1e-3)

    def __init__(self) -> None:
        self._origin: tuple[int, float] | None = None
        self._alpha = 1.0
        self._beta = 0.0
        self._p = [[0.0, 0.0], [0.0, 0.0]]
        self._since_init = 0
        self._residual = math.nan
        self._updates = 0
        self.reinits = 0

    def reset(self) -> None:
        self._origin = None

    def _initialise(self, fc_time_us: int, obc_time: float) -> None:
        self._origin = (fc_time_us, obc_time)
        self._alpha, self._beta = 1.0, 0.0
        self._p = [[self.P0[0], 0.0], [0.0, self.P0[1]]]
        self._since_init = 0
        self._updates = 0

    def observe(self, fc_time_us: int, obc_time: float) -> None:
        if self._origin is None:
            self._initialise(fc_time_us, obc_time)
            return
        self._since_init += 1
        if self._since_init % self.UPDATE_EVERY:
            return
        t_f = (fc_time_us - self._origin[0]) * 1e-6
        t_o = obc_time - self._origin[1]
        (p00, p01), (p10, p11) = self._p
        p00 += self.Q[0]
        p11 += self.Q[1]
        residual = t_o - (self._alpha * t_f + self._beta)
        self._residual = residual
        if abs(residual) > self.REINIT_RESIDUAL_S:
            self.reinits += 1
            self._initialise(fc_time_us, obc_time)
            return
        # S = H P Hᵀ + R, K = P Hᵀ / S, P ← (I − K H) P
        ph0 = p00 * t_f + p01
        ph1 = p10 * t_f + p11
        s = t_f * ph0 + ph1 + self.R
        k0, k1 = ph0 / s, ph1 / s
        self._alpha += k0 * residual
        self._beta += k1 * residual
        self._p = [
            [p00 - k0 * ph0, p01 - k0 * ph1],
            [p10 - k1 * ph0, p11 - k1 * ph1],
        ]
        self._updates += 1

    def to_obc(self, fc_time_us: int) -> float | None:
        if self._origin is None:
            return None
        origin_fc, origin_obc = self._origin
        return origin_obc + self._alpha * (fc_time_us - origin_fc) * 1e-6 + self._beta

    @property
    def state(self) -> ClockState:
        offset = math.nan
        if self._origin is not None:
            offset = self._origin[1] + self._beta - self._alpha * self._origin[0] * 1e-6
        return ClockState(
            locked=self._origin is not None and self._updates > 0,
            rate_ppm=(self._alpha - 1.0) * 1e6,
            offset_s=offset,
            residual_s=self._residual,
            updates=self._updates,
            reinits=self.reinits,
        )
