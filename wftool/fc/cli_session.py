"""A session with Betaflight's text CLI: enter, run commands, read settings, save or leave.

Betaflight facts (2025.12 `cli.c`, `msp_serial.c`) this is built on:

- `#` on an MSP port only *requests* the CLI; it opens after 100 ms without input and then
  prints a banner and the `# ` prompt. Bytes sent before that are swallowed, which is why a
  command sent right after `#` gets lost. So: send `#` plus a newline (harmless in either
  state: in a CLI already open it just re-prints the prompt) and wait for the prompt.
- Errors read `###ERROR IN <command>: <message>###`, e.g. `INVALID NAME: foo`,
  `INVALID VALUE` followed by the line `Allowed range: 0 - 1000`.
- Every way out reboots: `save` (persist, then reboot) and `exit` (reboot, "unsaved changes
  lost"). `exit noreboot` keeps running with the unsaved changes live in RAM and arming
  blocked until the next reboot; wftool uses it only to hand the port back to MSP briefly.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass

import serial

from wftool.errors import CliCommandError, PortError, ProtocolError
from wftool.fc.transport import open_port, port_errors

PROMPT = b"\r\n# "
SETTLE_S = 0.05
"""Quiet time after a prompt before a reply counts as complete (`# ` also starts comment
lines inside `diff` output)."""
EXIT_SETTLE_S = 0.1
"""After `exit noreboot`: time for the FC to finish its CLI input loop before MSP."""

_ERROR = re.compile(r"###ERROR IN ([^:]*): (.*?)###")
_INTEGER = re.compile(r"[+-]?\d+")
_RANGE = re.compile(r"Allowed range: (-?\d+) - (-?\d+)")
_VALUES = re.compile(r"Allowed values: (.*)")
_ARRAY = re.compile(r"Array length: (\d+)")
_STRING = re.compile(r"String length: (\d+) - (\d+)")
_SCOPE = re.compile(r"(profile|rateprofile) \d+")


@dataclass(frozen=True)
class Setting:
    """One CLI setting as `get NAME` reports it: value and the FC's own constraint."""

    name: str
    value: str
    constraint: str
    """The FC's line verbatim, e.g. "Allowed range: 0 - 1000" or "Allowed values: OFF, ON"."""
    scope: str | None = None
    """"profile 0"/"rateprofile 0" for per-profile settings, None for global ones."""

    @property
    def int_range(self) -> tuple[int, int] | None:
        """(min, max) for numeric settings."""
        match = _RANGE.fullmatch(self.constraint)
        return (int(match[1]), int(match[2])) if match else None

    def problem(self, value: str) -> str | None:
        """Why the FC would refuse (or silently mangle) `value`, or None if it is fine."""
        if self.int_range:
            low, high = self.int_range
            if not _INTEGER.fullmatch(value):
                return f"not an integer; {self.constraint}"
            return None if low <= int(value) <= high else f"out of range; {self.constraint}"
        if match := _VALUES.fullmatch(self.constraint):
            allowed = [v.strip().lower() for v in match[1].split(",")]
            return None if value.lower() in allowed else f"not allowed; {self.constraint}"
        if match := _ARRAY.fullmatch(self.constraint):
            items = [item.strip() for item in value.split(",")]
            if len(items) == int(match[1]) and all(_INTEGER.fullmatch(i) for i in items):
                return None
            return f"needs {match[1]} comma-separated integers; {self.constraint}"
        if match := _STRING.fullmatch(self.constraint):
            if value == "-" or int(match[1]) <= len(value) <= int(match[2]):
                return None
            return f"wrong length; {self.constraint} (or '-' for empty)"
        return f"the FC reported a constraint wftool does not understand: {self.constraint}"

    def canonical(self, value: str) -> str:
        """`value` spelled the way the FC prints it back, for before/after comparisons."""
        if match := _VALUES.fullmatch(self.constraint):
            for allowed in (v.strip() for v in match[1].split(",")):
                if allowed.lower() == value.lower():
                    return allowed
        if self.int_range and _INTEGER.fullmatch(value):
            return str(int(value))
        if _ARRAY.fullmatch(self.constraint):
            return ",".join(item.strip() for item in value.split(","))
        return value


def parse_get(name: str, output: str) -> Setting:
    """Find setting `name` in the output of `get` (which lists every name containing it)."""
    for block in re.split(r"\n\s*\n", output):
        lines = [line.strip() for line in block.strip().splitlines()]
        if not lines or " = " not in lines[0]:
            continue
        found, _, value = lines[0].partition(" = ")
        if found.lower() != name.lower():
            continue
        scope = next((line for line in lines[1:] if _SCOPE.fullmatch(line)), None)
        constraint = next(
            (line for line in lines[1:] if line.split(":")[0] in _CONSTRAINT_HEADS), None
        )
        if constraint is None:
            raise ProtocolError(f"`get {name}` printed no allowed range or values")
        return Setting(found, value, constraint, scope)
    raise CliCommandError(f"get {name}", f"INVALID NAME: {name} (only longer names contain it)")


