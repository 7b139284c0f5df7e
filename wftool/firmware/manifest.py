"""manifest.json: what a firmware was built from, so it can be traced and checked at flash time.

`wftool flash` codes against these keys (schema 1): it refuses firmware whose `board`/`mcu`
differ from the flight controller's, and confirms after flashing that the firmware reports
`git_revision` (MSP_BUILD_INFO carries its first 7 characters: `git_revision_msp`).
Artifact paths are relative to the manifest's directory.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from wftool.errors import UsageError

SCHEMA = 1
FILE_NAME = "manifest.json"
MSP_REVISION_LENGTH = 7
"""GIT_SHORT_REVISION_LENGTH in Betaflight's build/version.h: what MSP_BUILD_INFO sends."""


@dataclass(frozen=True)
class BuildFlags:
    """The researcher-facing options that change the firmware."""

    fsp_rate_hz: int | None = None
    mavlink_tunnel: bool = False
    defines: tuple[str, ...] = ()
    debug: bool = False

    def compiler_defines(self) -> list[str]:
        """The -D flags these options add (FSP_RATE_HZ_DEFAULT, USE_FSP_MAVLINK_TUNNEL...)."""
        defines = []
        if self.fsp_rate_hz is not None:
            defines.append(f"FSP_RATE_HZ_DEFAULT={self.fsp_rate_hz}")
        if self.mavlink_tunnel:
            defines.append("USE_FSP_MAVLINK_TUNNEL")
        defines += self.defines
        return [f"-D{define}" for define in defines]

    def to_json(self) -> dict[str, Any]:
        """The manifest's `flags` object."""
        return {
            "fsp_rate_hz": self.fsp_rate_hz,
            "mavlink_tunnel": self.mavlink_tunnel,
            "defines": list(self.defines),
            "debug": self.debug,
        }


def file_sha256(path: Path) -> str:
    """SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with path.open("rb") as source:
        while chunk := source.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


def read(path: Path) -> dict[str, Any] | None:
    """The manifest at PATH, or None when there is none (or it is unreadable)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def load(path: Path) -> dict[str, Any]:
    """The manifest at PATH, checked for the schema this wftool understands."""
    data = read(path)
    if data is None:
        raise UsageError(f"{path} is not a readable manifest.json")
    if data.get("schema") != SCHEMA:
        raise UsageError(f"{path} has manifest schema {data.get('schema')}, expected {SCHEMA}")
    return data


def write(path: Path, data: dict[str, Any]) -> None:
    """Write atomically (temp file + rename), so readers never see half a manifest."""
    temporary = path.with_name(f".{path.name}.tmp")
    temporary.write_text(json.dumps(data, indent=2) + "\n")
    os.replace(temporary, path)
