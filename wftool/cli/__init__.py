"""The `wftool` command line: a thin click layer over the importable API.

Each sibling module holds the commands of one concern and lists them in `COMMANDS`.
This is the only place where exceptions become messages and exit codes.
"""

from __future__ import annotations

import sys

import click
from rich.console import Console
from rich.markup import escape

from wftool import __version__
from wftool.cli import bench, build, fc, stream
from wftool.errors import EXIT_USAGE, WftoolError

err_console = Console(stderr=True, highlight=False)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="wftool")
def cli() -> None:
    """Build, flash, configure and verify the Weitflug research firmware."""


for _module in (build, fc, stream, bench):
    for _command in _module.COMMANDS:
        cli.add_command(_command)


def main(argv: list[str] | None = None) -> None:
    """Entry point: run the CLI and map errors to one line and an exit code."""
    try:
        cli.main(args=argv, prog_name="wftool", standalone_mode=False)
    except WftoolError as exc:
        err_console.print(f"[bold red]error:[/] {escape(str(exc))}", soft_wrap=True)
        sys.exit(exc.exit_code)
    except click.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code if exc.exit_code else EXIT_USAGE)
    except (click.Abort, KeyboardInterrupt):
        err_console.print("aborted")
        sys.exit(130)
    sys.exit(0)
