"""The conformance vectors of spec/vectors: decode exactly, and re-encode byte for byte."""

from __future__ import annotations

import json
from itertools import pairwise
from pathlib import Path
from typing import Any

import pytest

from wftool.fsp import (
    ArmingAction,
    ArmingRequest,
    Authority,
    AuthorityExit,
    CommandDecoder,
    CommandPacket,
    SensorFrame,
    StateDecoder,
    StatePacket,
)
from wftool.fsp.encoder import (
    encode_arming_request,
    encode_command,
    encode_command_report,
    encode_state,
    encode_time_reply,
    encode_uplink_status,
)
from wftool.fsp.framing import (
    STATE_E2_VERSIONS,
    STATE_VERSIONS,
    Deframer,
    Rejection,
)
from wftool.fsp.packets import (
    COMMAND_REPORT_LENGTH,
    TIME_REPLY_LENGTH,
    UPLINK_STATUS_LENGTHS,
    CommandOutcome,
    CommandReport,
    TimeReply,
    UplinkFlag,
    UplinkStatus,
    parse_command_report,
    parse_state,
    parse_time_reply,
    parse_uplink_status,
)
from wftool.link.crc import crc8

STATE_VECTORS = ["state_base", "state_e1_wrap", "state_mavlink"]
FRAME_FIELDS = ["sample_time_us", "acc", "acc_1g", "gyro_scale", "gyro", "attitude", "rc", "rpm"]


def load(vectors_dir: Path, name: str) -> tuple[bytes, dict[str, Any]]:
    wire = (vectors_dir / f"{name}.bin").read_bytes()
    expected = json.loads((vectors_dir / f"{name}.expected.json").read_text())
    return wire, expected


def packet_as_json(packet: StatePacket) -> dict[str, Any]:
    return {
        "version": packet.version,
        "mavlink": packet.mavlink.hex() if packet.mavlink is not None else None,
        "seq": packet.seq,
        "e1": packet.e1,
        "drops": packet.drops,
        "tx_time_us": packet.tx_time_us,
        "frames": [
            {name: _plain(getattr(f, name)) for name in [*FRAME_FIELDS, "vbat"]}
            for f in packet.frames
        ],
    }


def _plain(value: Any) -> Any:
    return list(value) if isinstance(value, tuple) else value


def packet_from_json(obj: dict[str, Any]) -> StatePacket:
    frames = tuple(
        SensorFrame(**{k: tuple(v) if isinstance(v, list) else v for k, v in f.items()})
        for f in obj["frames"]
    )
    mavlink = bytes.fromhex(obj["mavlink"]) if obj["mavlink"] is not None else None
    return StatePacket(obj["tx_time_us"], frames, obj["seq"], obj["e1"], obj["drops"], mavlink)


def test_crc_check_values(vectors_dir: Path) -> None:
    cases = json.loads((vectors_dir / "crc8.json").read_text())
    assert int(cases["poly"], 16) == 0xD5 and int(cases["init"], 16) == 0xFF
    for case in cases["cases"]:
        assert crc8(case["ascii"].encode()) == case["crc"], case


@pytest.mark.parametrize("name", STATE_VECTORS)
def test_state_vector_decodes_exactly(vectors_dir: Path, name: str) -> None:
    wire, expected = load(vectors_dir, name)
    decoder = StateDecoder()
    packets = decoder.feed(wire)
    assert [packet_as_json(p) for p in packets] == expected["packets"]
    assert decoder.stats.errors == 0


@pytest.mark.parametrize("name", STATE_VECTORS)
def test_state_vector_encodes_byte_for_byte(vectors_dir: Path, name: str) -> None:
    wire, expected = load(vectors_dir, name)
    assert b"".join(encode_state(packet_from_json(p)) for p in expected["packets"]) == wire


def test_command_vector_round_trip(vectors_dir: Path) -> None:
    wire, expected = load(vectors_dir, "command")
    decoder = CommandDecoder()
    commands = decoder.feed(wire)
    decoded = [
        {"version": 5, "seq": c.seq, "tx_time_us": c.tx_time_us, "rc": list(c.rc)}
        for c in commands
        if isinstance(c, CommandPacket)
    ]
    assert decoded == expected["packets"]
    assert not any(decoder.rejected.values())
    assert {c.sender for c in commands} == {0}  # the reference's zero, which the FC refuses
    rebuilt = [
        CommandPacket(tuple(p["rc"]), p["seq"], p["tx_time_us"]) for p in expected["packets"]
    ]
    assert b"".join(encode_command(c) for c in rebuilt) == wire