_CONSTRAINT_HEADS = {"Allowed range", "Allowed values", "Array length", "String length"}


class CliSession:
    """The CLI on an open link. Enter with `enter()`; leave with `save()` or `exit()`."""

    def __init__(self, link: serial.SerialBase, *, timeout: float = 5.0) -> None:
        self.link = link
        self.timeout = timeout
        self.url = link.port or "link"

    @classmethod
    def open(cls, url: str, *, timeout: float = 5.0) -> CliSession:
        """Open `url` and enter the CLI."""
        session = cls(open_port(url, timeout=0.05), timeout=timeout)
        try:
            session.enter()
        except BaseException:
            session.close()
            raise
        return session

    def close(self) -> None:
        self.link.close()

    def enter(self) -> None:
        """Switch the port from MSP to the CLI and wait for the prompt."""
        with port_errors(self.url):
            self.link.reset_input_buffer()
            self.link.write(b"#\r\n")
        self._read_reply("#", self.timeout)

    def run(self, command: str, timeout: float | None = None) -> str:
        """Run one command; return its output (echo and prompt removed, `\\n` line ends).

        Raises `CliCommandError` if the FC printed an `###ERROR …###`.
        """
        if "\n" in command or "\r" in command:
            raise ValueError(f"one command per call: {command!r}")
        with port_errors(self.url):
            self.link.write(command.encode("ascii") + b"\n")
        output = self._read_reply(command, self.timeout if timeout is None else timeout)
        if errors := _ERROR.findall(output):
            details = [
                line for line in output.splitlines() if line.strip() and not _ERROR.search(line)
            ]
            message = "; ".join(text for _, text in errors)
            suffix = f" ({'; '.join(details)})" if details else ""
            raise CliCommandError(command, message + suffix)
        return output

    def _read_reply(self, command: str, timeout: float) -> str:
        text = self._collect(command, timeout)[: -len(PROMPT)].replace("\r\n", "\n")
        echo, _, rest = text.lstrip("\n").partition("\n")
        return (rest if echo.strip() == command else text).strip("\n")

    def _collect(self, command: str, timeout: float, until: bytes | None = None) -> str:
        """Read until `until` arrives or a prompt ends the output and the line goes quiet."""
        received = bytearray()
        deadline = time.monotonic() + timeout
        last_data = time.monotonic()
        with port_errors(self.url):
            while True:
                chunk = self.link.read(max(1, self.link.in_waiting))
                now = time.monotonic()
                if chunk:
                    received += chunk
                    last_data = now
                    if until is not None and until in received:
                        break
                elif received.endswith(PROMPT) and now - last_data >= SETTLE_S:
                    break
                if now > deadline:
                    raise ProtocolError(
                        f"no CLI prompt after `{command}` within {timeout:.0f} s on {self.url}"
                    )
        return received.decode("ascii", "replace")

    def get(self, name: str) -> Setting:
        """The setting `name` with its current value and allowed range/values."""
        return parse_get(name, self.run(f"get {name}"))

    def set(self, name: str, value: str) -> None:
        output = self.run(f"set {name} = {value}")
        if f"{name.lower()} set to" not in output.lower():
            raise CliCommandError(f"set {name} = {value}", f"unexpected reply {output!r}")

    def diff_all(self) -> str:
        """`diff all`: every non-default setting as a replayable CLI script."""
        return self.run("diff all", timeout=max(self.timeout, 15.0))

    def save(self) -> None:
        """Persist the configuration; the FC reboots and the link is closed."""
        self._leave("save")

    def exit(self) -> None:
        """Leave without saving: the FC reboots, discarding every unsaved change."""
        self._leave("exit")

    def exit_noreboot(self) -> None:
        """Hand the port back to MSP without rebooting (unsaved changes stay live in RAM)."""
        with port_errors(self.url):
            self.link.write(b"exit noreboot\n")
        self._collect("exit noreboot", self.timeout, until=b"no reboot")
        # Betaflight's cliProcess() goes on reading the input after `exit`: bytes that arrive
        # before it returns (an MSP request sent at once) are eaten as CLI characters.
        time.sleep(EXIT_SETTLE_S)

    def _leave(self, command: str) -> None:
        """Send a command that ends in a reset; return once the FC is going down.

        If the FC refuses instead (e.g. `save` after errors inside `batch start`), the session
        stays open and `CliCommandError` says why.
        """
        try:
            with port_errors(self.url):
                self.link.write(command.encode("ascii") + b"\n")
            reply = self._collect(command, self.timeout, until=b"Rebooting")
        except PortError:
            reply = "Rebooting"  # the link dropped with the reset before the word arrived
        if "Rebooting" not in reply:
            errors = "; ".join(text for _, text in _ERROR.findall(reply))
            raise CliCommandError(command, f"refused: {errors or reply.strip()}")
        self.close()
