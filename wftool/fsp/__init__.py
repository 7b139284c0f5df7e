"""FSP (Flyby Serial Protocol, wire format v5) for the onboard computer; the contract is
spec/fsp.md. The README's layout table says which module holds what.

    from wftool.fsp import FspReader, StateDecoder
"""

from wftool.fsp.clock import (
    ClockEstimator,
    ClockState,
    EnvelopeClockEstimator,
    FcClock,
    KalmanClockEstimator,
    RoundTripObserver,
)
from wftool.fsp.decoder import CommandDecoder, StateDecoder, StreamStats, UplinkStatusWatch
from wftool.fsp.encoder import (
    CommandSender,
    encode_arming_request,
    encode_command,
    encode_command_report,
    encode_state,
    encode_time_reply,
    encode_uplink_status,
)
from wftool.fsp.estimators import ESTIMATORS, ONE_WAY_ESTIMATORS, make_estimator
from wftool.fsp.framing import Rejection
from wftool.fsp.packets import (
    ArmingAction,
    ArmingRequest,
    Authority,
    AuthorityExit,
    CommandOutcome,
    CommandPacket,
    CommandReport,
    SensorFrame,
    StatePacket,
    TimeReply,
    UplinkFlag,
    UplinkStatus,
)
from wftool.fsp.reader import DEFAULT_BAUDRATE, FspPort, FspReader
from wftool.fsp.timed import ReportBook, fc_time_us
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
    "ArmingAction",
    "ArmingRequest",
    "Authority",
    "AuthorityExit",
    "ClockEstimator",
    "ClockState",
    "CommandDecoder",
    "CommandOutcome",
    "CommandPacket",
    "CommandReport",
    "CommandSender",
    "EnvelopeClockEstimator",
    "FcClock",
    "FspPort",
    "FspReader",
    "KalmanClockEstimator",
    "Rejection",
    "ReportBook",
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
    "UplinkStatusWatch",
    "encode_arming_request",
    "encode_command",
    "encode_command_report",
    "encode_state",
    "encode_time_reply",
    "encode_uplink_status",
    "fc_time_us",
    "make_estimator",
]
