"""Configuration backups: a `diff all` plus what the CLI cannot express, in a timestamped file.

Betaflight 2025.12 dropped RX_MSP from the CLI's feature names (PR #13494), so a `diff all`
of a board whose receiver is MSP does not say so. The backup therefore records the MSP
feature mask in a header comment, which the FC ignores and `wftool restore` reads back.
"""

from __future__ import annotations

import re
from datetime import datetime, timezone
from pathlib import Path

from wftool.fc.msp import BoardInfo

DEFAULT_BACKUP_DIR = Path("backups")
_FEATURE_MASK = re.compile(r"^# wftool: feature mask (0x[0-9a-fA-F]+)", re.MULTILINE)


def write_backup(directory: Path, board: BoardInfo, feature_mask: int, diff: str) -> Path:
    """Write a backup file named after the board and the UTC time; return its path."""
    now = datetime.now(timezone.utc)
    label = re.sub(r"[^A-Za-z0-9_.-]", "_", board.board_name or board.target_name or "fc")
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{label}-{now:%Y%m%d-%H%M%S-%f}.txt"
    header = (
        f"# wftool backup of {board.board_name or '-'} ({board.target_name}) "
        f"at {now:%Y-%m-%dT%H:%M:%SZ}\n"
        f"# wftool: feature mask 0x{feature_mask:08x} (from MSP; the CLI cannot name RX_MSP)\n"
    )
    path.write_text(header + diff.rstrip("\n") + "\n")
    return path


def feature_mask_of(script: str) -> int | None:
    """The MSP feature mask a backup recorded, or None for other scripts."""
    match = _FEATURE_MASK.search(script)
    return int(match[1], 16) if match else None
