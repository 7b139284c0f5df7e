"""FSP (Flyby Serial Protocol, wire format v5) for the onboard computer.

Contract: spec/fsp.md. Where things live:

- `packets`  — models (`StatePacket`, `SensorFrame`, `CommandPacket`, `TimeReply`,
  `UplinkStatus`) and layouts
- `framing`  — COBS framing and the length/version/CRC checks (`Deframer`, `Rejection`)
- `crc`      — the table-driven CRC-8
- `decoder`  — `StateDecoder`: bytes in, timed packets out; loss, drops, resets counted
- `encoder`  — wire bytes for both directions; `CommandSender` for the uplink
- `clock`    — u32 unwrapping and OBC clock alignment (`make_estimator`: envelope, kalman,
  twoway)
- `twoway`   — E2 time replies paired with commands; `TwoWayClockEstimator` (absolute time)
- `schedule` — when the FC captures: `fsp_rate_hz`, the lockstep interval, the frame rate
- `reader`   — `FspPort` (bytes in, commands out) over any pyserial URL; `FspReader` decodes
- `columns`  — a whole capture into NumPy arrays, one per field (needs NumPy)
- `mavlink`  — messages from the tunnel variant (needs pymavlink)
"""

from wftool.fsp.clock import (
    ESTIMATORS,
    ONE_WAY_ESTIMATORS,
    ClockEstimator,
    ClockState,
    EnvelopeClockEstimator,
    FcClock,
    KalmanClockEstimator,
    RoundTripObserver,
    make_estimator,
)
from wftool.fsp.decoder import CommandDecoder, StateDecoder, StreamStats
from wftool.fsp.encoder import (
    CommandSender,
    encode_command,
    encode_state,
    encode_time_reply,
    encode_uplink_status,
)
from wftool.fsp.framing import Rejection
from wftool.fsp.packets import (
    CommandPacket,
    SensorFrame,
    StatePacket,
    TimeReply,
    UplinkFlag,
    UplinkStatus,
)
from wftool.fsp.reader import DEFAULT_BAUDRATE, FspPort, FspReader
from wftool.fsp.twoway import (
    RoundTrip,
    RoundTripMatcher,
    RoundTripRejection,
    TwoWayClockEstimator,
    TwoWayState,
)

__all__ = [
    "DEFAULT_BAUDRATE",
    "ESTIMATORS",
    "ONE_WAY_ESTIMATORS",
    "ClockEstimator",
    "ClockState",
    "CommandDecoder",
    "CommandPacket",
    "CommandSender",
    "EnvelopeClockEstimator",
    "FcClock",
    "FspPort",
    "FspReader",
    "KalmanClockEstimator",
    "Rejection",
    "RoundTrip",
    "RoundTripMatcher",
    "RoundTripObserver",
    "RoundTripRejection",
    "SensorFrame",
    "StateDecoder",
    "StatePacket",
    "StreamStats",
    "TimeReply",
    "TwoWayClockEstimator",
    "TwoWayState",
    "UplinkFlag",
    "UplinkStatus",
    "encode_command",
    "encode_state",
    "encode_time_reply",
    "encode_uplink_status",
    "make_estimator",
]
