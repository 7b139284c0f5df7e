"""Commands: benchmarks that print figures (bench ...)."""

from __future__ import annotations

import click

COMMANDS: list[click.Command] = []
