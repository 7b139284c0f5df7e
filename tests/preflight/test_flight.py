"""The moves of a run that need no FC: what counts as the pilot's sticks, the OBC's command
away from them, and the aux values that switch no mode (or keep the FC armed on firmware
that arms through AUX3/AUX4)."""

from __future__ import annotations

from dataclasses import replace

from tests.preflight.test_settings import PILOT_ARM, alone, piloted
from wftool.fc.modes import MODE_ARM, AuxRange
from wftool.fc.msp import ArmingDisabled, FcStatus
from wftool.preflight.flight import Flight, away_from, largest_move, near
from wftool.preflight.pilot import NoPilot
from wftool.preflight.watcher import Snapshot


def flight(settings, pilot_rc=()) -> Flight:  # type: ignore[no-untyped-def]
    return Flight(None, None, NoPilot(), settings, pilot_rc=pilot_rc)  # type: ignore[arg-type]


def test_near_and_away() -> None:
    assert near((1500, 1490), (1505, 1500)) and not near((1500, 1489), (1500, 1500))
    assert away_from((1500, 1500, 1500, 1000)) == (1800, 1800, 1800, 1150)
    assert away_from((1900, 1100, 1600, 2000)) == (1600, 1400, 1300, 2000)


def test_the_largest_move_is_over_all_sticks() -> None:
    class Seen:
        def __init__(self, sticks: tuple[int, ...]) -> None:
            self.sticks = sticks

    seen = [Seen((1500, 1500, 1500, 1000)), Seen((1500, 1520, 1500, 1000))]
    assert largest_move(seen, (1500, 1500, 1500, 1000)) == 20  # type: ignore[arg-type]
    assert largest_move([], (1500, 1500, 1500, 1000)) == 0


def test_with_a_pilot_the_obc_commands_away_from_the_pilots_aux3_aux4() -> None:
    pilot_rc = (1500, 1500, 1500, 1000, 1000, 1000, 1000, 2000)
    assert flight(piloted(), pilot_rc).command() == (1800, 1800, 1800, 1150, 2000, 1000)


def test_alone_aux3_aux4_switch_no_mode() -> None:
    assert flight(alone()).command() == (1400, 1600, 1450, 1000, 1000, 1000)
    beeper = AuxRange(1, 13, 2, 900, 1200)  # BEEPER on AUX3 at 1000: the aux moves off it
    assert flight(alone(ranges=[PILOT_ARM, beeper])).command()[4] == 2000


def test_armed_through_aux3_on_firmware_before_arming_requests() -> None:
    arm3 = AuxRange(0, MODE_ARM, 2, 1700, 2100)
    run = flight(replace(alone(), ranges=[arm3]))
    assert run.command()[4] == 1000  # disarmed: the switch off
    run.armed = True
    assert run.command()[4] == arm3.on_us


def test_a_hold_that_lost_the_radio_says_from_when_and_what_the_fc_showed() -> None:
    """The line names how many replies showed RXLOSS, from how long after its start, and
    what the first of them showed: the evidence to tell a handover from a lost radio."""
    pilot = (1500, 1500, 1500, 1000)

    def seen(at: float, rx_loss: bool) -> Snapshot:
        disabled = ArmingDisabled.RX_FAILSAFE if rx_loss else ArmingDisabled(0)
        return Snapshot(at, at, pilot, FcStatus(0, disabled), True, False, False)

    class Watcher:
        def since(self, t: float) -> list[Snapshot]:
            return [s for s in replies if s.asked >= t]

    class Uplink:
        status = None

    replies = [seen(100.0 + 0.05 * i, rx_loss=i in (4, 5)) for i in range(10)]
    run = Flight(Watcher(), Uplink(), NoPilot(), piloted(), armed=True)  # type: ignore[arg-type]
    line = run.holds("hold", 100.0, pilot, seconds=0.45)
    assert not line.passed
    assert line.measured == (
        "RXLOSS/failsafe in 2 of 10 MSP replies, from 200 ms on (RXLOSS, arming disabled "
        f"{ArmingDisabled.RX_FAILSAFE!r}; uplink: no uplink status)"
    )
    replies[4:6] = [seen(100.2, False), seen(100.25, False)]
    assert run.holds("hold", 100.0, pilot, seconds=0.45).passed
