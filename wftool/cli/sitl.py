"""Commands: the virtual FC (sitl)."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import click

from wftool.cli.verify import criteria_options, err, run_options, session_from, verify_stream
from wftool.errors import UsageError
from wftool.fsp import DEFAULT_BAUDRATE
from wftool.fsp.schedule import DEFAULT_RATE_HZ, RATE_HZ_MAX, RATE_HZ_MIN
from wftool.sitl.process import DEFAULT_PORT_BASE, MAX_PORT_BASE, SIM_PORT_OFFSET
from wftool.verify.live import check_duration
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
    help="Where SITL keeps eeprom.bin [a new scratch directory].",
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
    "--pilot",
    is_flag=True,
    help="A safety pilot: the simulated radio (SITL's RC input) is the receiver, ARM on its "
    "AUX1, and the OBC's commands override the sticks while its AUX2 switch is on (held on; "
    "sticks centred, throttle low, disarmed). Without it the OBC flies alone (RX_MSP).",
)
@click.option(
    "--verify",
    "verify_s",
    type=float,
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
def sitl(
    binary: Path | None, workdir: Path | None, rate_hz: int, motion: bool, time_reply: bool,
    pilot: bool, verify_s: float | None, port_base: int, project_dir: Path | None,
    **options: Any,
) -> None:  # fmt: skip
    """Run the virtual FC: the patched SITL with FSP on UART2, until Ctrl-C (or --verify).

    Flown by the OBC alone (the MSP receiver), or with --pilot by a safety pilot's simulated
    radio with the OBC overriding the sticks on its switch.

    With --verify it is judged as a board is: the frame rate against what fsp_rate_hz gives at
    the FC's PID looptime (read over MSP), unless --expected-rate says otherwise. Without it,
    --record, --csv and --foxglove read the stream for as long as the FC runs.
    """
    from wftool.sitl.radio import HIGH
    from wftool.sitl.session import PILOT_ARM, PILOT_OVERRIDE, Motion, VirtualFcSession

    check_duration(verify_s, "--verify")
    if verify_s is not None and time_reply:
        if not options["uplink"]:
            raise UsageError("--time-reply answers commands: add --uplink to send them")
        options["clock"] = options["clock"] or "twoway"
    if binary is None:
        binary = build_sitl(project_dir)
    workdir = workdir or Path(tempfile.mkdtemp(prefix="wftool-sitl-"))
    session = VirtualFcSession(
        binary, workdir, rate_hz=rate_hz, motion=Motion() if motion else None,
        port_base=port_base or None, time_reply=time_reply, pilot=pilot,
    )  # fmt: skip
    err.print(f"starting the virtual FC in {workdir} …")
    with session:
        err.print(f"MSP/CLI  [bold]{session.msp_url}[/]")
        replies = ", fsp_time_reply ON" if time_reply else ""
        err.print(f"FSP      [bold]{session.fsp_url}[/]  (fsp_rate_hz {rate_hz}{replies})")
        if session.radio is not None:
            session.radio.set({f"aux{PILOT_OVERRIDE}": HIGH})
            err.print(
                f"pilot    the simulated radio on UDP {session.fc.sim_rc_port}: ARM on "
                f"AUX{PILOT_ARM} (off), override on AUX{PILOT_OVERRIDE} (on)"
            )
        if options["expected_rate"] is None:
            options["expected_rate"] = session.expected_rate_hz
        if verify_s is not None:
            verify_stream(session.fsp_url, DEFAULT_BAUDRATE, verify_s, **options)
            return
        stream = serving_stream(session.fsp_url, **options)
        err.print("running; Ctrl-C stops it")
        try:
            session.serve(
                on_reset=lambda: err.print("the FC reset itself; starting it again"),
                alongside=(lambda stop: stream.run(stop=stop)) if stream else None,
            )
        except KeyboardInterrupt:
            err.print("stopping")
        finally:
            if stream is not None:
                stream.close()


def serving_stream(url: str, **options: Any) -> VerifySession | None:
    """The stream reader of a virtual FC served without --verify: it records and serves
    Foxglove if asked (None if not), and judges nothing."""
    if not (options["record_path"] or options["csv_path"] or options["foxglove_port"] is not None):
        return None
    stream = session_from(url, DEFAULT_BAUDRATE, None, **options)
    if options["record_path"] is not None:
        err.print(f"recording to {options['record_path']}")
    return stream


def build_sitl(project_dir: Path | None) -> Path:
    """The patched SITL program, built (or found up to date) in the wftool checkout."""
    from wftool.cli.build import build_with_progress
    from wftool.firmware import find_project

    result = build_with_progress(find_project(project_dir), "sitl")
    if not result.up_to_date:
        err.print(f"built {result.firmware}")
    return result.firmware


COMMANDS: list[click.Command] = [sitl]
