"""Commands: talking to a flight controller (set, config, configure, backup, restore, flash, doctor)."""

from __future__ import annotations

import click

COMMANDS: list[click.Command] = []
