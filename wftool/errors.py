"""The exceptions wftool raises on purpose.

Library code raises these; only the CLI edge (`wftool.cli.main`) turns them into a one-line
message and an exit code. Anything else escaping is a bug and keeps its traceback.
"""

from __future__ import annotations

EXIT_FAILURE = 1
"""The operation ran and did not succeed (build failed, verification failed, ...)."""
EXIT_USAGE = 2
"""The operation could not run: bad arguments or input, a port that cannot be opened."""


class WftoolError(Exception):
    """Base of every error wftool reports to a user."""

    exit_code = EXIT_FAILURE


class UsageError(WftoolError):
    """Bad arguments or input files."""

    exit_code = EXIT_USAGE


class PortError(WftoolError):
    """A serial port (or pyserial URL) cannot be opened, or vanished while in use."""

    exit_code = EXIT_USAGE


class ProtocolError(WftoolError):
    """The peer answered, but not as the protocol says (timeout, bad checksum, error reply)."""


class BuildError(WftoolError):
    """Fetching, patching or compiling the firmware failed."""


class FlashError(WftoolError):
    """Flashing did not complete or did not verify."""
