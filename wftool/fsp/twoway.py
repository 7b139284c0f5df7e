"""Two-way timing (spec §10, E2): time replies paired with the commands they answer
(`RoundTripMatcher`), and the absolute FC→OBC clock they give (`TwoWayClockEstimator`,
`make_estimator("twoway")`). How the round trips bound the offset: docs/design.md.
"""

from __future__ import annotations

import enum
import heapq
import math
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace

from wftool.fsp.clock import ClockEstimator, ClockState, EnvelopeClockEstimator
from wftool.fsp.packets import SEQ_MODULUS, TimeReply


class RoundTripRejection(str, enum.Enum):
    """Why a time reply did not become a round trip, or a round trip was not used."""

    UNMATCHED = "unmatched"
    """It answers no command this OBC sent (recently)."""
    DUPLICATE = "duplicate"
    """A second answer to one command."""
    STALE = "stale"
    """Its FC times are not the stream's: sent before an FC reset (or before any state packet)."""
    CLOCK_STEP = "clock_step"
    """Impossible times: a negative round trip, or the FC answering before it received."""
    TOO_LONG = "too_long"
    """A round trip longer than the bound: too loose to help."""
    INCONSISTENT = "inconsistent"
    """Its bounds miss those of the round trips before it, and no others confirm it."""


@dataclass(frozen=True, slots=True)
class RoundTrip:
    """One command and its time reply: OBC times in seconds, FC times in unwrapped µs."""

    obc_sent: float
    fc_received_us: int
    fc_sent_us: int
    obc_received: float

    @property
    def rtt_s(self) -> float:
        """Time on the wire both ways, the FC's hold time taken out (rate 1 assumed)."""
        return (self.obc_received - self.obc_sent) - (self.fc_sent_us - self.fc_received_us) * 1e-6


class RoundTripMatcher:
    """The commands this OBC sent, and the replies that answer them (spec §10, OBC side).

    A reply answers the command with its `seq` and `tx_time_us` both; commands are kept for
    KEEP_S seconds (at most KEEP_MAX of them). `on_round_trip` hears every pairing.
    """

    KEEP_S = 5.0
    KEEP_MAX = 4096

    def __init__(self, on_round_trip: Callable[[RoundTrip], None] | None = None) -> None:
        self._sent: OrderedDict[tuple[int, int], tuple[float, bool]] = OrderedDict()
        self.on_round_trip = on_round_trip
        self.matched = 0
        self.rejected: dict[RoundTripRejection, int] = dict.fromkeys(RoundTripRejection, 0)
        """Replies not paired: unmatched and duplicate ones here, stale ones and those
        answered before received (clock_step) where the decoder places them."""

    def sent(self, seq: int, tx_time_us: int, obc_time: float) -> None:
        """A command left with E1 `seq` and `tx_time_us` at OBC time `obc_time` (s)."""
        sent = self._sent
        sent[(seq % SEQ_MODULUS, tx_time_us)] = (obc_time, False)
        while sent and (
            len(sent) > self.KEEP_MAX or next(iter(sent.values()))[0] < obc_time - self.KEEP_S
        ):
            sent.popitem(last=False)

    def match(self, reply: TimeReply) -> RoundTrip | None:
        """The round trip `reply` completes (its FC times placed by the decoder), or None."""
        key = (reply.command_seq, reply.command_tx_time_us)
        record = self._sent.get(key)
        if record is None:
            self.rejected[RoundTripRejection.UNMATCHED] += 1
            return None
        obc_sent, answered = record
        if answered:
            self.rejected[RoundTripRejection.DUPLICATE] += 1
            return None
        self._sent[key] = (obc_sent, True)
        assert reply.received_us is not None and reply.sent_us is not None
        assert reply.arrival_time is not None
        trip = RoundTrip(obc_sent, reply.received_us, reply.sent_us, reply.arrival_time)
        self.matched += 1
        if self.on_round_trip is not None:
            self.on_round_trip(trip)
        return trip


@dataclass(frozen=True)
class TwoWayState:
    """What the round trips say, for display (`TwoWayClockEstimator.two_way`)."""

    active: bool
    """OBC times come from the round trips (enough of them agree); else they are one-way."""
    round_trips: int
    """In the window."""
    accepted: int
    rtt_min_s: float
    """The shortest round trip in the window."""
    delay_s: float
    """The FC→OBC minimum delay d_min: the one-way line's height over the true line."""
    uncertainty_s: float
    """± on the offset (and on `delay_s`): half the width of the window's bounds."""
    delay_bounds_s: tuple[float, float]
    """d_min lies between these (a one-way delay bound: no packet arrives faster than low)."""
    steps: int
    """Times the round trips jumped together (an OBC clock step) and the window restarted."""
    outliers: int
    """Round trips in the window whose bounds go beyond the confirmed ones (unconfirmed)."""
    rejected: dict[RoundTripRejection, int] = field(default_factory=dict)


