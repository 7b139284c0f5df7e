"""When the FC captures frames (spec §7): `fsp_rate_hz` and the lockstep interval.

The FC captures a frame every N-th PID loop iteration, N = floor((1e6 / fsp_rate_hz) /
pid_looptime_us) + 1, so the frame rate never exceeds `fsp_rate_hz`. The rate a stream should
have is therefore known from the configuration and the FC's PID looptime (MSP_STATUS), not
read off the stream itself.
"""

from __future__ import annotations

import math

RATE_HZ_MIN = 50
RATE_HZ_MAX = 8000
"""The firmware's range of `fsp_rate_hz` (8000: the fastest PID loop, where N = 2)."""
DEFAULT_RATE_HZ = 1100
"""The firmware's default `fsp_rate_hz` (the paper's setting)."""


def lockstep_interval(rate_hz: float, pid_looptime_us: float) -> int:
    """N: PID iterations per captured frame, as the firmware computes it."""
    if rate_hz <= 0 or pid_looptime_us <= 0:
        return 1
    return math.floor((1e6 / rate_hz) / pid_looptime_us) + 1


def frame_rate_hz(rate_hz: float, pid_looptime_us: float) -> float:
    """The frame rate an FC with this `fsp_rate_hz` and PID looptime streams."""
    return 1e6 / (lockstep_interval(rate_hz, pid_looptime_us) * pid_looptime_us)
