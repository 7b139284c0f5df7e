"""One preflight run: an armed FC refused before anything is sent on the FSP port, one armed
during the run stopping the OBC at once, a lost link one error naming the port, and firmware
without the authority named on its line."""

from __future__ import annotations

import struct
import time
from pathlib import Path

import pytest

from tests.conftest import run_cli
from tests.fc.stand_in import msp_stand_in
from tests.fc.test_msp import status_ex
from tests.preflight.fsp_stand_in import FspStandIn
from tests.preflight.test_settings import piloted
from wftool.errors import PortError
from wftool.fc.fsp_setup import SafetyPilot
from wftool.fc.modes import MODE_ARM
from wftool.fc.msp import ArmingDisabled, Cmd, MspClient
from wftool.fsp.framing import Deframer
from wftool.fsp.packets import UPLINK_STATUS_LENGTH
from wftool.fsp.reader import FspPort
from wftool.preflight.flight import Flight
from wftool.preflight.obc import Obc
from wftool.preflight.pilot import NoPilot
from wftool.preflight.run import STALLED, ArmedError, Preflight
from wftool.preflight.virtual import on_virtual_fc
from wftool.sitl.radio import HIGH
from wftool.sitl.session import PILOT_ARM, Motion, VirtualFcSession


def armed_fc(cmd: int) -> bytes:
    """An FC that answers MSP armed (ARM is its first mode)."""
    if cmd == Cmd.API_VERSION:
        return bytes([0, 1, 47])
    if cmd == Cmd.BOXIDS:
        return bytes([MODE_ARM])
    if cmd == Cmd.STATUS_EX:
        return status_ex(1, 0)
    if cmd == Cmd.RC:
        return struct.pack("<8H", *[1500] * 8)
    return b""


