"""The build errors, one class per thing that can go wrong, so callers can tell them apart."""

from __future__ import annotations

from wftool.errors import BuildError


class TreeError(BuildError):
    """The Betaflight tree is missing, dirty, on the wrong commit or cannot be fetched."""


class PatchError(BuildError):
    """The patch series does not apply, or cannot be exported."""


class ToolchainError(BuildError):
    """No usable compiler, a version mismatch under --strict-toolchain, or a failed install."""