def test_damaged_stream_yields_exactly_the_valid_packets(vectors_dir: Path) -> None:
    wire, expected = load(vectors_dir, "state_damaged")
    decoder = StateDecoder()
    packets = decoder.feed(wire)
    assert [p.tx_time_us for p in packets] == expected["valid_tx_times_us"]
    rejected = decoder.stats.rejected
    assert all(rejected[cause] >= 1 for cause in Rejection), rejected
    assert decoder.stats.errors == expected["rejected_chunks_total"]


def test_e1_wrap_vector_accounting(vectors_dir: Path) -> None:
    """Across the u32 and seq wraps: no loss, no reset, one wrap, the 3 FC-side drops."""
    wire, _ = load(vectors_dir, "state_e1_wrap")
    decoder = StateDecoder()
    packets = decoder.feed(wire)
    times = [f.time_us for p in packets for f in p.frames]
    assert all(b > a for a, b in pairwise(times))
    assert times[-1] > 2**32
    stats = decoder.stats
    assert (stats.lost_packets, stats.lost_frames, stats.fc_drops) == (0, 0, 3)
    assert (stats.wraps, stats.resets) == (1, 0)


# -- E2 time replies and E3 uplink statuses: vectors written by the firmware's own C encoder --

REPLY_FIELDS = ("command_seq", "command_tx_time_us", "rx_time_us", "tx_time_us")


def reply_as_json(reply: TimeReply) -> dict[str, Any]:
    return {"type": "time_reply", "version": reply.version} | {
        name: getattr(reply, name) for name in REPLY_FIELDS
    }


STATUS_FIELDS = (
    "command_seq", "tx_time_us", "accepted", "stale", "timeouts", "rejected", "timeout_ms",
    "flags", "failsafe_phase", "timed_out_us",
)  # fmt: skip
MIXED_VECTORS = [
    "time_reply", "time_reply_stream", "uplink_status", "uplink_status_stream",
    "command_report", "command_report_stream",
]  # fmt: skip
"""Written by the firmware's own C encoder: E2 time replies (§10), E3 uplink statuses (§12),
E4 command reports (§13)."""
REPORT_FIELDS = (
    "command_seq", "command_tx_time_us", "at_us", "event_us", "outcome", "queued", "counts",
)  # fmt: skip


def report_as_json(report: CommandReport) -> dict[str, Any]:
    fields = {name: getattr(report, name) for name in REPORT_FIELDS}
    fields["counts"] = list(report.counts)
    return {"type": "command_report", "version": report.version} | fields


AUTHORITY_FIELDS = (
    "authority", "exit", "proof_ms", "exit_us", "sender", "foreign", "refused",
    "msp_rc_refused", "rc_min_us", "rc_max_us",
)  # fmt: skip
"""Spec §12 bytes 32–62: in the 64-byte statuses only (the `_v2` vectors)."""


def status_as_json(status: UplinkStatus) -> dict[str, Any]:
    names = STATUS_FIELDS if status.authority is None else STATUS_FIELDS + AUTHORITY_FIELDS
    return {"type": "uplink_status", "version": status.version} | {
        name: getattr(status, name) for name in names
    }


def status_from_json(p: dict[str, Any]) -> UplinkStatus:
    status = UplinkStatus(*(p[name] for name in STATUS_FIELDS))
    if "authority" in p:
        for name in AUTHORITY_FIELDS:
            setattr(status, name, p[name])
        status.authority = Authority(p["authority"])
        status.exit = AuthorityExit(p["exit"])
    return status


def decode_mixed(wire: bytes) -> list[dict[str, Any]]:
    """Every packet of a stream with time replies and uplink statuses, in order, as the
    vectors' JSON."""

    def as_json(payload: bytes) -> dict[str, Any]:
        if len(payload) == TIME_REPLY_LENGTH:
            return reply_as_json(parse_time_reply(payload))
        if len(payload) in UPLINK_STATUS_LENGTHS:
            return status_as_json(parse_uplink_status(payload))
        if len(payload) == COMMAND_REPORT_LENGTH:
            return report_as_json(parse_command_report(payload))
        return {"type": "state"} | packet_as_json(parse_state(payload))

    deframer = Deframer(STATE_E2_VERSIONS)
    decoded = [as_json(payload) for payload in deframer.feed(wire)]
    assert not any(deframer.rejected.values()), deframer.rejected
    return decoded


