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


class ClockError(WftoolError):
    """The FC clock is not known well enough for what was asked: a timed command before the
    stream's clock is locked, or for an OBC time the FC clock cannot express."""


class ProtocolError(WftoolError):
    """The peer answered, but not as the protocol says (timeout, bad checksum, error reply)."""


class BuildError(WftoolError):
    """Fetching, patching or compiling the firmware failed."""


class TreeError(BuildError):
    """The Betaflight tree is missing, dirty, on the wrong commit or cannot be fetched."""


class PatchError(BuildError):
    """The patch series does not apply, or cannot be exported."""


class ToolchainError(BuildError):
    """No usable compiler, a version mismatch under --strict-toolchain, or a failed install."""


class FlashError(WftoolError):
    """Flashing did not complete or did not verify."""


class MspError(ProtocolError):
    """An MSP exchange failed: no reply in time, a corrupt frame, or an error reply (`$M!`)."""


class CliCommandError(ProtocolError):
    """The flight controller's CLI rejected a command (`###ERROR IN …###` and friends)."""

    def __init__(self, command: str, fc_error: str) -> None:
        super().__init__(f"`{command}`: {fc_error}")
        self.command = command
        self.fc_error = fc_error
        """What the FC printed, e.g. "INVALID VALUE (Allowed range: 0 - 1000)"."""


class UnsupportedFirmware(UsageError):
    """The FC runs a firmware (variant, version, MSP API) wftool does not talk to."""


class ParameterError(UsageError):
    """Parameters the flight controller would reject; found before anything was changed."""


class MissingExtraError(UsageError):
    """An optional dependency is not installed (`wftool.extras.require` names the extra)."""


class VerificationFailed(WftoolError):
    """The stream ran but did not meet the criteria (exit 1)."""


class RecordingError(WftoolError):
    """A recording could not go on (disk full, I/O error); the file is finished up to there."""


class SitlError(WftoolError):
    """The SITL (virtual flight controller) process would not start, or died."""


class PortInUseError(SitlError):
    """A port the virtual FC needs is held by another program (another virtual FC?)."""

    exit_code = EXIT_USAGE


class Ros2Error(WftoolError):
    """ROS 2 could not do its part: the wftool_msgs type support would not build, or the
    middleware would not start."""


class Terminated(BaseException):
    """SIGTERM or SIGHUP arrived: unwind (closing ports, stopping the virtual FC) and exit
    128 + the signal number, as a shell reports a process the signal ended."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum
