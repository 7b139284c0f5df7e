"""The safe parameter workflow behind `wftool set`, `config apply`, `restore`, `configure fsp`:
back up, validate everything with the FC, apply all or nothing, read back (the steps:
docs/design.md). What to change is a `wftool.fc.plan.Plan`; a script another Betaflight
version wrote is migrated onto the FC's first (`wftool.fc.migrate`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from wftool.errors import CliCommandError, ParameterError, PortError, WftoolError
from wftool.fc.backup import check_backup_dir, write_backup
from wftool.fc.board import Board, leave_open_cli, wait_after_drop
from wftool.fc.cli_session import CliSession, Setting
from wftool.fc.migrate import migrate
from wftool.fc.msp import RECEIVER_FEATURES, FcIdentity, MspClient
from wftool.fc.plan import Command, Plan, Planner
from wftool.fc.versions import BetaflightVersion, version_of
from wftool.link.transport import open_port
from wftool.progress import Log, quiet


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
    migration: list[str] = field(default_factory=list)
    """What migrating a script from another Betaflight version changed (logged as decided)."""

    @property
    def mismatches(self) -> list[str]:
        bad = [f"{row.name} reads back {row.after!r}" for row in self.rows if not row.ok]
        if not self.features_ok:
            bad.append("the feature mask did not persist")
        return bad


@dataclass(frozen=True)
class Connected:
    """An FC in its CLI inside the workflow, with its backup already written."""

    cli: CliSession
    msp: MspClient
    """MSP on the same link (usable after `cli.exit_noreboot()`)."""
    backup: Path
    fc: FcIdentity
    version: BetaflightVersion
    """The FC's Betaflight (`wftool.fc.versions`)."""


@contextlib.contextmanager
def configuration_session(board: Board, backup_dir: Path, log: Log = quiet) -> Iterator[Connected]:
    """Connect, take a backup proven complete, and yield the FC in its CLI.

    An FC running a Betaflight wftool does not know is refused before anything happens
    (`UnsupportedFirmware`). The caller must leave the session (`save`/`exit`) and wait for
    the board. If anything fails while the CLI is still open (here or in the caller's block),
    the FC leaves it with `exit`, which reboots it and drops every unsaved change.
    """
    check_backup_dir(backup_dir)
    leave_open_cli(board, log)
    link = open_port(board.url, timeout=0.05)
    session = CliSession(link)
    try:
        msp = MspClient(link)
        fc, mask = msp.identify(), msp.features()
        version = version_of(fc)
        session.enter()
        backup = write_backup(backup_dir, fc, version, mask, session.diff_all())
        log(f"backup of the current configuration: {backup}")
        yield Connected(session, msp, backup, fc, version)
    except BaseException:
        if session.in_cli:
            leave_without_saving(session, board, log)
        raise
    finally:
        link.close()


def take_backup(board: Board, backup_dir: Path, log: Log = quiet) -> Path:
    """`wftool backup`: the proven-complete backup alone; the FC leaves its CLI (reboots)."""
    with configuration_session(board, backup_dir, log) as connected:
        leave_without_saving(connected.cli, board, log)
    return connected.backup


def apply_plan(
    board: Board, plan: Plan | Planner, backup_dir: Path, log: Log = quiet
) -> ChangeReport:
    """Run the whole safe workflow (its steps: docs/design.md)."""
    with configuration_session(board, backup_dir, log) as connected:
        session, msp, backup, version = (
            connected.cli, connected.msp, connected.backup, connected.version
        )  # fmt: skip
        features_before = None
        nothing_saved = (
            f"— nothing was saved; the FC drops unsaved changes on reboot (backup: {backup})"
        )
        try:
            plan = plan(session, version) if callable(plan) else plan
            migration = migrate(plan, version)
            plan = migration.plan
            for note in migration.changes + plan.notes:
                log(note)
            changes = _validate(session, plan, version)
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
        after, features_after = _read_back(board, plan, version)
    except WftoolError as exc:
        raise _after_save(exc, confirmed, backup) from exc
    rows = [
        ChangeRow(name, scope, before.value, requested, after.get((scope, name), "?"))
        for (scope, name), (before, requested) in changes.items()
    ]
    report = ChangeReport(backup, rows, save_confirmed=confirmed, migration=migration.changes)
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


def _validate(session: CliSession, plan: Plan, version: BetaflightVersion) -> _Changes:
    """Check every command against what the FC (running VERSION) reports; change nothing.

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
        elif verb not in version.config_verbs:
            problems.append(f"{command.where}`{verb}` is not a command of {version.name}")
        elif verb in version.profile_kinds:
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


def _read_back(
    board: Board, plan: Plan, version: BetaflightVersion
) -> tuple[dict[tuple[str | None, str], str], int]:
    """After the save: every changed setting (by scope and name) and the feature mask."""
    link = open_port(board.url, timeout=0.05)
    try:
        features = MspClient(link).features()
        session = CliSession(link)
        session.enter()
        values: dict[tuple[str | None, str], str] = {}
        for command in plan.commands:
            if command.verb in version.profile_kinds:
                session.run(command.text)
            elif command.verb == "set":
                setting = session.get(command.assignment()[0])
                values[(setting.scope, setting.name)] = setting.value
        session.exit()
    finally:
        link.close()
    board.wait_back()
    return values, features