def encode_mixed(packets: list[dict[str, Any]]) -> bytes:
    def encode(p: dict[str, Any]) -> bytes:
        if p["type"] == "time_reply":
            return encode_time_reply(TimeReply(*(p[name] for name in REPLY_FIELDS)))
        if p["type"] == "uplink_status":
            return encode_uplink_status(status_from_json(p))
        if p["type"] == "command_report":
            values = {**p, "counts": tuple(p["counts"])}
            return encode_command_report(CommandReport(*(values[name] for name in REPORT_FIELDS)))
        return encode_state(packet_from_json({k: v for k, v in p.items() if k != "type"}))

    return b"".join(map(encode, packets))


STATUS_V2_VECTORS = ["uplink_status_v2", "uplink_status_v2_stream"]
"""E3 with the authority fields (64 bytes, spec §12), written by the firmware of §15."""


def load_firmware_vector(vectors_dir: Path, name: str) -> tuple[bytes, dict[str, Any]]:
    if name in STATUS_V2_VECTORS and not (vectors_dir / f"{name}.bin").exists():
        pytest.skip(f"{name}.bin is written by the firmware of spec §15, not here yet")
    return load(vectors_dir, name)


@pytest.mark.parametrize("name", MIXED_VECTORS + STATUS_V2_VECTORS)
def test_firmware_vector_decodes_exactly(vectors_dir: Path, name: str) -> None:
    wire, expected = load_firmware_vector(vectors_dir, name)
    assert decode_mixed(wire) == expected["packets"]


@pytest.mark.parametrize("name", MIXED_VECTORS + STATUS_V2_VECTORS)
def test_firmware_vector_encodes_byte_for_byte(vectors_dir: Path, name: str) -> None:
    wire, expected = load_firmware_vector(vectors_dir, name)
    assert encode_mixed(expected["packets"]) == wire


def test_plain_v5_decoder_rejects_each_time_reply_as_one_chunk(vectors_dir: Path) -> None:
    """A decoder without E2 yields every state packet, counts one chunk per reply, loses nothing."""
    wire, expected = load(vectors_dir, "time_reply_stream")
    decoder = StateDecoder()
    packets = decoder.feed(wire)
    states = [{k: v for k, v in p.items() if k != "type"} for p in expected["packets"]]
    assert [packet_as_json(p) for p in packets] == [s for s in states if "frames" in s]
    plain = expected["plain_v5"]
    assert len(packets) == plain["state_packets"]
    assert decoder.stats.errors == decoder.stats.rejected[Rejection.LENGTH]
    assert decoder.stats.errors == plain["rejected_chunks"]
    assert (decoder.stats.lost_packets, decoder.stats.lost_frames) == (0, 0)


# -- E3 uplink statuses (spec §12) ---------------------------------------------------------


def test_state_decoder_takes_uplink_statuses_between_the_packets(vectors_dir: Path) -> None:
    wire, expected = load(vectors_dir, "uplink_status_stream")
    decoder = StateDecoder()
    seen: list[tuple[int, int]] = []  # (state packets so far, accepted) at each status
    for byte in wire:  # byte by byte: a status completes between two state packets
        before = decoder.uplink_status
        decoder.feed(bytes([byte]))
        if decoder.uplink_status is not before:
            assert decoder.uplink_status is not None
            seen.append((decoder.stats.packets, decoder.uplink_status.accepted))
    statuses = [p for p in expected["packets"] if p["type"] == "uplink_status"]
    assert decoder.stats.errors == 0
    assert decoder.stats.uplink_statuses == len(statuses)
    assert seen == [(2, 40), (5, 41), (8, 41)]
    last = decoder.uplink_status
    assert last is not None and status_as_json(last) == statuses[-1]
    assert last.has(UplinkFlag.OVERRIDE) and not last.has(UplinkFlag.LIVE)
    assert last.failsafe_phase_name == "IDLE"
    packet = decoder.last_packet  # the status was sent 40 µs after it, by the FC clock
    assert packet is not None and packet.time_us is not None
    assert last.sent_us == packet.time_us + 40
    assert last.timed_out_at_us == last.sent_us - (last.tx_time_us - last.timed_out_us)


