"""FC time on the OBC: unwrapping the FC's u32 `micros()` and aligning it to the OBC clock.

Spec §7–§8. `FcClock` turns the wrapping counter into 64-bit time and tells a wrap (every
~71.6 min, not a reset) from a reboot. `ClockEstimator` is the interface the decoder talks
to. `EnvelopeClockEstimator` (the default) follows the lower envelope of the (FC time, OBC
arrival) points, where the clock line lies because delays have a hard minimum;
`KalmanClockEstimator` is the paper's reference filter of spec §8.2, made wrap-proof by working
on unwrapped time. `estimators.make_estimator` picks one by name.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

if TYPE_CHECKING:
    import numpy as np

U32 = 1 << 32
_HALF_U32 = 1 << 31

RESET_SLACK_S = 1.0
"""How far the FC clock may run ahead of the OBC clock between two packets (read bursts)."""
RESET_SLACK_RATE = 1e-3
"""... plus this fraction of the OBC time elapsed (1000 ppm, beyond any crystal)."""
STEADY_STEP_US = int(RESET_SLACK_S * 1e6)
"""A step this small is forward without a wrap in between, after a gap shorter than ..."""
STEADY_GAP_S = 4000.0
"""... this, which leaves no room for a whole wrap (2^32 µs ≈ 4295 s). `FcClock` decides
nothing for such steps; the columnar decoder (`columns`) applies the same rule to arrays."""


class FcClock:
    """Unwraps FC `micros()` readings into monotonic 64-bit microseconds.

    A reading that is "behind" the previous one is a wrap when the OBC clock says enough time
    passed, and a reset (FC reboot) when the FC clock would have to have run faster than the
    OBC clock to get there. Without OBC times, a backwards step of more than half the
    counter's range is a reset and anything else is forward. A step that is not steady is a
    reset, too, when the caller knows the stream started over (`restarted`, from E1: see
    `decoder.restarted`): after more than 2^31 µs of uptime a reboot looks like a step ahead.
    """

    def __init__(self) -> None:
        self._last_raw: int | None = None
        self._last_time_us = 0
        self._last_obc: float | None = None
        self.wraps = 0
        self.resets = 0

    def unwrap(
        self, raw_us: int, obc_time: float | None = None, *, restarted: bool = False
    ) -> tuple[int, bool]:
        """(64-bit time of `raw_us`, whether a reset happened just before it)."""
        last_raw, last_obc = self._last_raw, self._last_obc
        self._last_raw, self._last_obc = raw_us, obc_time
        if last_raw is None:
            self._last_time_us = raw_us
            return raw_us, False
        delta = (raw_us - last_raw) % U32
        short_gap = obc_time is None or last_obc is None or obc_time - last_obc < STEADY_GAP_S
        if delta < STEADY_STEP_US and short_gap:  # a steady stream: nothing to decide
            time_us = self._last_time_us + delta
            if raw_us < last_raw:
                self.wraps += 1
            self._last_time_us = time_us
            return time_us, False
        if restarted:
            advance = None
        elif obc_time is None or last_obc is None:
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
    """Times the estimator started over on its own (a step of the FC→OBC mapping)."""
    steps: int = 0
    """Of those, steps it detected: the OBC clock jumped, or the FC clock stood still."""
    lock_time_s: float = math.nan
    """OBC seconds from the latest (re-)initialisation to lock; NaN while acquiring."""
    rejected: int = 0
    """Observations ignored: NaN or infinite OBC time, FC time not increasing, lone outliers."""
    uncertainty_s: float = math.nan
    """Rough error scale of the one-way line (excluding d_min), if the estimator knows one."""


class ClockEstimator(Protocol):
    """Maps FC time (unwrapped µs) to OBC time (s). Swap in a better one through this."""

    def observe(self, fc_time_us: int, obc_time: float) -> None:
        """One received packet: its FC send time and the OBC time it was read. Bad input
        (a NaN OBC time, an FC time not after the last) is counted and ignored."""

    def to_obc(self, fc_time_us: int) -> float | None:
        """The OBC time of an FC instant; None before the first observation."""

    def reset(self) -> None:
        """The FC rebooted (a new clock epoch): forget everything."""

    @property
    def state(self) -> ClockState: ...


@runtime_checkable
class RoundTripObserver(Protocol):
    """What an estimator offers to take two-way timing too (spec §8.3; not in FSP v5 yet).

    A command left the OBC at `obc_sent` and reached the FC at `fc_received_us`; the FC's
    reply left at `fc_sent_us` and was read at `obc_received`. The first half bounds the
    line from below, as one-way packets bound it from above.
    """

    def observe_round_trip(
        self, obc_sent: float, fc_received_us: int, fc_sent_us: int, obc_received: float
    ) -> None: ...


class KalmanClockEstimator:
    """The reference estimator (spec §8.2) on x = [α, β] with t_obc = α·t_fc + β.

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
        self._lock_time = math.nan
        self.reinits = 0

    def reset(self) -> None:
        self._origin = None

    def _initialise(self, fc_time_us: int, obc_time: float) -> None:
        self._origin = (fc_time_us, obc_time)
        self._alpha, self._beta = 1.0, 0.0
        self._p = [[self.P0[0], 0.0], [0.0, self.P0[1]]]
        self._since_init = 0
        self._updates = 0
        self._lock_time = math.nan

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
        if not self._updates:
            self._lock_time = t_o
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
            steps=self.reinits,  # it re-initialises on a residual > 0.5 s: a step
            lock_time_s=self._lock_time,
        )


