"""Commands: the virtual FC (sitl)."""

from __future__ import annotations

import selectors
import sys
import threading
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import click
from rich.text import Text

from wftool.cli.number import SECONDS, Number
from wftool.cli.ros2 import node_from, node_options
from wftool.cli.verify import criteria_options, err, run_options, session_from, verify_stream
from wftool.display import shown
from wftool.errors import UsageError
from wftool.fsp import DEFAULT_BAUDRATE, StatePacket
from wftool.fsp.schedule import DEFAULT_RATE_HZ, RATE_HZ_MAX, RATE_HZ_MIN
from wftool.recording.events import Event, Sink, StreamHealth
from wftool.sitl.process import (
    DEFAULT_PORT_BASE,
    GYRO_HZ_MAX,
    GYRO_HZ_MIN,
    MAX_PORT_BASE,
    SIM_PORT_OFFSET,
    VirtualBoard,
    scratch_workdir,
)
from wftool.sitl.radio import EngagingPilot
from wftool.verify.session import VerifySession

rate_option = click.option(
    "--rate",
    "rate_hz",
    type=click.IntRange(RATE_HZ_MIN, RATE_HZ_MAX),
    default=DEFAULT_RATE_HZ,
    show_default=True,
    help="fsp_rate_hz of the virtual FC.",
)