def test_state_decoder_takes_64_byte_statuses_between_the_packets(vectors_dir: Path) -> None:
    """The firmware of spec §15: who flies, in the statuses between the state packets; the
    exit dated on the stream's FC clock like the timeout."""
    wire, expected = load_firmware_vector(vectors_dir, "uplink_status_v2_stream")
    decoder = StateDecoder()
    packets = decoder.feed(wire)
    statuses = [p for p in expected["packets"] if p["type"] == "uplink_status"]
    assert len(packets) == sum(p["type"] == "state" for p in expected["packets"])
    assert decoder.stats.errors == 0
    assert decoder.stats.uplink_statuses == len(statuses)
    last = decoder.uplink_status
    assert last is not None and status_as_json(last) == statuses[-1]
    assert last.reports_authority and last.pulse_range == (last.rc_min_us, last.rc_max_us)
    assert last.sent_us is not None and last.sent_us % 2**32 == last.tx_time_us
    if last.exit:
        assert last.exit_at_us == last.sent_us - (last.tx_time_us - last.exit_us) % 2**32


@pytest.mark.parametrize("name", ["uplink_status_stream", "uplink_status_v2_stream"])
def test_plain_v5_decoder_rejects_each_uplink_status_as_one_chunk(
    vectors_dir: Path, name: str
) -> None:
    """A v5 reader without E3 (here: a Deframer of state packets only) loses nothing else."""
    wire, expected = load_firmware_vector(vectors_dir, name)
    deframer = Deframer(STATE_VERSIONS)
    states = [packet_as_json(parse_state(p)) for p in deframer.feed(wire)]
    plain = expected["plain_v5"]
    assert len(states) == plain["state_packets"]
    assert sum(deframer.rejected.values()) == deframer.rejected[Rejection.LENGTH]
    assert deframer.rejected[Rejection.LENGTH] == plain["rejected_chunks"]


# -- E4 timed commands and command reports (spec §13) ---------------------------------------


def test_timed_command_vector_round_trip(vectors_dir: Path) -> None:
    wire, expected = load(vectors_dir, "timed_command")
    decoder = CommandDecoder()
    decoded = [
        {"version": 5, "seq": c.seq, "tx_time_us": c.tx_time_us, "rc": list(c.rc),
         "at_us": c.at_us}
        for c in decoder.feed(wire)
    ]  # fmt: skip
    assert decoded == expected["packets"]
    assert not any(decoder.rejected.values())
    rebuilt = [
        CommandPacket(tuple(p["rc"]), p["seq"], p["tx_time_us"], p["at_us"])
        for p in expected["packets"]
    ]
    assert b"".join(encode_command(c) for c in rebuilt) == wire


def test_an_fc_without_e4_rejects_each_timed_command_as_one_chunk(vectors_dir: Path) -> None:
    """What the firmware before E4 (or built without it) does: no command, one chunk each."""
    wire, expected = load(vectors_dir, "timed_command")
    decoder = CommandDecoder(timed=False)
    plain = expected["plain_v5"]
    assert len(decoder.feed(wire)) == plain["commands"] == 0
    assert sum(decoder.rejected.values()) == decoder.rejected[Rejection.LENGTH]
    assert decoder.rejected[Rejection.LENGTH] == plain["rejected_chunks"]
    immediate, _ = load(vectors_dir, "command")
    assert len(decoder.feed(immediate)) == 8  # and takes the immediate ones as ever


def test_state_decoder_takes_command_reports_between_the_packets(vectors_dir: Path) -> None:
    wire, expected = load(vectors_dir, "command_report_stream")
    decoder = StateDecoder()
    packets = decoder.feed(wire)
    reports = decoder.take_command_reports()
    assert [report_as_json(r) for r in reports] == [
        p for p in expected["packets"] if p["type"] == "command_report"
    ]
    assert len(packets) == 8 and decoder.stats.errors == 0
    assert decoder.stats.command_reports == 3
    assert decoder.take_command_reports() == []  # taken once
    on_time, late, refused = reports
    assert (on_time.outcome, late.outcome, refused.outcome) == (
        CommandOutcome.ON_TIME, CommandOutcome.LATE, CommandOutcome.TOO_FAR,
    )  # fmt: skip
    assert (on_time.delay_us, late.delay_us, refused.delay_us) == (50, 2375, None)
    # the FC times unwrapped into the stream's: the event beside the state packet before it
    for report in reports:
        assert report.event_time_us is not None and report.at_time_us is not None
        assert report.event_time_us % 2**32 == report.event_us
        assert report.at_time_us - report.event_time_us == report.at_us - report.event_us