class TwoWayClockEstimator:
    """The one-way line (any `ClockEstimator`, default the envelope) lowered by d_min from
    round trips: OBC times of FC instants without the transport delay (spec §8.3).

    With E the one-way line, a round trip gives a = E(t2) − t1 and b = t4 − E(t3), and
    d_min = E − truth lies in [−b, a] (both delays ≥ 0). The window's round trips (WINDOW_S,
    at most MAX_ROUND_TRIPS) together bound it to [max −b, min a], tighter than any one of
    them — each bound taken as the CONFIRM-th best, so no lone round trip (a command stamped
    by a clock that jumped and came back) can narrow it. d_min is the midpoint (equal minimum
    delays both ways, the assumption of every two-way method), the uncertainty the half
    width. Only round trips up to MAX_RTT_S count (PX4's timesync gate); the bounds come from
    the shortest ones anyway. d_min is E's height, so it is taken again whenever E moves
    (a faster packet lowers it, a fit turns it), not only at the next round trip: OBC times
    move with what the round trips say, never with E's own corrections.

    A round trip whose bounds miss the window's by more than TOLERANCE_S is held; CONFIRM such
    in a row that agree with each other are a step (the OBC clock jumped) and restart the
    window, otherwise they are rejected. An FC reset (`reset`) or a step of the one-way line
    clears the window.
    """

    MAX_RTT_S = 10e-3
    WINDOW_S = 10.0
    MAX_ROUND_TRIPS = 256
    MIN_ROUND_TRIPS = 4
    """Round trips in the window before OBC times use them (and the one-way line locked)."""
    TOLERANCE_S = 50e-6
    CONFIRM = 3

    def __init__(self, one_way: ClockEstimator | None = None, max_rtt_s: float = MAX_RTT_S) -> None:
        self.one_way: ClockEstimator = one_way if one_way is not None else EnvelopeClockEstimator()
        self.max_rtt_s = max_rtt_s
        self.rejected: dict[RoundTripRejection, int] = dict.fromkeys(RoundTripRejection, 0)
        self.accepted = 0
        self.steps = 0
        self._clear()

    def _clear(self) -> None:
        self._trips: deque[RoundTrip] = deque()
        self._held: list[RoundTrip] = []
        self._delay = math.nan
        self._bounds = (math.nan, math.nan)
        self._bounds_line: tuple[float, float] | None = None
        """The line E the bounds were taken against."""
        self._outliers = 0
        self._line_steps: int | None = None

    # -- ClockEstimator ---------------------------------------------------------------------

    def observe(self, fc_time_us: int, obc_time: float) -> None:
        self.one_way.observe(fc_time_us, obc_time)
        if self._delay != self._delay:  # NaN: no estimate to keep up
            return
        one_way = self.one_way.state
        if one_way.reinits != self._line_steps:
            self._clear()  # d_min was measured against the line before its step: not this one
            return
        line = self._line()
        if line is not None and line != self._bounds_line:
            self._estimate(line, one_way.locked)

    def to_obc(self, fc_time_us: int) -> float | None:
        line = self.one_way.to_obc(fc_time_us)
        if line is None or self._delay != self._delay:  # NaN: not enough round trips
            return line
        return line - self._delay

    def reset(self) -> None:
        self.one_way.reset()
        self._clear()

    @property
    def state(self) -> ClockState:
        """The one-way state, with the offset and uncertainty of the round trips once active."""
        state = self.one_way.state
        if self._delay != self._delay:
            return state
        return replace(
            state,
            offset_s=state.offset_s - self._delay,
            uncertainty_s=(self._bounds[1] - self._bounds[0]) / 2,
        )

    # -- RoundTripObserver ------------------------------------------------------------------

    def observe_round_trip(
        self, obc_sent: float, fc_received_us: int, fc_sent_us: int, obc_received: float
    ) -> None:
        trip = RoundTrip(obc_sent, fc_received_us, fc_sent_us, obc_received)
        if not (math.isfinite(obc_sent) and math.isfinite(obc_received)):
            self.rejected[RoundTripRejection.CLOCK_STEP] += 1
            return
        line = self._line()
        if line is None:  # no packet of this FC epoch yet: nothing to measure against
            self.rejected[RoundTripRejection.STALE] += 1
            return
        rtt = (obc_received - obc_sent) - line[1] * (fc_sent_us - fc_received_us) * 1e-6
        if obc_received < obc_sent or fc_sent_us < fc_received_us or rtt < 0.0:
            self.rejected[RoundTripRejection.CLOCK_STEP] += 1
            return
        if rtt > self.max_rtt_s:
            self.rejected[RoundTripRejection.TOO_LONG] += 1
            return
        one_way = self.one_way.state
        if one_way.reinits != self._line_steps:  # the line started over: so do the bounds
            self._trips.clear()
            self._held.clear()
            self._line_steps = one_way.reinits
        trips = self._trips
        while trips and (
            trips[0].obc_received < obc_received - self.WINDOW_S
            or len(trips) >= self.MAX_ROUND_TRIPS
        ):
            trips.popleft()
        low, high = self._confirmed(*self._limits([trip], line), 1)
        window_low, window_high = self._confirmed(*self._limits(trips, line), self.CONFIRM)
        tolerance = self.TOLERANCE_S
        # Until the line is locked its rate may still be off, and bounds with it: no judging.
        if one_way.locked and (low > window_high + tolerance or high < window_low - tolerance):
            self._hold(trip, line)
        else:
            self.rejected[RoundTripRejection.INCONSISTENT] += len(self._held)
            self._held.clear()
            trips.append(trip)
            self.accepted += 1
        self._estimate(line, one_way.locked)

    def _hold(self, trip: RoundTrip, line: tuple[float, float]) -> None:
        held = self._held
        held.append(trip)
        while held:
            low, high = self._confirmed(*self._limits(held, line), 1)
            if high >= low - self.TOLERANCE_S:
                break
            held.pop(0)  # the held ones disagree among themselves too: the oldest was wrong
            self.rejected[RoundTripRejection.INCONSISTENT] += 1
        if len(held) >= self.CONFIRM:
            self.steps += 1
            self.accepted += len(held)
            self._trips = deque(held)
            self._held = []

    def _line(self) -> tuple[float, float] | None:
        """The one-way line E as (E(0) in s, rate); None before data."""
        zero = self.one_way.to_obc(0)
        if zero is None:
            return None
        rate = self.one_way.to_obc(1_000_000) - zero  # type: ignore[operator]
        return zero, rate

    @staticmethod
    def _limits(
        trips: deque[RoundTrip] | list[RoundTrip], line: tuple[float, float]
    ) -> tuple[list[float], list[float]]:
        """Each trip's bounds on d_min against `line`: the −b (lows) and the a (highs)."""
        zero, rate = line
        scale = rate * 1e-6
        lows = [zero + scale * trip.fc_sent_us - trip.obc_received for trip in trips]
        highs = [zero + scale * trip.fc_received_us - trip.obc_sent for trip in trips]
        return lows, highs

    @staticmethod
    def _confirmed(lows: list[float], highs: list[float], confirm: int) -> tuple[float, float]:
        """[max −b, min a], each the `confirm`-th best (of fewer, the worst); (−inf, inf) for
        none."""
        if not lows:
            return -math.inf, math.inf
        rank = min(confirm, len(lows))
        return heapq.nlargest(rank, lows)[-1], heapq.nsmallest(rank, highs)[-1]

    def _estimate(self, line: tuple[float, float], line_locked: bool) -> None:
        if not line_locked or len(self._trips) < self.MIN_ROUND_TRIPS:
            self._delay = math.nan
            self._bounds = (math.nan, math.nan)
            return
        lows, highs = self._limits(self._trips, line)
        low, high = self._confirmed(lows, highs, self.CONFIRM)
        tolerance = self.TOLERANCE_S
        self._outliers = sum(
            1 for one_low, one_high in zip(lows, highs)
            if one_low > low + tolerance or one_high < high - tolerance
        )  # fmt: skip
        if high < low:  # within the tolerance (else held): the mismatch is the uncertainty
            low, high = high, low
        self._bounds = (low, high)
        self._bounds_line = line
        self._delay = (low + high) / 2

    @property
    def two_way(self) -> TwoWayState:
        trips = self._trips
        return TwoWayState(
            active=self._delay == self._delay,
            round_trips=len(trips),
            accepted=self.accepted,
            rtt_min_s=min((t.rtt_s for t in trips), default=math.nan),
            delay_s=self._delay,
            uncertainty_s=(self._bounds[1] - self._bounds[0]) / 2,
            delay_bounds_s=self._bounds,
            steps=self.steps,
            outliers=self._outliers,
            rejected=dict(self.rejected),
        )
