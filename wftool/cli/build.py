"""Commands: building the firmware (build, patches, toolchain)."""

from __future__ import annotations

import click

COMMANDS: list[click.Command] = []