def test_plain_v5_decoder_rejects_each_command_report_as_one_chunk(vectors_dir: Path) -> None:
    wire, expected = load(vectors_dir, "command_report_stream")
    deframer = Deframer(STATE_VERSIONS)
    states = [packet_as_json(parse_state(p)) for p in deframer.feed(wire)]
    plain = expected["plain_v5"]
    assert len(states) == plain["state_packets"]
    assert deframer.rejected[Rejection.LENGTH] == plain["rejected_chunks"]
    assert sum(deframer.rejected.values()) == plain["rejected_chunks"]


def test_the_reference_vectors_decode_as_before(vectors_dir: Path) -> None:
    """E4 changes nothing a stream without timed commands carries: every vector of the
    original contract decodes with no command report and no new rejection."""
    for name in [*STATE_VECTORS, "state_damaged"]:
        wire, _ = load(vectors_dir, name)
        decoder = StateDecoder()
        decoder.feed(wire)
        assert decoder.stats.command_reports == 0, name
    wire, _ = load(vectors_dir, "command")
    assert all(c.at_us is None for c in CommandDecoder().feed(wire))


# -- one sender (spec §5, §11) and E5 arming requests (§14): from the spec's own encoder -----


def test_command_sender_vector_round_trip(vectors_dir: Path) -> None:
    """Immediate and timed commands naming their sender: a sender's first ones, `seq`,
    `tx_time_us`, `sender` and `at_us` at their limits, the smallest sender with all-zero
    fields, distinct bytes."""
    wire, expected = load(vectors_dir, "command_sender")
    decoder = CommandDecoder()
    commands = decoder.feed(wire)
    decoded = [
        {"version": 5, "seq": c.seq, "tx_time_us": c.tx_time_us, "rc": list(c.rc),
         "sender": c.sender} | ({} if c.at_us is None else {"at_us": c.at_us})
        for c in commands
        if isinstance(c, CommandPacket)
    ]  # fmt: skip
    assert decoded == expected["packets"]
    assert not any(decoder.rejected.values())
    rebuilt = [
        CommandPacket(tuple(p["rc"]), p["seq"], p["tx_time_us"], p.get("at_us"), p["sender"])
        for p in expected["packets"]
    ]
    assert b"".join(encode_command(c) for c in rebuilt) == wire


ARMING_FIELDS = ("seq", "tx_time_us", "request", "sender")


def test_arming_request_vector_round_trip(vectors_dir: Path) -> None:
    """Arm and disarm from one sender (its `seq` carrying on from its commands), fields at
    their limits, the smallest sender, distinct bytes."""
    wire, expected = load(vectors_dir, "arming_request")
    decoder = CommandDecoder()
    requests = decoder.feed(wire)
    assert all(isinstance(r, ArmingRequest) for r in requests)
    decoded = [
        {"type": "arming_request", "version": 5} | {n: getattr(r, n) for n in ARMING_FIELDS}
        for r in requests
    ]
    assert decoded == expected["packets"]
    assert not any(decoder.rejected.values())
    rebuilt = [
        ArmingRequest(ArmingAction(p["request"]), p["seq"], p["tx_time_us"], p["sender"])
        for p in expected["packets"]
    ]
    assert b"".join(encode_arming_request(r) for r in rebuilt) == wire
    assert [r.request for r in requests[:2]] == [ArmingAction.ARM, ArmingAction.DISARM]


def test_an_fc_without_e5_rejects_each_arming_request_as_one_chunk(vectors_dir: Path) -> None:
    wire, expected = load(vectors_dir, "arming_request")
    decoder = CommandDecoder(timed=False)
    assert decoder.feed(wire) == []
    assert decoder.rejected[Rejection.LENGTH] == len(expected["packets"])
    assert sum(decoder.rejected.values()) == len(expected["packets"])


def test_commands_of_one_sender_continue_into_its_arming_requests(vectors_dir: Path) -> None:
    """One sequence per sender (spec §11): the arming vector's first requests follow the
    command vector's first commands of that sender."""
    _, commands = load(vectors_dir, "command_sender")
    _, requests = load(vectors_dir, "arming_request")
    sender = requests["packets"][0]["sender"]
    link = [p["seq"] for p in commands["packets"] if p["sender"] == sender]
    link += [p["seq"] for p in requests["packets"] if p["sender"] == sender]
    assert link == [*range(link[0], link[0] + len(link))]
