"""The `wftool` command line: a thin click layer over the importable API.

Each sibling module holds the commands of one concern and lists them in `COMMANDS`.
This is the only place where exceptions become messages and exit codes.
"""

from __future__ import annotations

import io
import signal
import sys

import click
from rich.console import Console
from rich.text import Text

from wftool import __version__
from wftool.cli import analyze, bench, build, fc, paper, preflight, record, ros2, sitl, verify
from wftool.display import printable, shown
from wftool.errors import EXIT_USAGE, Terminated, WftoolError
from wftool.interrupts import raise_for

err_console = Console(stderr=True, highlight=False)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="wftool")
def cli() -> None:
    """Build, flash, configure and verify the Weitflug research firmware."""


for _module in (build, fc, verify, preflight, record, sitl, ros2, bench, analyze, paper):
    for _command in _module.COMMANDS:
        cli.add_command(_command)


def _terminate(signum: int, _frame: object) -> None:
    raise_for(signum)


def main(argv: list[str] | None = None) -> None:
    """Entry point: run the CLI and map errors to one line and an exit code.

    SIGTERM and SIGHUP unwind like Ctrl-C, so whatever the command holds (a virtual FC, a
    recording, an FC in its CLI) is released on the way out.
    """
    previous = {sig: signal.signal(sig, _terminate) for sig in (signal.SIGTERM, signal.SIGHUP)}
    try:
        cli.main(args=argv, prog_name="wftool", standalone_mode=False)
    except WftoolError as exc:
        err_console.print(Text.assemble(("error:", "bold red"), " ", shown(exc)), soft_wrap=True)
        sys.exit(exc.exit_code)
    except Terminated as exc:
        err_console.print(f"terminated ({signal.Signals(exc.signum).name})")
        sys.exit(128 + exc.signum)
    except click.ClickException as exc:
        message = io.StringIO()
        exc.show(file=message)  # it quotes the arguments as given: shown as text
        for line in message.getvalue().splitlines():
            click.echo(printable(line), err=True)
        sys.exit(exc.exit_code if exc.exit_code else EXIT_USAGE)
    except (click.Abort, KeyboardInterrupt):
        err_console.print("aborted")
        sys.exit(130)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    sys.exit(0)
