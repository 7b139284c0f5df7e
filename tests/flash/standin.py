"""Handle on the dfu-util STAND-IN's state (see standin_dfu_util.py)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

SCRIPT = Path(__file__).with_name("standin_dfu_util.py")
FLASH_SIZE = 512 << 10
UNTOUCHED = 0xA5
"""What the stand-in's flash holds before a test: anything written or erased changes it."""


@dataclass
class StandinDfuUtil:
    """Handle on the stand-in's state: configure it, read what it was asked and wrote."""

    state: Path

    def configure(self, **settings: object) -> None:
        (self.state / "config.json").write_text(json.dumps(settings))

    def calls(self) -> list[list[str]]:
        path = self.state / "calls.jsonl"
        return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []

    def flash(self) -> bytes:
        return (self.state / "flash.bin").read_bytes()
