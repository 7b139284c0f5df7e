"""Commands: the FSP stream (verify, replay, sitl)."""

from __future__ import annotations

import click

COMMANDS: list[click.Command] = []
