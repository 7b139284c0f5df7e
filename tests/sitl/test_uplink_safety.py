"""The uplink fails safe on the real firmware (the patched SITL), as `configure fsp` sets it up.

A safety pilot (the simulated radio the receiver, armed, MSP OVERRIDE on its switch): when the
OBC is killed, stops, repeats its last packet, sends garbage or replays old packets, the
pilot's stick values are back within 100 ms of its last fresh command, the FC still armed and
following the pilot's sticks; switched on before any fresh command, nothing moves. The OBC
alone (RX_MSP): a stuck OBC is an RX loss within 100 ms, then Betaflight's failsafe. And an FC
that is never sent a command streams exactly what a v5 reader expects.

Times are the FC's own (its clock runs slow on a loaded host, so host times would measure the
host): from the FC time the last fresh command was taken (its E2 time reply) to the first
frame that carries the pilot's sticks, or the uplink status (E3) that reports the change. A
killed OBC's port closes and a new connection reads on (SITL releases the old one in ~0.3 s):
the statuses then say when the FC's command timed out. What MSP says (armed, RXLOSS, the
sticks) is checked as well.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import pytest

from wftool.fc.msp import MspClient
from wftool.fsp.framing import STATE_VERSIONS, Deframer, Rejection
from wftool.fsp.packets import UplinkFlag
from wftool.fsp.reader import FspPort
from wftool.sitl.radio import SimulatedPilot
from wftool.sitl.session import (
    FSP_UART,
    PILOT_ARM,
    PILOT_OVERRIDE,
    Motion,
    VirtualFcSession,
)
from wftool.verify.preflight import (
    FAILURES,
    LIMIT_MS,
    STICKS,
    FcWatcher,
    Obc,
    near,
    offset_rc,
)


@dataclass
class Flight:
    session: VirtualFcSession
    watcher: FcWatcher
    obc: Obc
    pilot: SimulatedPilot | None
    pilot_rc: tuple[int, ...]


@pytest.fixture(scope="module")
def piloted(sitl_binary: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Flight]:
    """A virtual FC with a safety pilot, armed by the pilot."""
    workdir = tmp_path_factory.mktemp("piloted")
    with (
        VirtualFcSession(
            sitl_binary, workdir, motion=Motion(), port_base=None, pilot=True, time_reply=True
        ) as fc,
        MspClient.open(fc.msp_url) as msp,
    ):
        assert fc.radio is not None
        pilot = SimulatedPilot(fc.radio, PILOT_OVERRIDE, PILOT_ARM)
        watcher = FcWatcher(msp).start()
        obc = Obc(fc.fsp_url, closing=partial(fc.fc.close_client, FSP_UART)).start()
        try:
            assert watcher.wait(lambda s: s.can_arm, time.monotonic(), 20.0), "arming disabled"
            pilot.hold(armed=True)
            assert watcher.wait(lambda s: s.armed, time.monotonic(), 5.0), "the pilot cannot arm"
            pilot.hold(override=True)
            on = watcher.wait(lambda s: s.override, time.monotonic(), 1.0)
            assert on is not None, "MSP OVERRIDE did not come on"
            yield Flight(fc, watcher, obc, pilot, on.rc)
        finally:
            obc.stop()
            watcher.stop()


def test_override_on_before_any_fresh_command_moves_nothing(piloted: Flight) -> None:
    pilot, watcher, obc, pilot_rc = piloted.pilot, piloted.watcher, piloted.obc, piloted.pilot_rc
    assert pilot is not None
    pilot.hold(override=False)
    time.sleep(0.2)
    pilot.hold(override=True)
    on = watcher.wait(lambda s: s.override, time.monotonic(), 1.0)
    assert on is not None, "MSP OVERRIDE did not come on"
    obc.send_one((*offset_rc(pilot_rc), 2000, 2000))  # one packet is no evidence
    time.sleep(0.5)
    seen = watcher.since(on.t)
    assert len(seen) > 50
    assert all(s.rc[:8] == pilot_rc[:8] for s in seen), {s.rc[:8] for s in seen}
    assert min(min(s.rc[:STICKS]) for s in seen) > 885  # never the unset value's clamp


@pytest.mark.parametrize("failure", list(FAILURES))
def test_the_pilots_sticks_are_back_within_the_limit(piloted: Flight, failure: str) -> None:
    pilot, watcher, obc, pilot_rc = piloted.pilot, piloted.watcher, piloted.obc, piloted.pilot_rc
    assert pilot is not None and piloted.session.radio is not None
    pilot.hold(override=True)
    command = (*offset_rc(pilot_rc), 2000, 2000)
    obc.behave("fresh", command)
    taken = watcher.wait(lambda s: near(s.rc[:STICKS], command[:STICKS]), time.monotonic(), 2.0)
    assert taken is not None, "fresh commands do not fly the sticks"
    time.sleep(0.3)
    assert near(watcher.latest().rc[4:8], pilot_rc[4:8])  # ARM, the switch: the pilot's
    t0 = obc.behave(failure)
    try:
        back = watcher.wait(lambda s: near(s.rc[:STICKS], pilot_rc[:STICKS]), t0, 5.0)
        assert back is not None, f"{FAILURES[failure]}: the pilot's sticks never came back"
        if failure == "closed":  # the stream broke off: the FC's timeout, from its status
            us = obc.wait_fc_elapsed_us(timed_out=True)
        else:
            us = obc.wait_fc_elapsed_us(sticks=lambda rc: near(rc, pilot_rc[:4]))
        assert us is not None and us <= LIMIT_MS * 1000, f"{FAILURES[failure]}: {us} µs"
        time.sleep(0.5)  # the failure goes on: the pilot keeps the sticks, armed, no RXLOSS
        after = watcher.since(back.t)
        assert all(near(s.rc[:STICKS], pilot_rc[:STICKS]) for s in after)
        fallen = [s for s in after if not s.armed or s.rx_loss or s.failsafe]
        assert not fallen, f"{len(fallen)} of {len(after)}, first {fallen[0]} ({back.t=})"
        roll = pilot_rc[0] + 120  # and the FC flies the pilot's sticks
        piloted.session.radio.set(roll=roll)
        assert watcher.wait(lambda s: s.rc[0] == roll, time.monotonic(), 1.0)
    finally:
        piloted.session.radio.set(roll=pilot_rc[0])
        obc.behave("stopped")
        watcher.wait(lambda s: s.rc[0] == pilot_rc[0], time.monotonic(), 1.0)


def test_obc_alone_stuck_is_rx_loss_then_failsafe(sitl_binary: Path, tmp_path: Path) -> None:
    with (
        VirtualFcSession(
            sitl_binary,
            tmp_path,
            motion=Motion(),
            port_base=None,
            time_reply=True,
        ) as fc,
        MspClient.open(fc.msp_url) as msp,
    ):
        watcher = FcWatcher(msp).start()
        obc = Obc(fc.fsp_url).start()
        try:
            obc.behave("fresh", (1400, 1600, 1450, 1000, 1000, 1000))
            assert watcher.wait(lambda s: s.can_arm, time.monotonic(), 20.0), "arming disabled"
            obc.behave("fresh", (1400, 1600, 1450, 1000, 1850, 1000))  # ARM on AUX3
            assert watcher.wait(lambda s: s.armed, time.monotonic(), 5.0), "the OBC cannot arm"
            time.sleep(0.3)
            t0 = obc.behave("stuck")
            assert watcher.wait(lambda s: s.rx_loss, t0, 5.0), "no RXLOSS"
            assert watcher.wait(lambda s: not s.armed, t0, 10.0), "still armed"
            lost = obc.wait_fc_elapsed_us(status=lambda s: s.has(UplinkFlag.RX_LOSS))
            assert lost is not None and lost <= LIMIT_MS * 1000, lost
            stage2 = obc.wait_fc_elapsed_us(status=lambda s: not s.has(UplinkFlag.ARMED))
            assert stage2 is not None and 1_500_000 <= stage2 <= 1_500_000 + LIMIT_MS * 1000, stage2
        finally:
            obc.stop()
            watcher.stop()


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