def test_an_armed_fc_is_refused_before_the_fsp_port_is_opened(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with msp_stand_in(armed_fc) as url, FspStandIn() as fsp:
        for arm in ((), ("--arm",)):
            code, out, err = run_cli(
                capsys, "preflight", "--port", url, "--fsp-port", fsp.url, "--yes", *arm
            )
            assert code == 2, out + err
            [line] = err.strip().splitlines()
            assert line.startswith(f"error: the FC on {url} is armed: preflight sends nothing")
        assert fsp.connections == 0 and fsp.received == b""


def test_a_board_the_pilot_armed_gets_nothing_on_its_fsp_port(
    sitl_binary: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The patched SITL armed by its pilot: refused, exit 2, and the FC never heard of an OBC
    (an FC that is never sent a packet sends no uplink status, spec §12)."""
    with VirtualFcSession(sitl_binary, tmp_path, motion=Motion(), port_base=None, pilot=True) as fc:
        arm_by_the_pilot(fc)
        code, out, err = run_cli(
            capsys, "preflight", "--port", fc.msp_url, "--fsp-port", fc.fsp_url, "--yes"
        )
        assert code == 2 and "is armed: preflight sends nothing" in err, out + err
        statuses = Deframer({UPLINK_STATUS_LENGTH: 5})
        with FspPort(fc.fsp_url) as port:
            until = time.monotonic() + 0.5
            while time.monotonic() < until:
                assert statuses.feed(port.read_bytes(0.05)) == []


def arm_by_the_pilot(fc: VirtualFcSession) -> None:
    """The pilot arms the virtual FC once it can be armed; returns once it reports armed."""
    assert fc.radio is not None
    with MspClient.open(fc.msp_url) as msp:
        bit = msp.mode_bits()[MODE_ARM]
        deadline = time.monotonic() + 20.0
        while msp.status_ex().arming_disabled & ~ArmingDisabled.ARM_SWITCH:
            assert time.monotonic() < deadline, "arming stays disabled"
            time.sleep(0.05)
        fc.radio.set({f"aux{PILOT_ARM}": HIGH})
        while not msp.status_ex().active(bit):
            assert time.monotonic() < deadline, "the pilot could not arm"
            time.sleep(0.05)


def test_armed_during_the_run_without_arm_stops_the_obc(sitl_binary: Path, tmp_path: Path) -> None:
    with on_virtual_fc(sitl_binary, control=SafetyPilot(), port_base=None, workdir=tmp_path) as run:
        run.read()
        with pytest.raises(ArmedError, match="armed during the run, without --arm"):  # noqa: SIM117
            with run.flying() as flight:
                assert flight.watcher.wait(lambda s: s.can_arm, time.monotonic(), 20.0)
                flight.pilot.hold(armed=True)  # the pilot arms, unasked
                assert flight.watcher.wait(lambda s: s.armed, time.monotonic(), 5.0)
                flight.take_over("flying")
        accepted = flight.obc.status.accepted  # type: ignore[union-attr]
        with FspPort(run.fsp_url) as port:  # the FC heard no command since
            until = time.monotonic() + 0.3
            watch = port.uplink_status
            while time.monotonic() < until:
                port.read_bytes(0.05)
            watch = port.uplink_status
        assert watch is None or watch.accepted <= accepted + 1


def test_the_scenarios_wait_for_the_fc_to_receive_the_pilots_radio(
    sitl_binary: Path, tmp_path: Path
) -> None:
    """A virtual FC restarted after its settings were read is in RX loss until its receiver
    has had frames for a while: the scenarios start once it receives the pilot's radio, and a
    radio it never receives is a failed line."""
    with on_virtual_fc(sitl_binary, control=SafetyPilot(), port_base=None, workdir=tmp_path) as run:
        run.read()
        with run.flying() as flight:
            assert not flight.watcher.latest().rx_loss
        radio = run.pilot.args[0]  # type: ignore[attr-defined]  # the session's simulated radio
        radio.transmitting(False)
        run.read()  # the FC restarts without it
        with run.flying():
            pass
    lines = {line.name: line for line in run.report.lines}
    line = lines["the FC receives the pilot's radio"]
    assert (line.passed, line.measured) == (False, "RXLOSS")


def test_a_lost_link_mid_run_is_one_error_naming_its_port(
    sitl_binary: Path, tmp_path: Path
) -> None:
    with on_virtual_fc(sitl_binary, control=SafetyPilot(), port_base=None, workdir=tmp_path) as run:
        run.read()
        urls = (run.board.url, run.fsp_url)
        with pytest.raises(PortError) as lost:  # noqa: SIM117
            with run.flying() as flight:
                assert flight.take_over("flying")
                run.board.stop()  # type: ignore[attr-defined]  # the FC gone: both links
                flight.obc.frames.wait(lambda f: False, flight.obc.frames.end, 10.0)
                flight.watcher.wait(lambda s: False, time.monotonic(), 10.0)
    message = str(lost.value)
    assert message.startswith(urls) and "link" in message and "lost mid-run" in message, message


def test_firmware_without_the_authority_fails_naming_the_line() -> None:
    """A 36-byte uplink status (firmware before spec §15)."""
    with FspStandIn(answer_status=True) as fsp, Obc(fsp.url) as obc:
        run = Preflight(None, fsp.url, lambda settings: NoPilot())  # type: ignore[arg-type]
        flight = Flight(None, obc, NoPilot(), piloted(), run.report)  # type: ignore[arg-type]
        run._first_status(flight)
    lines = {line.name: line for line in run.report.lines}
    line = lines["the firmware reports who flies (E3 authority, spec §15)"]
    assert not line.passed and "36-byte" in line.measured
    assert lines["fsp_cmd_timeout_ms as the FC applies it (E3)"].passed


def test_a_scenario_the_obc_stalled_in_is_played_again_or_not_checked() -> None:
    """What the FC did while wftool's own OBC was late is no evidence: the lines of that try
    go, the scenario is played again, and after every try stalled it reads not checked."""
    from types import SimpleNamespace

    from wftool.preflight.record import Record
    from wftool.preflight.report import Report
    from wftool.preflight.scenarios import PILOT, Scenario

    stalls: Record[float] = Record()
    flight = SimpleNamespace(report=Report(), obc=SimpleNamespace(stalls=stalls), pilot=NoPilot())
    tries = []

    def stalls_twice(flight: object) -> None:
        tries.append(1)
        flight.report.check(f"try {len(tries)}", True, "yes")  # type: ignore[attr-defined]
        if len(tries) <= 2:
            stalls.add(0.07)

    run = Preflight(None, "", lambda settings: NoPilot())  # type: ignore[arg-type]
    run.play(flight, Scenario("x", "a scenario", (PILOT,), stalls_twice))  # type: ignore[arg-type]
    assert [line.name for line in flight.report.lines] == ["try 3"]
    run.play(flight, Scenario("y", "another", (PILOT,), lambda f: stalls.add(0.08)))  # type: ignore[arg-type]
    unchecked = flight.report.lines[-1]
    assert unchecked.name == "another" and not unchecked.passed
    assert unchecked.measured.startswith(f"{STALLED} (up to 80 ms apart)")


def test_a_scenario_the_simulated_radio_stalled_in_is_played_again() -> None:
    """A gap in the simulated radio's frames long enough for the FC's RX loss (its host
    stalled the transmitter) is no evidence either: that try's lines go, it is played again."""
    from types import SimpleNamespace

    from wftool.preflight.record import Record
    from wftool.preflight.report import Report
    from wftool.preflight.scenarios import PILOT, Scenario

    class StalledRadio(NoPilot):
        def __init__(self) -> None:
            self.stalls: list[float] = []

        def stalls_since(self, since: float) -> list[float]:
            return self.stalls

    pilot = StalledRadio()
    flight = SimpleNamespace(report=Report(), obc=SimpleNamespace(stalls=Record()), pilot=pilot)
    tries = []

    def radio_stalls_once(flight: object) -> None:
        tries.append(1)
        flight.report.check(f"try {len(tries)}", len(tries) > 1, "yes")  # type: ignore[attr-defined]
        pilot.stalls = [0.13] if len(tries) == 1 else []

    run = Preflight(None, "", lambda settings: pilot)  # type: ignore[arg-type]
    run.play(flight, Scenario("x", "a scenario", (PILOT,), radio_stalls_once))  # type: ignore[arg-type]
    assert [(line.name, line.passed) for line in flight.report.lines] == [("try 2", True)]


def test_a_scenario_played_again_keeps_the_arming_it_did() -> None:
    """A try that armed the FC, then stalled: its lines go, but the arming line stays — the
    FC is still armed, and the next try (finding it so) does not say it again."""
    from types import SimpleNamespace

    from wftool.preflight.record import Record
    from wftool.preflight.report import Report
    from wftool.preflight.scenarios import ALONE, Scenario

    stalls: Record[float] = Record()
    report = Report()
    flight = SimpleNamespace(
        report=report, obc=SimpleNamespace(stalls=stalls), pilot=NoPilot(), armed=False
    )

    def arms_then_stalls_once(flight: SimpleNamespace) -> None:
        if not flight.armed:
            armed = report.check("the OBC (an arming request) arms (--arm)", True, "armed")
            report.lasting.append(armed)
            flight.armed = True
            report.check("first try", True, "yes")
            stalls.add(0.07)
        else:
            report.check("second try", True, "yes")

    run = Preflight(None, "", lambda settings: NoPilot())  # type: ignore[arg-type]
    run.play(flight, Scenario("x", "armed", (ALONE,), arms_then_stalls_once))  # type: ignore[arg-type]
    assert [line.name for line in report.lines] == [
        "the OBC (an arming request) arms (--arm)",
        "second try",
    ]
