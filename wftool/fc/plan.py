"""What to change on an FC: CLI commands with where each came from, made from `set`
arguments, a TOML file or a Betaflight CLI script (a `diff all`, a wftool backup); a script's
version line says which Betaflight wrote it (`WrittenBy`), for the migration onto another.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from wftool.errors import UsageError
from wftool.fc.backup import feature_mask_of, firmware_line, split_backup
from wftool.fc.cli_session import CliSession, line_problem
from wftool.fc.msp import RECEIVER_FEATURES
from wftool.fc.versions import VERSIONS, BetaflightVersion, for_release, supported

if sys.version_info >= (3, 11):
    import tomllib
else:
    import tomli as tomllib

HANDLED_BY_WFTOOL = frozenset({"batch", "save"})
"""All-or-nothing and the final save are wftool's job; these script lines are skipped."""


@dataclass(frozen=True)
class Command:
    """One CLI command to send, and where it came from (for error messages)."""

    text: str
    origin: str = ""
    """"file.txt:12", or empty for command-line arguments."""

    def __post_init__(self) -> None:
        """Refuse, before anything is sent, what the FC's CLI would mangle."""
        if problem := line_problem(self.text):
            raise UsageError(f"{self.where}{self.text!r}: {problem} (nothing was changed)")
        if self.verb == "set":
            if "=" not in self.text:
                raise UsageError(f"{self.where}expected `set NAME = VALUE`")
            name, value = self.assignment()
            if not name or not value or value.startswith("="):
                raise UsageError(
                    f"{self.where}`{self.text}`: expected `set NAME = VALUE` with one '=' "
                    "between a name and a value"
                )

    @property
    def where(self) -> str:
        """Prefix for messages about this command."""
        return f"{self.origin}: " if self.origin else ""

    @property
    def verb(self) -> str:
        return self.text.split(maxsplit=1)[0].lower()

    def assignment(self) -> tuple[str, str]:
        """(name, value) of a `set name = value` command, split the way the FC splits it."""
        name, _, value = self.text.split(maxsplit=1)[1].partition("=")
        return name.strip(), value.strip()


@dataclass(frozen=True)
class FeatureChange:
    """Feature bits to switch over MSP, for features the CLI cannot name (RX_MSP)."""

    enable: int
    disable: int

    def applied_to(self, mask: int) -> int:
        return (mask & ~self.disable) | self.enable


@dataclass(frozen=True)
class WrittenBy:
    """The firmware a CLI script's version line names (`# Betaflight / … 2025.12.5 …`)."""

    release: str
    """As the line has it, e.g. "2025.12.5"."""
    version: BetaflightVersion
    origin: str
    """Where the line is, e.g. "backup.txt:4"."""


@dataclass
class Plan:
    """What to change: CLI commands in order, and optionally feature bits via MSP."""

    commands: list[Command]
    features: FeatureChange | None = None
    notes: list[str] = field(default_factory=list)
    """Things the user should know before reading the result (e.g. what gets replaced)."""
    written_by: WrittenBy | None = None
    """The Betaflight that wrote the script, if it says (a `diff all`, a backup): the plan
    is migrated onto the FC's version before it is validated (`wftool.fc.migrate`)."""


Planner = Callable[[CliSession, BetaflightVersion], Plan]
"""Builds a plan from what the FC reports (its CLI session, its Betaflight version), inside
the workflow's CLI session."""


def set_command(name: str, value: str, origin: str = "") -> Command:
    return Command(f"set {name} = {value}", origin)


def plan_from_assignments(assignments: Sequence[str]) -> Plan:
    """`NAME=VALUE` arguments of `wftool set`."""
    commands = []
    for text in assignments:
        name, equals, value = text.partition("=")
        if not equals or not name.strip() or not value.strip() or value.startswith("="):
            raise UsageError(f"expected NAME=VALUE, got {text!r}")
        commands.append(set_command(name.strip(), value.strip()))
    if not commands:
        raise UsageError("nothing to set: give NAME=VALUE arguments")
    return Plan(commands)


def plan_from_file(path: Path) -> Plan:
    """A TOML file of `name = value` pairs, or a Betaflight CLI script (e.g. `diff all`)."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"cannot read {path}: {exc}") from exc
    if path.suffix.lower() == ".toml":
        return _plan_from_toml(text, path.name)
    return parse_cli_script(text, path.name)


def _plan_from_toml(text: str, name: str) -> Plan:
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise UsageError(f"{name}: {exc}") from exc
    commands = []
    for key, value in table.items():
        if isinstance(value, bool):
            value_text = "ON" if value else "OFF"
        elif isinstance(value, (int, str)):
            value_text = str(value)
        elif isinstance(value, list) and all(isinstance(v, int) for v in value):
            value_text = ",".join(str(v) for v in value)
        else:
            raise UsageError(f"{name}: {key}: use an integer, string, boolean or integer list")
        commands.append(set_command(key, value_text, f"{name}: {key}"))
    if not commands:
        raise UsageError(f"{name}: no settings in it")
    return Plan(commands)


def parse_cli_script(text: str, name: str) -> Plan:
    """A Betaflight CLI script: comments and batch/save skipped, unknown commands refused.

    Of a wftool backup only the dump is replayed, never the header above it. A script whose
    version line names a Betaflight wftool does not know is refused; its commands are those
    of the version that wrote it (any known version's, without a version line).
    """
    commands = []
    header, lines = split_backup(text)
    written_by = _written_by(lines, name, len(header))
    versions = [written_by.version] if written_by else VERSIONS
    verbs = frozenset().union(*(version.config_verbs for version in versions))
    for number, raw in enumerate(lines, start=len(header) + 1):
        line = raw.split("#", 1)[0].strip()  # the FC strips comments the same way
        if not line:
            continue
        command = Command(" ".join(line.split()), f"{name}:{number}")
        verb = command.verb
        if verb in HANDLED_BY_WFTOOL:
            continue
        if verb not in verbs:
            raise UsageError(
                f"{command.where}`{verb}` is not a configuration command wftool replays "
                "(nothing was changed)"
            )
        if verb == "defaults" and command.text.lower() != "defaults nosave":
            raise UsageError(
                f"{command.where}only `defaults nosave` is allowed (plain `defaults` saves "
                "and reboots)"
            )
        commands.append(command)
    if not commands:
        raise UsageError(f"{name}: no configuration commands in it")
    mask = feature_mask_of(text)
    features = None
    if mask is not None:
        receiver = mask & RECEIVER_FEATURES
        features = FeatureChange(enable=receiver, disable=RECEIVER_FEATURES & ~receiver)
    return Plan(commands, features, written_by=written_by)


def _written_by(lines: list[str], name: str, offset: int) -> WrittenBy | None:
    """What the dump's version line says wrote it; a version wftool does not know is refused."""
    found = firmware_line(lines)
    if found is None:
        return None
    index, release = found
    origin = f"{name}:{offset + index + 1}"
    version = for_release(release)
    if version is None:
        raise UsageError(
            f"{origin}: written by Betaflight {release}, which wftool does not migrate from "
            f"(it knows {supported()}; nothing was changed)"
        )
    return WrittenBy(release, version, origin)