@click.command("sitl")
@click.option(
    "--binary",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="Run this SITL program [build the patched one: wftool build sitl].",
)
@click.option(
    "--workdir",
    type=click.Path(file_okay=False, path_type=Path),
    help="Where SITL keeps eeprom.bin and its log [a temporary directory, removed at the end "
    "unless the run failed].",
)
@rate_option
@click.option(
    "--motion/--no-motion",
    default=True,
    show_default=True,
    help="Feed synthetic IMU motion through SITL's simulator input.",
)
@click.option(
    "--time-reply",
    is_flag=True,
    help="The FC answers each command with a time reply (fsp_time_reply = ON; two-way timing, "
    "spec §10). With --verify: needs --uplink; the OBC times use the replies (--clock twoway) "
    "unless --clock says otherwise.",
)
@click.option(
    "--paper",
    is_flag=True,
    help="As the paper's board: a gyro reporting 3200 Hz whose samples come at 3148 Hz, UARTs "
    "at their baud rates, serial_update_rate_hz 1000, the MSP port at 921600 baud (the "
    "options below override).",
)
@click.option(
    "--gyro-hz",
    type=click.IntRange(GYRO_HZ_MIN, GYRO_HZ_MAX),
    help="The sample rate the virtual gyro reports; the FC's looptime follows from it [8000].",
)
@click.option(
    "--gyro-clock-hz",
    type=Number(GYRO_HZ_MIN, GYRO_HZ_MAX, unit="Hz"),
    help="The rate its samples really come at, which the PID loop locks onto (a board's gyro "
    "runs off its own oscillator) [as --gyro-hz].",
)
@click.option(
    "--uart-pacing",
    is_flag=True,
    help="UARTs move bytes at their baud rate in FC time, 10 bits a byte, both ways, as wires "
    "do [as fast as TCP].",
)
@click.option(
    "--msp-baud",
    type=click.IntRange(9600, 2470000),
    help="The MSP port's baud rate (UART1; it counts with --uart-pacing) [115200].",
)
@click.option(
    "--pilot",
    is_flag=True,
    help="A safety pilot: the simulated radio (SITL's RC input) is the receiver, ARM on its "
    "AUX1 (off), sticks centred, throttle low; the OBC's commands override the sticks once "
    "the pilot has engaged it, turning the AUX2 switch off and on whenever the FC reports "
    "the OBC ready (or, with your OBC on the FSP port, when you press Enter). Without it the "
    "OBC flies alone (RX_MSP), arming by arming requests.",
)
@click.option(
    "--verify",
    "verify_s",
    type=SECONDS,
    metavar="SECONDS",
    help="Verify the stream for SECONDS, then stop with the verdict as exit code.",
)
@click.option(
    "--port-base",
    type=click.IntRange(0, MAX_PORT_BASE),
    default=DEFAULT_PORT_BASE,
    show_default=True,
    help=f"UARTn on TCP PORT_BASE+n; simulator UDP at PORT_BASE+{SIM_PORT_OFFSET + 1}... "
    "0: any free ports.",
)
@click.option(
    "--project",
    "project_dir",
    type=click.Path(file_okay=False, path_type=Path),
    help="The wftool checkout to build in [found from the current directory].",
)
@run_options
@criteria_options
@click.option(
    "--ros2",
    "ros2",
    is_flag=True,
    help="Publish the stream as a ROS 2 node, as `wftool ros2` does (extra ros2).",
)
@node_options
def sitl(
    binary: Path | None, workdir: Path | None, rate_hz: int, motion: bool, time_reply: bool,
    paper: bool, gyro_hz: int | None, gyro_clock_hz: float | None, uart_pacing: bool,
    msp_baud: int | None, pilot: bool,
    verify_s: float | None, port_base: int, project_dir: Path | None, ros2: bool,
    **options: Any,
) -> None:  # fmt: skip
    """Run the virtual FC: the patched SITL with FSP on UART2, until Ctrl-C (or --verify).

    Flown by the OBC alone (the MSP receiver), or with --pilot by a safety pilot's simulated
    radio, who engages the OBC on the override switch once the FC says it is ready.

    With --verify it is judged as a board is: the frame rate against what fsp_rate_hz gives at
    the FC's PID looptime (read over MSP), unless --expected-rate says otherwise. Without it,
    --record, --csv, --foxglove and --ros2 read the stream for as long as the FC runs.
    """
    from wftool.sitl.session import PILOT_ARM, PILOT_OVERRIDE, Motion, VirtualFcSession

    if options["accept_commands"] and not ros2:
        raise UsageError("--accept-commands is the ROS 2 node's: add --ros2")
    if options["accept_commands"] and options["uplink"]:
        raise UsageError("--uplink and --accept-commands both send commands: choose one")
    if verify_s is not None and time_reply:
        if not options["uplink"]:
            raise UsageError("--time-reply answers commands: add --uplink to send them")
        options["clock"] = options["clock"] or "twoway"
    if binary is None:
        binary = build_sitl(project_dir)
    with scratch_workdir(workdir, "wftool-sitl-") as workdir:
        board = VirtualBoard(gyro_hz, gyro_clock_hz, uart_pacing)
        serial_update_rate_hz = None
        if paper:
            from wftool.analysis.setup import PAPER_BOARD, PAPER_MSP_BAUD, SERIAL_RATE_HZ

            board = VirtualBoard(
                gyro_hz or PAPER_BOARD.gyro_hz,
                gyro_clock_hz or PAPER_BOARD.gyro_clock_hz,
                True,
            )
            msp_baud = msp_baud or PAPER_MSP_BAUD
            serial_update_rate_hz = SERIAL_RATE_HZ
        session = VirtualFcSession(
            binary, workdir, rate_hz=rate_hz, motion=Motion() if motion else None,
            port_base=port_base or None, time_reply=time_reply, board=board, msp_baud=msp_baud,
            serial_update_rate_hz=serial_update_rate_hz, pilot=pilot,
        )  # fmt: skip
        err.print(shown(f"starting the virtual FC in {workdir} …"))
        with session:
            err.print(Text.assemble("MSP/CLI  ", shown(session.msp_url, "bold")))
            replies = ", fsp_time_reply ON" if time_reply else ""
            err.print(
                Text.assemble(
                    "FSP      ",
                    shown(session.fsp_url, "bold"),
                    f"  (fsp_rate_hz {rate_hz}{replies})",
                )
            )
            sinks: list[Sink] = []
            pilot_flips: Callable[[threading.Event], None] | None = None
            if session.radio is not None:
                engaging = EngagingPilot(session.radio, PILOT_OVERRIDE, say=err.print)
                sinks.append(PilotWatch(engaging))
                pilot_flips = partial(flip_on_enter, engaging)
                err.print(
                    f"pilot    the simulated radio on UDP {session.fc.sim_rc_port}: ARM on "
                    f"AUX{PILOT_ARM} (off), override on AUX{PILOT_OVERRIDE} (off: the pilot turns "
                    "it on when the OBC is ready)"
                )
            if options["expected_rate"] is None:
                options["expected_rate"] = session.expected_rate_hz
            if ros2:
                bridge = node_from(**options)
                sinks.append(bridge)
                options["commander"] = bridge if options["accept_commands"] else None
            options["sinks"] = sinks
            if verify_s is not None:
                verify_stream(session.fsp_url, DEFAULT_BAUDRATE, verify_s, **options)
                return
            stream = serving_stream(session.fsp_url, **options)
            if stream is None and pilot_flips is not None:
                err.print(
                    "pilot    your OBC reads the FSP port, so the pilot cannot see when it is "
                    "ready: press Enter to turn the override switch off and on (once its uplink "
                    "status says READY)"
                )
            try:  # from the line on: a Ctrl-C the moment it shows stops it as any later one
                err.print("running; Ctrl-C stops it")
                session.serve(
                    on_reset=lambda: err.print("the FC reset itself; starting it again"),
                    alongside=(lambda stop: stream.run(stop=stop)) if stream else pilot_flips,
                )
            except KeyboardInterrupt:
                err.print("stopping")
            finally:
                if stream is not None:
                    stream.close()


