"""Commands: talking to a flight controller (set, config, backup, restore, flash, doctor)."""

from __future__ import annotations

import click

COMMANDS: list[click.Command] = []