@runtime_checkable
class BatchObserver(Protocol):
    """What an estimator offers to be told a run of packets at once (the columnar decoder).

    `track` gives exactly what `observe` of each packet in turn, each followed by `to_obc`
    of that packet's row of `at_us`, would give (NaN for None), leaving the estimator as
    they would: it is a faster way to say the same, not another estimate.
    """

    def track(self, fc_time_us: np.ndarray, obc_time: np.ndarray, at_us: np.ndarray) -> np.ndarray:
        """`fc_time_us` (int64) and `obc_time` (float64) per packet; `at_us` (int64, one
        row per packet) the FC instants to map after each; float64 like `at_us`."""
        ...


Point = tuple[int, float]
"""(u, v): FC µs since the anchor, and OBC µs since the anchor minus u."""


class SlidingLowerHull:
    """Points sorted by u in a sliding window, and their lower convex hull, kept up to date.

    `append` is Andrew's monotone chain step (amortised O(1)). `drop_before` removes old
    points; when the leftmost hull vertex goes, only the stretch up to the next vertex is
    rebuilt — a vertex of the hull of a set stays one for any subset that still holds it.
    Two-way timing can reuse it upside down: the upper hull is the lower hull of (u, −v).
    """

    def __init__(self, points: Iterable[Point] = ()) -> None:
        self.points: deque[Point] = deque()
        self.hull: list[Point] = []
        for point in points:
            self.append(point)

    def __len__(self) -> int:
        return len(self.points)

    @staticmethod
    def _push(hull: list[Point], point: Point) -> None:
        u, v = point
        while len(hull) >= 2:
            (u1, v1), (u2, v2) = hull[-2], hull[-1]
            if (u2 - u1) * (v - v1) - (v2 - v1) * (u - u1) > 0.0:  # a left turn: convex
                break
            hull.pop()
        hull.append(point)

    def append(self, point: Point) -> None:
        """Add a point right of all others."""
        self.points.append(point)
        self._push(self.hull, point)

    def drop_before(self, u: int) -> None:
        """Forget the points left of `u`."""
        points, hull = self.points, self.hull
        if not points or points[0][0] >= u:
            return
        while points and points[0][0] < u:
            points.popleft()
        keep = 0
        while keep < len(hull) and hull[keep][0] < u:
            keep += 1
        if keep:
            rebuilt: list[Point] = []
            if keep < len(hull):  # rebuild up to the first surviving vertex, keep the rest
                end = hull[keep][0]
                for point in points:
                    self._push(rebuilt, point)
                    if point[0] >= end:
                        break
                rebuilt += hull[keep + 1 :]
            self.hull = rebuilt

    def slope_at(self, u: float) -> float:
        """Slope of the hull edge over `u` (the ends' edges beyond them); NaN for one vertex."""
        hull = self.hull
        if len(hull) < 2:
            return math.nan
        i = 1
        while i < len(hull) - 1 and hull[i][0] < u:
            i += 1
        (u1, v1), (u2, v2) = hull[i - 1], hull[i]
        return (v2 - v1) / (u2 - u1)

    def intercept(self, slope: float) -> float:
        """The highest c with v ≥ c + slope · u for every point: the supporting line."""
        return min(v - slope * u for u, v in self.hull)


