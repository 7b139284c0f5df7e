"""A session with Betaflight's text CLI: enter, run commands, read settings, save or leave
(the CLI's ways this is built on: docs/design.md).

    cli = CliSession.open("socket://127.0.0.1:5761")   # in the CLI once it answers
    print(cli.get("gyro_lpf1_static_hz"))
    cli.exit()   # reboots: unsaved changes are dropped
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass

from wftool.errors import CliCommandError, PortError, ProtocolError
from wftool.fc.versions import VERSIONS
from wftool.link.transport import Port, open_port, port_errors, read_size

PROMPT = b"\r\n# "
SETTLE_S = 0.05
"""Quiet time after a prompt before a reply counts as complete (`# ` also starts comment
lines inside `diff` output)."""
EXIT_SETTLE_S = 0.1
"""After `exit noreboot`: time for the FC to finish its CLI input loop before MSP."""
LINE_MAX = 255
"""The longest command line the CLI keeps whole (`CLI_IN_BUFFER_SIZE` 256, with its NUL)."""
DIFF_TAIL = "\n# save configuration\nsave"
"""The last lines of a complete `diff all`/`dump all`."""
DIFF_END = DIFF_TAIL.replace("\n", "\r\n").encode() + PROMPT
"""The same as it arrives, with the prompt after it."""
DIFF_STALL_S = 1.0
"""How long `diff all` output may pause after a `# ` line before the reply counts as ended
(without its end it is then incomplete)."""
REDRAW = b"\x0c"
"""Ctrl-L: an open CLI redraws its prompt; MSP ignores it."""
ERASE = b"\x7f"
"""DEL: an open CLI erases the last character typed; MSP ignores it."""
PROBE_S = 0.5
"""How long an open CLI may take to answer `REDRAW`."""

_ERROR = re.compile(r"###ERROR IN ([^:]*): (.*?)###")
_INTEGER = re.compile(r"[+-]?\d+")
_RANGE = re.compile(r"Allowed range: (-?\d+) - (-?\d+)")
_VALUES = re.compile(r"Allowed values: (.*)")
_ARRAY = re.compile(r"Array length: (\d+)")
_STRING = re.compile(r"String length: (\d+) - (\d+)")
_SCOPE = re.compile(rf"({'|'.join(sorted({k for v in VERSIONS for k in v.profile_kinds}))}) \d+")
"""`get`'s line saying which profile a per-profile setting was read in, in any version."""


@dataclass(frozen=True)
class Setting:
    """One CLI setting as `get NAME` reports it: value and the FC's own constraint."""

    name: str
    value: str
    constraint: str
    """The FC's line verbatim, e.g. "Allowed range: 0 - 1000" or "Allowed values: OFF, ON"."""
    scope: str | None = None
    """"profile 0"/"rateprofile 0"/"battery_profile 0" for per-profile settings, None for global
    ones."""

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


