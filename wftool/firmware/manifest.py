"""manifest.json: what a firmware was built from, so it can be traced and checked at flash time.

One typed `Manifest` for everyone: the builder makes and writes it, `wftool build` prints
it, `wftool flash` loads it (schema-checked). The flasher codes against these keys (schema
1): it refuses firmware whose `board`/`mcu` differ from the flight controller's, and
confirms after flashing that the firmware reports `git_revision` (MSP_BUILD_INFO carries
its first 7 characters: `git_revision_msp`). Artifact paths are relative to the manifest's
directory.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from wftool.errors import UsageError
from wftool.firmware.make import Usage

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


@dataclass(frozen=True)
class Manifest:
    """`build/<target>/manifest.json`: built by the builder, shown by the CLI, checked by the
    flasher. `load` checks the schema; `to_json` is the file's content."""

    path: Path
    target: str
    board: str
    mcu: str
    betaflight_commit: str
    betaflight_head: str
    betaflight_version: str | None
    git_revision: str
    patch_series_sha256: str
    patches: list[dict[str, str]]
    """`{"name", "sha256"}` per patch, in series order."""
    board_config_sha256: str | None
    toolchain: dict[str, Any]
    """`{"path", "version", "required", "strict"}`."""
    flags: BuildFlags
    usage: Usage | None
    build_seconds: float | None
    built_at: str
    artifacts: dict[str, str]
    """Kind (hex, bin, elf, exe) → file name relative to the manifest."""
    artifact_sha256: dict[str, str]
    inputs_sha256: str

    @property
    def out_dir(self) -> Path:
        """build/<target>/, where the artifacts are."""
        return self.path.parent

    @property
    def git_revision_msp(self) -> str:
        """What MSP_BUILD_INFO reports of `git_revision`."""
        return self.git_revision[:MSP_REVISION_LENGTH]

    def artifact(self, kind: str) -> Path | None:
        """The artifact of this kind (hex, bin, elf, exe), None if the build made none."""
        name = self.artifacts.get(kind)
        return self.out_dir / name if name else None

    @property
    def hex(self) -> Path | None:
        return self.artifact("hex")

    @property
    def bin(self) -> Path | None:
        return self.artifact("bin")

    @property
    def firmware(self) -> Path:
        """The file to flash (.hex) or to run (SITL)."""
        found = self.artifact("hex") or self.artifact("exe") or self.artifact("elf")
        assert found is not None, "load() checks that there is an elf"
        return found

    def to_json(self) -> dict[str, Any]:
        """The file's content (schema 1)."""
        return {
            "schema": SCHEMA,
            "target": self.target,
            "board": self.board,
            "mcu": self.mcu,
            "betaflight_commit": self.betaflight_commit,
            "betaflight_head": self.betaflight_head,
            "betaflight_version": self.betaflight_version,
            "git_revision": self.git_revision,
            "git_revision_msp": self.git_revision_msp,
            "patch_series_sha256": self.patch_series_sha256,
            "patches": [dict(patch) for patch in self.patches],
            "board_config_sha256": self.board_config_sha256,
            "toolchain": dict(self.toolchain),
            "flags": self.flags.to_json(),
            "usage": None if self.usage is None else dataclasses.asdict(self.usage),
            "build_seconds": self.build_seconds,
            "built_at": self.built_at,
            "artifacts": dict(self.artifacts),
            "artifact_sha256": dict(self.artifact_sha256),
            "inputs_sha256": self.inputs_sha256,
        }

    def write(self) -> None:
        """Write atomically (temp file + rename), so readers never see half a manifest."""
        temporary = self.path.with_name(f".{self.path.name}.tmp")
        temporary.write_text(json.dumps(self.to_json(), indent=2) + "\n")
        os.replace(temporary, self.path)

    @classmethod
    def load(cls, path: Path) -> Manifest:
        """The manifest at PATH, checked against the schema; `UsageError` says what is wrong."""
        try:
            data = json.loads(path.read_text())
            if not isinstance(data, dict):
                raise ValueError("not a JSON object")
            return cls._from_json(path, data)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            reason = f"no {exc}" if isinstance(exc, KeyError) else str(exc)
            raise UsageError(f"bad build manifest {path}: {reason}") from None

    @classmethod
    def read(cls, path: Path) -> Manifest | None:
        """The manifest at PATH, or None when there is none or it does not check out."""
        try:
            return cls.load(path)
        except UsageError:
            return None

    @classmethod
    def _from_json(cls, path: Path, data: dict[str, Any]) -> Manifest:
        if data.get("schema") != SCHEMA:
            raise ValueError(f"schema {data.get('schema')!r}, this wftool reads {SCHEMA}")
        artifacts = _field(data, "artifacts", dict)
        if "elf" not in artifacts:
            raise ValueError("artifacts lists no elf")
        flags = _field(data, "flags", dict)
        usage = _field(data, "usage", dict, None)
        return cls(
            path=path,
            target=_field(data, "target", str),
            board=_field(data, "board", str),
            mcu=_field(data, "mcu", str),
            betaflight_commit=_field(data, "betaflight_commit", str),
            betaflight_head=_field(data, "betaflight_head", str),
            betaflight_version=_field(data, "betaflight_version", str, None),
            git_revision=_field(data, "git_revision", str),
            patch_series_sha256=_field(data, "patch_series_sha256", str),
            patches=_field(data, "patches", list),
            board_config_sha256=_field(data, "board_config_sha256", str, None),
            toolchain=_field(data, "toolchain", dict),
            flags=BuildFlags(
                flags["fsp_rate_hz"],
                flags["mavlink_tunnel"],
                tuple(flags["defines"]),
                flags["debug"],
            ),
            usage=None if usage is None else Usage(**usage),
            build_seconds=_field(data, "build_seconds", int, float, None),
            built_at=_field(data, "built_at", str),
            artifacts=artifacts,
            artifact_sha256=_field(data, "artifact_sha256", dict),
            inputs_sha256=_field(data, "inputs_sha256", str),
        )


def _field(data: dict[str, Any], key: str, *types: type | None) -> Any:
    """DATA[KEY], checked to be one of TYPES (None allows null)."""
    value = data[key]
    allowed = tuple(type(None) if kind is None else kind for kind in types)
    if not isinstance(value, allowed):
        raise TypeError(f"{key} is {type(value).__name__}")
    return value
