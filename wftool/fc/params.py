"""The safe parameter workflow behind `wftool set`, `config apply`, `restore`, `configure fsp`:
back up, validate everything with the FC, apply all or nothing, read back (the steps:
docs/design.md).
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from wftool.errors import (
    CliCommandError,
    ParameterError,
    PortError,
    UsageError,
    WftoolError,
)
from wftool.fc.backup import check_backup_dir, feature_mask_of, split_backup, write_backup
from wftool.fc.board import Board, leave_open_cli, wait_after_drop
from wftool.fc.cli_session import CliSession, Setting, line_problem
from wftool.fc.msp import RECEIVER_FEATURES, MspClient
from wftool.link.transport import open_port
from wftool.progress import Log, quiet

if sys.version_info >= (3, 11):
    import tomllib
else:
    import tomli as tomllib

CONTEXT_VERBS = frozenset({"profile", "rateprofile", "battery_profile"})
"""Switch which PID/rate/battery profile the following `set` lines address (battery profiles
since Betaflight 2026.6)."""
CONFIG_VERBS = frozenset(
    {
        "set", "feature", "serial", "map", "aux", "profile", "rateprofile", "defaults",
        "resource", "timer", "dma", "beeper", "beacon", "led", "color", "mode_color",
        "adjrange", "rxrange", "rxfail", "vtxtable", "vtx", "mixer", "mmix", "smix", "servo",
        "board_name", "manufacturer_id", "mcu_id", "signature", "battery_profile", "waypoint",
    }
)  # fmt: skip
"""What a `diff all`/`dump` script contains, minus what wftool does itself (batch, save);
`battery_profile` and `waypoint` since Betaflight 2026.6."""
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


@dataclass
class Plan:
    """What to change: CLI commands in order, and optionally feature bits via MSP."""

    commands: list[Command]
    features: FeatureChange | None = None
    notes: list[str] = field(default_factory=list)
    """Things the user should know before reading the result (e.g. what gets replaced)."""


Planner = Callable[[CliSession], Plan]
"""Builds a plan from what the FC reports, inside the workflow's CLI session."""


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

    Of a wftool backup only the dump is replayed, never the header above it.
    """
    commands = []
    header, lines = split_backup(text)
    for number, raw in enumerate(lines, start=len(header) + 1):
        line = raw.split("#", 1)[0].strip()  # the FC strips comments the same way
        if not line:
            continue
        command = Command(" ".join(line.split()), f"{name}:{number}")
        verb = command.verb
        if verb in HANDLED_BY_WFTOOL:
            continue
        if verb not in CONFIG_VERBS:
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
    return Plan(commands, features)


@dataclass(frozen=True)
class ChangeRow:
    """One setting in the before/after report."""

    name: str
    scope: str | None
    before: str
    requested: str
    after: str

    @property
    def ok(self) -> bool:
        return self.after.lower() == self.requested.lower()


@dataclass
class ChangeReport:
    backup: Path
    rows: list[ChangeRow]
    features: tuple[int, int] | None = None
    """(mask before, mask after) when the plan switched features over MSP."""
    features_ok: bool = True
    save_confirmed: bool = True
    """Whether the FC confirmed `save`; if the link dropped first, only the rows tell."""

    @property
    def mismatches(self) -> list[str]:
        bad = [f"{row.name} reads back {row.after!r}" for row in self.rows if not row.ok]
        if not self.features_ok:
            bad.append("the feature mask did not persist")
        return bad


@contextlib.contextmanager
def configuration_session(
    board: Board, backup_dir: Path, log: Log = quiet
) -> Iterator[tuple[CliSession, MspClient, Path]]:
    """Connect, take a backup proven complete, and yield the CLI session, the MSP client and
    the backup path.

    The caller must leave the session (`save`/`exit`) and wait for the board. If anything
    fails while the CLI is still open (here or in the caller's block), the FC leaves it with
    `exit`, which reboots it and drops every unsaved change.
    """
    check_backup_dir(backup_dir)
    leave_open_cli(board, log)
    link = open_port(board.url, timeout=0.05)
    session = CliSession(link)
    try:
        msp = MspClient(link)
        fc, mask = msp.identify(), msp.features()
        session.enter()
        backup = write_backup(backup_dir, fc, mask, session.diff_all())
        log(f"backup of the current configuration: {backup}")
        yield session, msp, backup
    except BaseException:
        if session.in_cli:
            leave_without_saving(session, board, log)
        raise
    finally:
        link.close()


def take_backup(board: Board, backup_dir: Path, log: Log = quiet) -> Path:
    """`wftool backup`: the proven-complete backup alone; the FC leaves its CLI (reboots)."""
    with configuration_session(board, backup_dir, log) as (session, _msp, backup):
        leave_without_saving(session, board, log)
    return backup


def apply_plan(
    board: Board, plan: Plan | Planner, backup_dir: Path, log: Log = quiet
) -> ChangeReport:
    """Run the whole safe workflow (its steps: docs/design.md)."""
    with configuration_session(board, backup_dir, log) as (session, msp, backup):
        features_before = None
        nothing_saved = (
            f"— nothing was saved; the FC drops unsaved changes on reboot (backup: {backup})"
        )
        try:
            plan = plan(session) if callable(plan) else plan
            for note in plan.notes:
                log(note)
            changes = _validate(session, plan)
            log(f"validated {len(plan.commands)} commands with the FC; applying")
            _apply(session, plan)
            if plan.features is not None:
                session.exit_noreboot()
                features_before = msp.features()
                msp.set_features(plan.features.applied_to(features_before))
                session.enter()
        except ParameterError:
            leave_without_saving(session, board, log)
            raise
        except WftoolError as exc:
            leave_without_saving(session, board, log)
            raise _with_context(exc, nothing_saved) from exc
        except BaseException:
            leave_without_saving(session, board, log)
            log(f"interrupted {nothing_saved}")
            raise
        try:
            confirmed = session.save()
        except CliCommandError as exc:  # the FC refused `save`, so it saved nothing
            leave_without_saving(session, board, log)
            raise _with_context(exc, nothing_saved) from exc
        except BaseException:  # `save` went out: the FC may have saved
            leave_without_saving(session, board, log)
            log(f"interrupted at `save`: whether the FC saved is not confirmed (backup: {backup})")
            raise
    still_in_cli = False
    try:
        if confirmed:
            log("saved; waiting for the FC to reboot")
            board.wait_back()
        else:
            log(
                "the FC did not confirm `save` (the link dropped or it did not answer in "
                "time); looking for the FC"
            )
            still_in_cli = wait_after_drop(board, log)
    except WftoolError as exc:
        raise _after_save(exc, confirmed, backup) from exc
    if still_in_cli:
        raise PortError(f"`save` did not reach the FC (it still sat in its CLI) {nothing_saved}")
    try:
        after, features_after = _read_back(board, plan)
    except WftoolError as exc:
        raise _after_save(exc, confirmed, backup) from exc
    rows = [
        ChangeRow(name, scope, before.value, requested, after.get((scope, name), "?"))
        for (scope, name), (before, requested) in changes.items()
    ]
    report = ChangeReport(backup, rows, save_confirmed=confirmed)
    if plan.features is not None and features_before is not None:
        expected = plan.features.applied_to(features_before)
        report.features = (features_before, features_after)
        report.features_ok = (features_after ^ expected) & RECEIVER_FEATURES == 0
    if not confirmed and not report.mismatches:
        log("saved: the FC did not confirm `save`, but every setting reads back as asked")
    return report


def _after_save(exc: WftoolError, confirmed: bool, backup: Path) -> WftoolError:
    """A failure after `save` went out: it says whether the FC confirmed the save."""
    state = "the FC confirmed `save`" if confirmed else "whether the FC saved is not confirmed"
    return _with_context(exc, f"— {state}, but the settings were not read back (backup: {backup})")


def _with_context(exc: WftoolError, context: str) -> WftoolError:
    """The same kind of error, with `context` appended to its message."""
    if isinstance(exc, CliCommandError):
        return CliCommandError(exc.command, f"{exc.fc_error} {context}")
    return type(exc)(f"{exc} {context}")


def leave_without_saving(session: CliSession, board: Board, log: Log = quiet) -> None:
    """`exit` reboots the FC, which is Betaflight's only way to drop unsaved changes.

    Works from the MSP side of `exit noreboot` too (the CLI is entered again to leave it).
    Problems here are logged, not raised: the caller is already reporting the error that
    made it leave.
    """
    try:
        if not session.in_cli:
            session.enter()
        if session.exit():
            board.wait_back()
        else:
            wait_after_drop(board, log)
    except WftoolError as exc:
        log(f"after leaving the CLI without saving: {exc}")


_Changes = dict[tuple[str | None, str], tuple[Setting, str]]


def _validate(session: CliSession, plan: Plan) -> _Changes:
    """Check every command against what the FC reports; change nothing.

    Profile switches are tried for real (to check them, and to read per-profile values in
    the right profile) and the original selection is restored afterwards.
    """
    problems: list[str] = []
    changes: _Changes = {}
    original_selection: dict[str, str] = {}
    feature_names: dict[str, bool] | None = None
    serial_ports: set[str] | None = None
    for command in plan.commands:
        verb = command.verb
        if verb == "set":
            name, value = command.assignment()
            try:
                setting = session.get(name)
            except CliCommandError as exc:
                problems.append(f"{command.where}{name}: the FC says {exc.fc_error}")
                continue
            problem = setting.problem(value) or _comment_problem(value)
            if problem:
                problems.append(f"{command.where}{name} = {value}: {problem}")
                continue
            key = (setting.scope, setting.name)
            before = changes[key][0] if key in changes else setting
            changes[key] = (before, setting.canonical(value))
        elif verb in CONTEXT_VERBS:
            if verb not in original_selection:
                original_selection[verb] = session.run(verb)
            try:
                session.run(command.text)
            except CliCommandError as exc:
                problems.append(f"{command.where}`{command.text}`: the FC says {exc.fc_error}")
        elif verb == "feature":
            feature_names = feature_names or _features(session)
            name, enable = _feature_request(command)
            if name not in feature_names:
                problems.append(f"{command.where}feature {name}: not in the FC's feature list")
            elif enable and not feature_names[name]:
                problems.append(f"{command.where}feature {name}: unavailable in this firmware")
        elif verb == "serial":
            serial_ports = serial_ports or _serial_ports(session)
            problem = _serial_problem(command.text, serial_ports)
            if problem:
                problems.append(f"{command.where}{problem}")
    for selection in original_selection.values():
        session.run(selection)
    if problems:
        raise ParameterError(f"{len(problems)} invalid, nothing changed: " + "; ".join(problems))
    return changes


def _comment_problem(value: str) -> str | None:
    return "contains '#', which the FC's CLI cuts off as a comment" if "#" in value else None


def _feature_request(command: Command) -> tuple[str, bool]:
    """(NAME, enable?) of `feature NAME` / `feature -NAME`."""
    argument = command.text.split()[-1]
    return argument.lstrip("-").upper(), not argument.startswith("-")


def _features(session: CliSession) -> dict[str, bool]:
    """Feature names the FC lists, mapped to whether this build supports them."""
    names: dict[str, bool] = {}
    for line in session.run("feature").splitlines():
        heading, _, listed = line.partition(":")
        for name in listed.split():
            names[name.upper()] = heading.strip() != "Unavailable"
    return names


def _serial_ports(session: CliSession) -> set[str]:
    """Port identifiers the FC lists in `serial` (UART1, VCP, …)."""
    lines = session.run("serial").splitlines()
    return {fields[1].upper() for line in lines if len(fields := line.split()) > 1}


def _serial_problem(text: str, ports: set[str]) -> str | None:
    fields = text.split()[1:]
    if not fields or fields[0].upper() not in ports:
        port = fields[0] if fields else "(none)"
        return f"serial {port}: no such port on this FC (it has {', '.join(sorted(ports))})"
    if len(fields) != 6 or not all(field.isdigit() for field in fields[1:]):
        return (
            f"`{text}`: expected `serial PORT FUNCTIONS` and four baud rates (MSP, GPS, "
            "telemetry, blackbox)"
        )
    return None


def _apply(session: CliSession, plan: Plan) -> None:
    for command in plan.commands:
        if command.verb == "set":
            session.set(*command.assignment())
            continue
        output = session.run(command.text)
        # Disabling an unavailable feature is a no-op (SITL's own `diff all` does it).
        unavailable = command.verb == "feature" and output.startswith("Unavailable")
        if unavailable and _feature_request(command)[1]:
            raise CliCommandError(command.text, output)


def _read_back(board: Board, plan: Plan) -> tuple[dict[tuple[str | None, str], str], int]:
    """After the save: every changed setting (by scope and name) and the feature mask."""
    link = open_port(board.url, timeout=0.05)
    try:
        features = MspClient(link).features()
        session = CliSession(link)
        session.enter()
        values: dict[tuple[str | None, str], str] = {}
        for command in plan.commands:
            if command.verb in CONTEXT_VERBS:
                session.run(command.text)
            elif command.verb == "set":
                setting = session.get(command.assignment()[0])
                values[(setting.scope, setting.name)] = setting.value
        session.exit()
    finally:
        link.close()
    board.wait_back()
    return values, features