class EnvelopeClockEstimator:
    """The default estimator: the clock line is the lower envelope of the arrivals (spec §8.1).

    A one-way delay is the minimum transport delay d_min plus something non-negative
    (queueing, bursts, the wait for the next read), so every (FC time, OBC arrival) point lies
    on or above t_obc = rate · t_fc + offset + d_min and the fastest packets touch it. As in
    Moon, Skelly & Towsley (1999) and Zhang, Liu & Xia (2002) the line is a supporting line of
    the points' lower convex hull — below every point, at the least summed distance from them:
    the hull edge over the middle of a window that slides so the rate may drift. The window
    is sized from the link's scatter against a design drift (10 s on a clean link, ~60 s
    with 16 ms reads).

    Bounded and O(1) amortised: each BUCKET_S of FC time keeps only its lowest point and the
    window's hull is kept up to date incrementally (`SlidingLowerHull`). Between fits the line
    drops at once to any point below it, so it stays a lower bound of the data. Numbers are
    µs from an anchor taken at the first packet — u = FC µs (an exact int), v = OBC µs − u
    (the residual against rate 1) — so float64 keeps sub-ns resolution over days.

    Steps: once tracking, points far below the line (impossible for a positive delay) from
    STEP_READS distinct reads, or the line dropping as far within STEP_CONFIRM_S, are a
    backward step of the OBC clock; a lone such point is an outlier, rejected. From the first
    fit, STEP_READS consecutive buckets, from distinct reads, whose lowest point stays far
    above the line are a forward step (or the FC clock stood still); one read carrying many
    buckets is an OBC stall, not a step; no lock while such a run is open. The offset
    restarts from the points after the step, the rate from before it is kept (a property of
    the two crystals), and the step is counted. A step while the rate was still being learnt
    (the window spans it: the rate, or the offset the lock would take, is wrong) leaves no
    rate to keep: it is learnt again from the points after the step. Smaller
    steps than the thresholds pass as a change of delay: the line follows within a window,
    off by at most the step meanwhile. `reset` (FC reboot, reconnect) forgets everything.

    Two-way timing fits the same frame: a command sent at OBC t1 and received at FC t2 is a
    point (t2, t1) *below* the line, so the line lies between this hull and the upper hull of
    such points (a `SlidingLowerHull` of (u, −v)); their gap bounds the offset and their
    midpoint removes d_min.
    """

    BUCKET_S = 0.25
    WINDOW_S = (10.0, 120.0)
    """Shortest and longest window; in between it balances scatter against DRIFT_PPM_PER_MIN."""
    DRIFT_PPM_PER_MIN = 2.0
    """The rate drift the window is sized for (a warming crystal: ~1 ppm/min)."""
    SUPPORT_AT = 0.5
    """Where in the window the supporting line touches the hull (0 oldest, 1 newest)."""
    LOCK_SPAN_S = 4.0
    """The rate is trusted once it comes from this much data; steps are watched from then."""
    OFFSET_SPAN_S = 1.0
    """... and the offset from this much since the latest (re-)initialisation."""
    LOCK_UNCERTAINTY_S = 50e-6
    """Locked when, on top of that, the uncertainty is this small or the window is full."""
    MAX_RATE_PPM = 1000.0
    """Beyond any crystal: bounds the rate from a window shorter than LOCK_SPAN_S (noisy);
    from a long enough one it is what the data say (a virtual FC's clock may run off)."""
    STEP_BELOW_S = 0.25e-3
    """A point below the line by the larger of this and 4 × the uncertainty cannot be a
    delay: evidence of a backward step."""
    STEP_ABOVE_S = 0.5e-3
    """A bucket minimum above the line by the larger of this and 8 × the median height of
    bucket minima is evidence of a forward step."""
    STEP_READS = 3
    """Evidence from this many distinct reads makes a step: consecutive buckets above, or
    points below within STEP_CONFIRM_S."""
    STEP_CONFIRM_S = 0.5
    _PENDING_CAP = 64

    def __init__(self) -> None:
        self.reinits = 0
        self.steps = 0
        self.rejected = 0
        self._bucket_us = round(self.BUCKET_S * 1e6)
        self._window_us_range = (round(self.WINDOW_S[0] * 1e6), round(self.WINDOW_S[1] * 1e6))
        self._drift = self.DRIFT_PPM_PER_MIN / 60.0  # µs/s²
        self._lock_span_us = round(self.LOCK_SPAN_S * 1e6)
        self._offset_span_us = round(self.OFFSET_SPAN_S * 1e6)
        self._trust_us = self.STEP_READS * self._bucket_us
        self._max_slope = self.MAX_RATE_PPM * 1e-6
        self._pending: deque[tuple[int, float, float]] = deque()
        self._slopes: deque[tuple[int, float, bool]] = deque(maxlen=16)
        """(last u, slope, trusted) of recent fits: a step keeps a trusted rate from before it."""
        self.reset()

    def reset(self) -> None:
        self._x0: int | None = None
        self._y0 = 0.0
        self._slope = 0.0
        self._slopes.clear()
        self._rate_known = False
        self._rate_since_u = 0
        """Where the rate became known: a step seen before STEP_READS buckets more may lie
        within the window it came from (unseen then), so that rate is not kept through it."""
        self._rate_span_us = self._lock_span_us  # the window's own rate counts from this span
        self._window_us = self._window_us_range[1]
        self._above_us = self.STEP_ABOVE_S * 1e6
        self._below_us = -self.STEP_BELOW_S * 1e6
        self._restart([(0, 0.0)], 0, math.nan)

    def _restart(self, points: list[Point], u: int, obc_time: float) -> None:
        """A new epoch of the offset from `points` (sorted by u) at (u, obc_time); rate kept."""
        self._window = SlidingLowerHull(points)
        self._high: list[Point] = []
        self._pending.clear()
        self._epoch_u = points[0][0]
        self._epoch_obc = obc_time
        self._tracking = self._locked = False
        self._lock_time = math.nan
        self._fits = 0
        self._scatter: tuple[int, float, float] = (-1, math.nan, math.nan)
        """The median height (µs) at (fits, intercept): the line drops between fits too."""
        self._excess = 0.0
        self._drop_since, self._drop_u, self._dropped = obc_time, u, 0.0
        self._last_u = u
        self._new_bucket(u)
        slope = self._slope
        self._intercept = min(pv - slope * pu for pu, pv in points)

    def _new_bucket(self, u: int) -> None:
        self._bucket_end = (u // self._bucket_us + 1) * self._bucket_us
        self._best_key = math.inf
        self._best: Point | None = None

    def observe(self, fc_time_us: int, obc_time: float) -> None:
        if self._x0 is None:
            if math.isfinite(obc_time):
                self._x0, self._y0 = fc_time_us, obc_time
                self._restart([(0, 0.0)], 0, obc_time)
            else:
                self.rejected += 1
            return
        u = fc_time_us - self._x0
        if u <= self._last_u or not math.isfinite(obc_time):
            self.rejected += 1
            return
        self._last_u = u
        v = (obc_time - self._y0) * 1e6 - u
        if u >= self._bucket_end:
            self._close_bucket(u, obc_time)
        key = v - self._slope * u  # the point's height over a line of the current slope
        excess = self._excess = key - self._intercept
        if excess < 0.0:
            if self._tracking and self._dropping(u, v, obc_time, excess):
                return
            self._intercept = key
        if key < self._best_key:
            self._best_key = key
            self._best = (u, v)

    def _close_bucket(self, u: int, obc_time: float) -> None:
        best = self._best
        self._new_bucket(u)
        if best is None:
            return
        self._window.append(best)
        self._window.drop_before(best[0] - self._window_us)
        self._fit()
        self._expire(obc_time)
        # Watched while the rate is learnt too: a window spanning a step gives a wrong line.
        if best[1] - self._slope * best[0] - self._intercept <= self._above_us:
            self._high = []
        else:
            # One read may carry many buckets (the OBC stalled): only distinct reads count.
            high = self._high
            if not high or abs(sum(high[-1]) - sum(best)) > 1.0:  # u + v: arrival µs
                high.append(best)
            if len(high) >= self.STEP_READS:
                self._step(high, u, obc_time, high[0][0])
                return
        if not self._locked:
            self._check_lock(obc_time)

    def _fit(self) -> None:
        window = self._window
        first_u = window.points[0][0]
        span = window.points[-1][0] - first_u
        slope = self._slope
        last_u = window.points[-1][0]
        if len(window.hull) >= 2 and (span >= self._rate_span_us or not self._rate_known):
            slope = window.slope_at(first_u + self.SUPPORT_AT * span)
            if not self._rate_known and span >= self._rate_span_us:
                self._rate_known, self._rate_since_u = True, last_u
            if not self._rate_known:
                slope = max(-self._max_slope, min(self._max_slope, slope))
        self._slope = slope
        trusted = self._rate_known and last_u - self._rate_since_u >= self._trust_us
        self._slopes.append((last_u, slope, trusted))
        self._intercept = window.intercept(slope)
        self._fits += 1
        if self._fits % 16 == 0:
            self._size_window()

    def _size_window(self) -> None:
        """Noise ≈ 2m·√(B/W) (see `_uncertainty_us`), the bias of a drift D at the window's
        end D·W²/8: their squared sum is least at W⁵ = 64·m²·B / D²."""
        low, high = self._window_us_range
        median = self._median_height_us()
        best = (64.0 * median**2 * self.BUCKET_S / self._drift**2) ** 0.2
        self._window_us = max(low, min(high, round(best * 1e6)))
        self._above_us = max(self.STEP_ABOVE_S * 1e6, 8.0 * median)
        self._below_us = -max(self.STEP_BELOW_S * 1e6, 4.0 * self._uncertainty_us())

    def _check_lock(self, obc_time: float) -> None:
        window = self._window.points
        self._tracking = self._rate_known and (self._last_u - self._epoch_u >= self._offset_span_us)
        full = window[-1][0] - window[0][0] >= self._window_us - self._bucket_us
        settled = self._tracking and not self._high  # the newest bucket is no step's start
        if settled and (full or self._uncertainty_us() <= self.LOCK_UNCERTAINTY_S * 1e6):
            self._locked = True
            self._lock_time = obc_time - self._epoch_obc

    def _median_height_us(self) -> float:
        """How high the window's bucket minima sit above the line, typically (the scatter)."""
        fits, intercept, value = self._scatter
        if fits != self._fits or intercept != self._intercept:
            slope, intercept = self._slope, self._intercept
            heights = sorted(v - slope * u - intercept for u, v in self._window.points)
            value = heights[len(heights) // 2]
            self._scatter = (self._fits, intercept, value)
        return value

    def _uncertainty_us(self) -> float:
        """A scale for the line's error, from how high the window's lowest points sit above it.

        The line rests on the few lowest of K bucket minima. When their heights grow like δ²
        near zero (a delay density rising from zero, as with quantised reads), those few sit
        near 2/√K of the median height; for a density that jumps at zero (no reads) the error
        is smaller still, so this errs on the safe side.
        """
        return 2.0 * self._median_height_us() / math.sqrt(len(self._window))

    def _dropping(self, u: int, v: float, obc_time: float, excess: float) -> bool:
        """A point below the line: a step if far below, or if the line keeps dropping."""
        if excess < self._below_us:
            self._below(u, v, obc_time)
            return True
        if obc_time - self._drop_since > self.STEP_CONFIRM_S:
            self._drop_since, self._drop_u, self._dropped = obc_time, u, 0.0
        self._dropped += excess
        if self._dropped < self._below_us:
            self._step([(u, v)], u, obc_time, self._drop_u)
            return True
        return False

    def _expire(self, obc_time: float) -> None:
        """Points far below the line that found no company in time were outliers."""
        pending = self._pending
        while pending and obc_time - pending[0][2] > self.STEP_CONFIRM_S:
            pending.popleft()
            self.rejected += 1

    def _below(self, u: int, v: float, obc_time: float) -> None:
        self._expire(obc_time)
        pending = self._pending
        if len(pending) < self._PENDING_CAP:
            pending.append((u, v, obc_time))
        if len({t for _, _, t in pending}) >= self.STEP_READS:
            self._step([(pu, pv) for pu, pv, _ in pending], u, obc_time, pending[0][0])

    def _step(self, points: list[Point], u: int, obc_time: float, since_u: int) -> None:
        """Start over from `points` after a step first seen at `since_u`."""
        self.steps += 1
        self.reinits += 1
        kept = False
        for fit_u, slope, trusted in reversed(self._slopes):  # the rate before fits saw it
            if fit_u < since_u:
                kept = trusted
                if trusted:
                    self._slope = slope
                    self._rate_span_us = self._window_us  # kept until the new window is as long
                break
        if not kept:  # a rate learnt across the step, or none: learn it from the points after
            self._slope = 0.0
            self._rate_known = False
            self._rate_span_us = self._lock_span_us
        self._restart(points, u, obc_time)

    def track(self, fc_time_us: np.ndarray, obc_time: np.ndarray, at_us: np.ndarray) -> np.ndarray:
        """`BatchObserver.track`: runs of points that only lower the line or raise nothing
        are done by NumPy, each decision (a bucket's end, a point the tracked line drops
        to, a rejected point) by `observe` itself; the line after each packet is kept and
        `to_obc`'s formula applied to all at the end, so both give the same floats."""
        import numpy as np

        count = len(fc_time_us)
        out = np.full(at_us.shape, np.nan)
        lines, slopes = np.empty(count), np.empty(count)
        index = mapped = 0  # mapped: the first packet after which to_obc answers
        while index < count and self._x0 is None:  # the first point anchors u and v
            self.observe(int(fc_time_us[index]), float(obc_time[index]))
            lines[index], slopes[index] = self._intercept, self._slope
            index += 1
            mapped = index - (self._x0 is not None)
        if self._x0 is None:
            return out
        x0, y0 = self._x0, self._y0
        u = fc_time_us - x0
        v = (obc_time - y0) * 1e6 - u
        # A point is surely accepted when its time is finite and u beats every u before it.
        before = np.maximum.accumulate(np.concatenate(([self._last_u], u[:-1])))
        irregular = np.flatnonzero(~np.isfinite(obc_time) | (u <= before)).tolist()
        irregular.append(count)
        next_irregular = 0
        while index < count:
            while irregular[next_irregular] < index:
                next_irregular += 1
            stop = irregular[next_irregular]
            # Within [index, end) u rises and stays inside the open bucket.
            end = index + int(np.searchsorted(u[index:stop], self._bucket_end))
            slope, intercept = self._slope, self._intercept
            if end > index and self._tracking:
                # The first point below the line makes a decision: run up to it.
                key = v[index:end] - slope * u[index:end]
                below = np.flatnonzero(key < intercept)
                if len(below):
                    end = index + int(below[0])
                    key = key[: end - index]
            if end == index:  # a decision, or an irregular point: the per-point path
                self.observe(int(fc_time_us[index]), float(obc_time[index]))
                lines[index], slopes[index] = self._intercept, self._slope
                index += 1
                continue
            if self._tracking:
                run = np.full(end - index, intercept)
            else:
                key = v[index:end] - slope * u[index:end]
                run = np.minimum.accumulate(np.minimum(key, intercept))
            self._last_u = int(u[end - 1])
            self._excess = float(key[-1] - (run[-2] if len(run) > 1 else intercept))
            self._intercept = float(run[-1])
            lowest = int(np.argmin(key))
            if key[lowest] < self._best_key:
                self._best_key = float(key[lowest])
                self._best = (int(u[index + lowest]), float(v[index + lowest]))
            lines[index:end], slopes[index:end] = run, slope
            index = end
        at = at_us[mapped:] - x0  # what to_obc computes, packet by packet
        out[mapped:] = y0 + ((at + lines[mapped:, None]) + slopes[mapped:, None] * at) * 1e-6
        return out

    def to_obc(self, fc_time_us: int) -> float | None:
        if self._x0 is None:
            return None
        u = fc_time_us - self._x0
        return self._y0 + (u + self._intercept + self._slope * u) * 1e-6

    @property
    def points(self) -> int:
        """Points held (window, open bucket, step candidates): bounded, however long the run."""
        return len(self._window) + (self._best is not None) + len(self._pending)

    @property
    def state(self) -> ClockState:
        if self._x0 is None:
            return ClockState(
                locked=False, rate_ppm=0.0, offset_s=math.nan, residual_s=math.nan, updates=0,
                reinits=self.reinits, steps=self.steps, rejected=self.rejected,
            )  # fmt: skip
        return ClockState(
            locked=self._locked,
            rate_ppm=self._slope * 1e6,
            offset_s=self._y0 + (self._intercept - (1.0 + self._slope) * self._x0) * 1e-6,
            residual_s=self._excess * 1e-6,
            updates=self._fits,
            reinits=self.reinits,
            steps=self.steps,
            lock_time_s=self._lock_time,
            rejected=self.rejected,
            uncertainty_s=self._uncertainty_us() * 1e-6,
        )