class PilotWatch:
    """A sink of the live loop that shows the simulated pilot each uplink status the FC
    sends, so it engages the OBC when the FC says it is ready."""

    def __init__(self, pilot: EngagingPilot) -> None:
        self.pilot = pilot

    def event(self, event: Event) -> None:
        pass

    def packets(self, packets: Sequence[StatePacket], health: StreamHealth | None = None) -> None:
        self.pilot.observe(health.uplink.status if health and health.uplink else None)

    def close(self) -> None:
        pass


def flip_on_enter(pilot: EngagingPilot, stop: threading.Event) -> None:
    """Turn the pilot's override switch off and on at each Enter on stdin, until `stop`
    (stdin at its end, or not a terminal: nothing more to read, serving goes on)."""
    if not sys.stdin.isatty():
        stop.wait()
        return
    with selectors.DefaultSelector() as selector:
        selector.register(sys.stdin, selectors.EVENT_READ)
        while not stop.is_set():
            if not selector.select(0.2):
                continue
            if not sys.stdin.readline():
                stop.wait()
                return
            pilot.engage()


def serving_stream(url: str, **options: Any) -> VerifySession | None:
    """The stream reader of a virtual FC served without --verify: it records and serves
    Foxglove if asked (None if not), and judges nothing; the simulated pilot alone needs no
    reader (the user's OBC reads the port)."""
    if not (
        options["record_path"]
        or options["csv_path"]
        or options["foxglove_port"] is not None
        or any(not isinstance(sink, PilotWatch) for sink in options.get("sinks", ()))
    ):
        return None
    stream = session_from(url, DEFAULT_BAUDRATE, None, **options)
    if options["record_path"] is not None:
        err.print(shown(f"recording to {options['record_path']}"))
    return stream


def build_sitl(project_dir: Path | None) -> Path:
    """The patched SITL program, built (or found up to date) in the wftool checkout."""
    from wftool.cli.build import build_with_progress
    from wftool.firmware import find_project

    result = build_with_progress(find_project(project_dir), "sitl")
    if not result.up_to_date:
        err.print(shown(f"built {result.firmware}"))
    return result.firmware


COMMANDS: list[click.Command] = [sitl]
