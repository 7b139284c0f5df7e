"""Control changes hands only on purpose on the real firmware (the patched SITL), configured
by `configure fsp`: `wftool preflight`'s own scenarios (`wftool.preflight.scenarios`), each
played on a virtual FC and held to every line it reports.

A safety pilot (the simulated radio the receiver, armed by the pilot, MSP OVERRIDE on its
switch): the OBC steers only once the pilot engaged it; when it dies, stalls, repeats itself,
lies, restarts, doubles or steps its clock, the pilot's sticks are back within 100 ms of its
last fresh command and stay until the pilot engages it again. The OBC alone (the MSP
receiver): RXLOSS within 100 ms, Betaflight's failsafe, nothing sent by accident disarms.
And an FC never sent a command streams exactly what a v5 reader expects.

Times are the FC's own where it gives them (its clock runs slow on a loaded host, so host
times would measure the host).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from wftool.fc.fsp_setup import ObcOnly, SafetyPilot
from wftool.fsp.framing import STATE_VERSIONS, Deframer, Rejection
from wftool.fsp.packets import ArmingAction
from wftool.fsp.reader import FspPort
from wftool.preflight.flight import Flight
from wftool.preflight.report import Report
from wftool.preflight.run import STALLED, Preflight
from wftool.preflight.scenarios import ALONE, BY_KEY, PILOT, SCENARIOS
from wftool.preflight.virtual import on_virtual_fc
from wftool.sitl.session import VirtualFcSession

Flown = tuple[Preflight, Flight]
NEVER_S = 60.0
"""Only bounds "never": arming may wait out the FC's own delays on a loaded host."""


def _flying(
    control: SafetyPilot | ObcOnly, binary: Path, workdir: Path
) -> Iterator[tuple[Preflight, Flight]]:
    """A virtual FC as `configure fsp` leaves it, its settings passed, the OBC on its FSP port
    (with a safety pilot the pilot has armed it; the OBC alone arms it where a scenario
    needs)."""
    with on_virtual_fc(binary, control=control, port_base=None, workdir=workdir, arm=True) as run:
        run.read()
        assert run.report.ok, [f"{line.name}: {line.measured}" for line in run.report.failed]
        with run.flying() as flight:
            yield run, flight


@pytest.fixture(scope="module")
def piloted(sitl_binary: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Flown]:
    yield from _flying(SafetyPilot(), sitl_binary, tmp_path_factory.mktemp("piloted"))


@pytest.fixture(scope="module")
def alone(sitl_binary: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Flown]:
    yield from _flying(ObcOnly("drop"), sitl_binary, tmp_path_factory.mktemp("alone"))


def _passes(flown: Flown, key: str) -> None:
    """The scenario `key` played once: every line it reports passed."""
    run, flight = flown
    flight.report = Report()
    run.play(flight, BY_KEY[key])
    lines = flight.report.lines
    assert lines, f"{key}: no lines"
    if stalled := [line for line in lines if line.measured.startswith(STALLED)]:
        pytest.skip(f"{stalled[0].name}: {stalled[0].measured}")
    failed = [f"{line.name}: {line.measured} ({line.limit})" for line in lines if not line.passed]
    assert not failed, failed


@pytest.mark.parametrize("key", [s.key for s in SCENARIOS if PILOT in s.setups])
def test_with_a_safety_pilot(piloted: Flown, key: str) -> None:
    _passes(piloted, key)


@pytest.mark.parametrize("key", [s.key for s in SCENARIOS if ALONE in s.setups])
def test_the_obc_alone(alone: Flown, key: str) -> None:
    _passes(alone, key)


def test_a_stream_never_commanded_is_plain_v5(sitl_binary: Path, tmp_path: Path) -> None:
    """No command, no uplink status: a v5 reader rejects nothing. One command later, the FC
    reports on it (E3), which a v5 reader counts as chunks of another length."""
    with VirtualFcSession(sitl_binary, tmp_path, port_base=None) as fc, FspPort(fc.fsp_url) as port:
        plain = Deframer(STATE_VERSIONS)
        until = time.monotonic() + 1.0
        while time.monotonic() < until:
            plain.feed(port.read_bytes(0.05))
        assert not any(plain.rejected.values()), plain.rejected
        port.send_command((1500, 1500, 1500, 1000, 1000, 1000))
        until = time.monotonic() + 0.5
        while time.monotonic() < until:
            plain.feed(port.read_bytes(0.05))
        assert plain.rejected[Rejection.LENGTH] >= 1


def test_a_disarm_no_scenario_sent_is_said_and_not_carried_into_the_next(
    sitl_binary: Path, tmp_path: Path
) -> None:
    """The OBC alone, armed by a scenario: disarmed by a request no scenario sent, the next
    scenario says the FC is no longer armed, arms it again and is judged on its own (it took
    its own flag for the FC's state, and failed on the disarm before it)."""
    alone = ObcOnly("drop")
    with on_virtual_fc(
        sitl_binary, control=alone, port_base=None, workdir=tmp_path, arm=True
    ) as run:
        run.read()
        with run.flying() as flight:
            flight.report = Report()
            run.play(flight, BY_KEY["default_command"])
            assert flight.report.ok, flight.report.failed
            flight.take_over("a disarm")
            deadline = time.monotonic() + NEVER_S
            while flight.watcher.latest().armed:  # one superseded in its FSP task run: again
                assert time.monotonic() < deadline, "the FC took no disarm request"
                asked = time.monotonic()
                flight.obc.request_arming(ArmingAction.DISARM)
                flight.watcher.wait(lambda s: not s.armed, asked, 1.0)
            flight.report = Report()
            run.play(flight, BY_KEY["default_command"])
    said = {line.name: line for line in flight.report.lines}
    assert not said["the FC is still armed from before"].passed
    assert said["the OBC (an arming request) arms (--arm)"].passed
    assert said["the README's command: the FC stays armed, no mode switches"].passed
