"""Who holds the radio: a person asked in words, and the virtual FC's simulated radio moved
where the FC's own mode ranges and channel map put the switches (its frames read back off
the wire)."""

from __future__ import annotations

import socket
import struct
from dataclasses import replace

from tests.preflight.test_settings import OVERRIDE, PILOT_ARM, piloted
from wftool.fc.modes import MODE_MSP_OVERRIDE, AuxRange
from wftool.preflight.pilot import HumanPilot, RadioPilot, switch_position
from wftool.sitl.radio import RC_CHANNELS, SimulatedRadio

FRAME = struct.Struct(f"<d{RC_CHANNELS}H")
TAER = (1, 2, 3, 0, 4, 5, 6, 7)
"""The raw channels of roll, pitch, yaw, throttle, AUX1-4 under `map TAER1234`."""


def test_a_switch_sits_mid_range_when_on_and_clear_of_it_when_off() -> None:
    assert switch_position(OVERRIDE, True) == 1900 and switch_position(OVERRIDE, False) == 1000
    low = AuxRange(1, MODE_MSP_OVERRIDE, 1, 900, 1300)
    assert switch_position(low, False) == 2000
    stuck = AuxRange(1, MODE_MSP_OVERRIDE, 1, 900, 2100)  # no off position: the far end
    assert switch_position(stuck, True) == 1500 and switch_position(stuck, False) in (1000, 2000)


def test_a_person_is_asked_in_words() -> None:
    asked: list[str] = []
    pilot = HumanPilot(asked.append)
    pilot.hold(override=True, armed=False)
    assert pilot.transmitter(False)
    assert asked == [
        "disarm, override switch ON; sticks centred and still, throttle low",
        "transmitter OFF (props off!)",
    ]


def test_the_radio_flips_the_switches_on_the_fcs_channels() -> None:
    """Under `map TAER1234` the throttle is raw channel 1 and AUX2 raw channel 6."""
    settings = replace(piloted(), rcmap=TAER)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(2.0)
        with SimulatedRadio(sock.getsockname()[1]) as radio:
            pilot = RadioPilot(radio, settings)
            pilot.hold(override=True, armed=True)
            while True:  # the transmitter's frames, until one carries the switches
                channels = FRAME.unpack(sock.recv(FRAME.size))[1:]
                if channels[5] == 1900:
                    break
    assert channels[0] == 1000 and channels[1:4] == (1500, 1500, 1500)  # throttle low
    assert channels[5] == OVERRIDE.on_us and channels[4] == PILOT_ARM.on_us
