"""The paper's set-up as this project reproduces it: the virtual FC emulating the paper's
board, from its published set-up (`published.SETUP`), and the choices the paper leaves open,
said as ours.

    VirtualFcSession(binary, workdir, board=PAPER_BOARD, msp_baud=PAPER_MSP_BAUD)
"""

from __future__ import annotations

from wftool.analysis.published import SETUP
from wftool.sitl.process import VirtualBoard

PAPER_BOARD = VirtualBoard(
    gyro_hz=round(SETUP.loop_nominal_hz.value),
    gyro_clock_hz=SETUP.loop_hz.value,
    uart_pacing=True,
)
"""The paper's board as the virtual FC emulates it: a gyro reporting the nominal 3.2 kHz
whose samples come at the 3148 Hz the scheduler reports (§5.1), UARTs as wires."""
SERIAL_RATE_HZ = round(SETUP.serial_update_rate_hz.value)
"""The paper's MSP baseline: a 1 kHz serial task (`serial_update_rate_hz`, §5.1)."""
PAPER_MSP_BAUD = 921600
"""Ours: the MSP port's baud rate, which the paper does not state. Polling MSP_RAW_IMU at
1 kHz needs more than 115200 (a reply alone takes 2.1 ms there), and 921600 is the common
fast rate of a companion computer's UART link (a Jetson's ttyTHS takes it)."""
PAPER_MSP_BAUD_WHY = (
    "ours: 1 kHz polling needs more than 115200, where a RAW_IMU reply alone takes 2.1 ms; "
    "921600 is the common fast rate of a companion computer's UART"
)
FSP_BAUD_WHY = "ours: FSP's default, at which a state packet takes 0.59 ms"
MSP_BAUD_SWEEP = (115200, 1000000)
"""Ours: further MSP baud rates the virtual FC is polled at, to show how the MSP figures
move with it."""
