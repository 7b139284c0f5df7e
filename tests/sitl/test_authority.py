"""Who flies, end to end on the patched SITL with wftool's OBC library (spec §14, §15): the
OBC alone arms and disarms only by arming requests, and no command a restarted program sends
by default disarms; under a safety pilot the OBC steers only once the simulated pilot has
engaged it, and after a loss only once engaged again."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import pytest

from wftool.fc.msp import MspClient, MspError
from wftool.fsp import ArmingAction, Authority, AuthorityExit, FspReader, UplinkFlag, UplinkStatus
from wftool.sitl.radio import EngagingPilot
from wftool.sitl.session import PILOT_OVERRIDE, Motion, VirtualFcSession

PERIOD_S = 0.01
"""The OBC commands at 100 Hz."""
DEFAULTS = (1500, 1500, 1500, 1000, 1000, 1000)
"""What a program restarting with default values sends (the README's example)."""


class Obc:
    """wftool's OBC library on the FSP port: reads the stream and sends a command every
    `PERIOD_S` while it waits for what the FC reports."""

    def __init__(self, url: str) -> None:
        self.reader = FspReader(url).open()
        self.rc = DEFAULTS
        self.sending = True
        self._next = time.monotonic()

    def close(self) -> None:
        self.reader.close()

    @property
    def status(self) -> UplinkStatus | None:
        return self.reader.uplink_status

    @property
    def roll(self) -> int | None:
        """The roll the FC ran on last, as its stream shows it."""
        last = self.reader.decoder.last_packet
        return None if last is None else last.frames[1].rc[0]

    def run_until(
        self, done: Callable[[Obc], bool], timeout_s: float, each: Callable[[], object] = list
    ) -> bool:
        """Read and command until `done(self)` holds (True) or `timeout_s` passed (False);
        `each` runs after every read (a pilot watching the statuses)."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if self.sending and time.monotonic() >= self._next:
                self.reader.send_command(self.rc)
                self._next = max(self._next + PERIOD_S, time.monotonic() - PERIOD_S)
            self.reader.read(max(0.0, min(PERIOD_S, self._next - time.monotonic())))
            each()
            if done(self):
                return True
        return False


def flags(obc: Obc, *wanted: UplinkFlag) -> bool:
    status = obc.status
    return status is not None and all(status.has(flag) for flag in wanted)


def asking(obc: Obc, action: ArmingAction, flag: UplinkFlag, *, on: bool) -> Callable[[], None]:
    """Ask for `action` now and every 0.5 s until the FC's switch shows it, as an OBC does: the
    FC takes a request only while a command of its sender is in effect (spec §14), and a
    loaded host's OBC is now and then late past the timeout."""
    asked: list[float] = []

    def ask() -> None:
        if flags(obc, flag) != on and (not asked or time.monotonic() - asked[-1] >= 0.5):
            obc.reader.send_arming(action)
            asked.append(time.monotonic())

    ask()
    return ask


def test_the_obc_alone_arms_and_disarms_only_by_arming_requests(
    sitl_binary: Path, tmp_path: Path
) -> None:
    """Betaflight's own arming rules apply to the switch the FC holds: the request is sent
    once nothing but the switch keeps the FC from arming (MSP_STATUS_EX says)."""
    with (
        VirtualFcSession(sitl_binary, tmp_path, motion=Motion(), port_base=None) as fc,
        MspClient.open(fc.msp_url) as msp,
    ):
        obc = Obc(fc.fsp_url)
        try:
            receiver = obc.run_until(
                lambda o: o.status is not None and o.status.authority is Authority.RECEIVER
                and not msp.status_ex().arming_disabled,
                20.0,
            )  # fmt: skip
            assert receiver, (obc.status, msp.status_ex())
            assert not flags(obc, UplinkFlag.ARMED)
            obc.rc = (1500, 1500, 1500, 1000, 2000, 2000)  # aux3/aux4 high: no switch arms
            assert not obc.run_until(lambda o: flags(o, UplinkFlag.ARMED), 1.0)
            armed = obc.run_until(
                lambda o: flags(o, UplinkFlag.ARMED, UplinkFlag.ARM_SWITCH),
                10.0,
                each=asking(obc, ArmingAction.ARM, UplinkFlag.ARM_SWITCH, on=True),
            )
            assert armed, obc.status
            obc.rc = DEFAULTS
            assert not obc.run_until(lambda o: not flags(o, UplinkFlag.ARMED), 1.0)
        finally:
            obc.close()
        # A restarted program: a new sender, defaults from its first command on.
        restarted = Obc(fc.fsp_url)
        try:
            assert restarted.run_until(lambda o: flags(o, UplinkFlag.LIVE), 5.0)
            assert (
                restarted.status is not None and restarted.status.sender != obc.reader.sender.sender
            )
            assert not restarted.run_until(lambda o: not flags(o, UplinkFlag.ARMED), 1.0)
            assert flags(restarted, UplinkFlag.ARM_SWITCH)  # held through the silence
            disarmed = restarted.run_until(
                lambda o: not flags(o, UplinkFlag.ARMED) and not flags(o, UplinkFlag.ARM_SWITCH),
                5.0,
                each=asking(restarted, ArmingAction.DISARM, UplinkFlag.ARM_SWITCH, on=False),
            )  # fmt: skip
            assert disarmed, restarted.status
        finally:
            restarted.close()


def test_under_a_pilot_the_obc_steers_only_once_engaged_and_again_only_if_engaged_again(
    sitl_binary: Path, tmp_path: Path
) -> None:
    session = VirtualFcSession(sitl_binary, tmp_path, motion=Motion(), port_base=None, pilot=True)
    with session as fc:
        assert fc.radio is not None
        said: list[str] = []
        pilot = EngagingPilot(fc.radio, PILOT_OVERRIDE, say=said.append)
        obc = Obc(fc.fsp_url)
        obc.rc = (1300, 1500, 1500, 1000, 1500, 1500)
        try:
            ready = obc.run_until(
                lambda o: o.status is not None and o.status.authority is Authority.READY, 10.0
            )
            assert ready, obc.status
            assert obc.roll == 1500  # proven, not engaged: the pilot's sticks
            watch = lambda: pilot.observe(obc.status)  # noqa: E731
            engaged = obc.run_until(lambda o: o.roll == 1300, 5.0, each=watch)
            assert engaged and obc.status is not None, obc.status
            assert pilot.engagements == 1 and "pilot: the OBC is engaged" in " ".join(said), said

            obc.sending = False  # silence past the timeout: the pilot's sticks
            assert obc.run_until(lambda o: o.roll == 1500, 2.0)
            obc.sending = True  # back, fresh: proven again, but not engaged
            assert obc.run_until(
                lambda o: o.status is not None and o.status.authority is Authority.READY, 5.0
            )
            status = obc.status
            assert status is not None and status.exit is AuthorityExit.TIMEOUT
            assert not obc.run_until(lambda o: o.roll == 1300, 1.0)  # only the pilot engages
            assert obc.run_until(lambda o: o.roll == 1300, 5.0, each=watch)  # the switch on again
            assert pilot.engagements == 2, said
            assert obc.status is not None and obc.status.authority is Authority.ENGAGED
        finally:
            obc.close()


def test_msp_set_raw_rc_is_refused_and_counted_while_the_uplink_owns_the_receiver(
    sitl_binary: Path, tmp_path: Path
) -> None:
    """A second program on the other MSP port cannot steer past the uplink (spec §5): each
    MSP_SET_RAW_RC gets an error reply and is counted in E3, and the sticks stay the OBC's."""
    with (
        VirtualFcSession(sitl_binary, tmp_path, motion=Motion(), port_base=None) as fc,
        MspClient.open(fc.msp_url) as msp,
    ):
        obc = Obc(fc.fsp_url)
        try:
            obc.rc = (1300, 1500, 1500, 1000, 1500, 1500)
            steering = obc.run_until(lambda o: o.roll == 1300, 10.0)
            assert steering and obc.status is not None, obc.status
            before = obc.status.msp_rc_refused
            assert before is not None
            tries = 5
            rolls: list[int | None] = []
            for _ in range(tries):
                with pytest.raises(MspError, match="MSP_SET_RAW_RC"):
                    msp.set_raw_rc([1700, 1700, 1700, 1700, 2000, 2000, 2000, 2000])
            counted = obc.run_until(
                lambda o: o.status is not None and (o.status.msp_rc_refused or 0) >= before + tries,
                5.0,
                each=lambda: rolls.append(obc.roll),
            )
            assert counted, obc.status
            assert obc.status.msp_rc_refused == before + tries
            assert msp.rc()[0] == 1300 and 1700 not in rolls
        finally:
            obc.close()