def line_problem(line: str) -> str | None:
    """Why the CLI cannot take LINE as typed (it would drop or cut characters), or None."""
    if bad := sorted({char for char in line if not " " <= char <= "~"}):
        shown = ", ".join(repr(char) for char in bad)
        return f"the FC's CLI takes printable ASCII only, not {shown}"
    if len(line) > LINE_MAX:
        return f"{len(line)} characters; the FC's CLI keeps at most {LINE_MAX} a line"
    return None


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

    def __init__(self, link: Port, *, timeout: float = 5.0) -> None:
        self.link = link
        self.timeout = timeout
        self.url = link.port or "link"
        self.in_cli = False
        """Whether this session has the FC's CLI open (entered and not yet left)."""

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

    def enter(self) -> None:
        """Switch the port from MSP to the CLI and wait for the prompt."""
        with port_errors(self.url):
            self.link.reset_input_buffer()
            self.link.write(b"#\r\n")
        self._read_reply("#", self.timeout)
        self.in_cli = True

    def run(self, command: str, timeout: float | None = None) -> str:
        """Run one command; return its output (echo and prompt removed, `\\n` line ends).

        Raises `CliCommandError` if the FC printed an `###ERROR …###`.
        """
        self._send(command)
        reply = self._read_reply(command, self.timeout if timeout is None else timeout)
        return self._checked(command, reply)

    def _send(self, command: str) -> None:
        if problem := line_problem(command):
            raise ValueError(f"{command!r}: {problem}")
        with port_errors(self.url):
            self.link.write(command.encode("ascii") + b"\n")

    @staticmethod
    def _checked(command: str, output: str) -> str:
        """OUTPUT, unless the FC printed an error in it."""
        if errors := _ERROR.findall(output):
            details = [
                line for line in output.splitlines() if line.strip() and not _ERROR.search(line)
            ]
            message = "; ".join(text for _, text in errors)
            suffix = f" ({'; '.join(details)})" if details else ""
            raise CliCommandError(command, message + suffix)
        return output

    def _read_reply(
        self, command: str, timeout: float, until: bytes | None = None, settle: float = SETTLE_S
    ) -> str:
        text = self._collect(command, timeout, until, settle)
        text = text.removesuffix(PROMPT.decode()).replace("\r\n", "\n")
        echo, _, rest = text.lstrip("\n").partition("\n")
        return (rest if echo.strip() == command else text).strip("\n")

    def _collect(
        self, command: str, timeout: float, until: bytes | None = None, settle: float = SETTLE_S
    ) -> str:
        """Read until `until` arrives or a prompt ends the output and the line stays quiet
        for `settle` seconds."""
        received = bytearray()
        deadline = time.monotonic() + timeout
        last_data = time.monotonic()
        with port_errors(self.url):
            while True:
                chunk = self.link.read(read_size(self.link))
                now = time.monotonic()
                if chunk:
                    received += chunk
                    last_data = now
                    # Only where `until` can end: the whole reply, searched per chunk, was
                    # quadratic (a 400 KB `diff all` did not arrive within its timeout).
                    tail = len(received) - len(chunk) - (len(until) if until else 0)
                    if until is not None and received.find(until, max(0, tail)) >= 0:
                        break
                elif received.endswith(PROMPT) and now - last_data >= settle:
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
        """`diff all`: every non-default setting as a replayable CLI script.

        The reply is read to its end (`DIFF_END`), through pauses after `# ` lines; one that
        stops short of it is refused, so nothing incomplete passes for a backup.
        """
        command = "diff all"
        self._send(command)
        timeout = max(self.timeout, 15.0)
        output = self._checked(
            command, self._read_reply(command, timeout, until=DIFF_END, settle=DIFF_STALL_S)
        )
        if not output.endswith(DIFF_TAIL):
            last = output.rstrip().rpartition("\n")[2] or "nothing"
            raise ProtocolError(
                f"the FC's `diff all` output on {self.url} stopped after {last!r}, short of "
                "its end (`# save configuration`, `save`): incomplete"
            )
        return output

    def save(self) -> bool:
        """Persist the configuration; the FC reboots and the link is closed.

        True once the FC confirmed (`Rebooting`); False if the link dropped first or the
        confirmation did not come in time, when nobody knows yet whether the FC saved: read
        the settings back to find out.
        """
        return self._leave("save")

    def exit(self) -> bool:
        """Leave without saving: the FC reboots, discarding every unsaved change.

        True once the FC confirmed; False if the link dropped first (see `save`).
        """
        return self._leave("exit")

    def exit_noreboot(self) -> None:
        """Hand the port back to MSP without rebooting (unsaved changes stay live in RAM)."""
        self._send("exit noreboot")
        self._collect("exit noreboot", self.timeout, until=b"no reboot")
        self.in_cli = False
        # Betaflight's cliProcess() goes on reading the input after `exit`: bytes that arrive
        # before it returns (an MSP request sent at once) are eaten as CLI characters.
        time.sleep(EXIT_SETTLE_S)

    def _leave(self, command: str) -> bool:
        """Send a command that ends in a reset; True once the FC says it is going down,
        False if the link dropped or the FC said nothing conclusive in time (the session is
        closed either way): the FC may or may not have got the command.

        If the FC refuses instead (e.g. `save` after errors inside `batch start`), the session
        stays open and `CliCommandError` says why.
        """
        try:
            self._send(command)
            reply = self._collect(command, self.timeout, until=b"Rebooting")
        except (PortError, ProtocolError):  # dropped, or no answer in time: not confirmed
            self.close()
            return False
        if "Rebooting" not in reply:
            errors = "; ".join(text for _, text in _ERROR.findall(reply))
            raise CliCommandError(command, f"refused: {errors or reply.strip()}")
        self.close()
        return True

    def close(self) -> None:
        self.in_cli = False
        self.link.close()


def cli_is_open(link: Port) -> bool:
    """Whether the FC on LINK sits in its CLI (and so ignores MSP): an open CLI answers
    `REDRAW` with its prompt; MSP ignores it. Whatever was half typed is erased."""
    url = link.port or "link"
    with port_errors(url):
        link.reset_input_buffer()
        link.write(REDRAW)
        received = bytearray()
        deadline = time.monotonic() + PROBE_S
        while not received.endswith(PROMPT) and time.monotonic() < deadline:
            received += link.read(read_size(link))
        if not received.endswith(PROMPT):
            return False
        link.write(ERASE * (LINE_MAX + 1))
    return True
