"""A CLI script written by one Betaflight version, replayed on another: each rule rewrites or
drops lines and says so, or refuses the line it cannot carry — never a silent partial restore.

The rules (what differs comes from the two versions' profiles, `wftool.fc.versions`):

- only onto the same or a newer version: a newer script on an older FC is refused;
- a command the FC's version does not have is refused, naming the line;
- `serial` lines keep each port's functions by name: a function bit the FC's version numbers
  otherwise is renumbered (FSP: 1 << 19 on 2025.12, 1 << 30 on 2026.6); a function it does
  not have is refused, naming the line;
- a `set` of a setting a version since the script's removed (a reason is on record) is
  dropped;
- a setting that is per battery profile on the FC's version but was global where the script
  was written is set where the FC puts a plain `set`: the selected battery profile (the
  first, after `defaults nosave`).

Everything else goes to the FC's own validation as it is, which names each line it refuses.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from wftool.errors import ParameterError
from wftool.fc.plan import Command, Plan, WrittenBy
from wftool.fc.versions import VERSIONS, BetaflightVersion


@dataclass(frozen=True)
class Migration:
    """A plan rewritten for the FC's version, and what was changed, one line each."""

    plan: Plan
    changes: list[str]


def migrate(plan: Plan, target: BetaflightVersion) -> Migration:
    """PLAN (written by `plan.written_by`, if it says) made fit for an FC running TARGET.

    Raises `ParameterError` listing every line that cannot be carried over (nothing was
    changed on the FC yet).
    """
    source = plan.written_by
    if source is None or source.version == target:
        return Migration(plan, [])
    if source.version.series > target.series:
        raise ParameterError(
            f"{source.origin}: written by Betaflight {source.release}, and the FC runs "
            f"{target.name}: wftool carries backups to newer Betaflight only (nothing was "
            "changed)"
        )
    changes = [
        f"{source.origin}: written by Betaflight {source.release}; migrated onto {target.name}:"
    ]
    removed = {  # by every version after the source, up to the FC's
        name: f"{version.name} removed it — {why}"
        for version in VERSIONS
        if source.version.series < version.series <= target.series
        for name, why in version.removed_settings.items()
    }
    problems: list[str] = []
    commands: list[Command] = []
    per_battery: list[Command] = []
    for command in plan.commands:
        if command.verb not in target.config_verbs:
            problems.append(f"{command.where}`{command.verb}` is not a command of {target.name}")
        elif command.verb == "serial":
            migrated = _serial(command, source, target, problems)
            if migrated.text != command.text:
                reason = _serial_reason(command, source, target)
                changes.append(f"  {command.where}`{command.text}` → `{migrated.text}`{reason}")
            commands.append(migrated)
            continue
        elif command.verb == "set":
            name = command.assignment()[0].lower()
            if name in removed:
                changes.append(f"  {command.where}`{command.text}` dropped: {removed[name]}")
                continue
            if (
                name in target.battery_profile_settings
                and name not in source.version.battery_profile_settings
            ):
                per_battery.append(command)
        commands.append(command)
    if problems:
        raise ParameterError(
            f"{len(problems)} line(s) {target.name} cannot take, nothing changed: "
            + "; ".join(problems)
        )
    if per_battery:
        names = ", ".join(c.assignment()[0] for c in per_battery)
        where = ", ".join(c.origin for c in per_battery if c.origin)
        changes.append(
            f"  {where}: {names}: per battery profile on {target.name}, set for the selected "
            "battery profile (the first, after `defaults nosave`)"
        )
    if len(changes) == 1:
        changes[0] = changes[0].removesuffix(":") + " (nothing to change)"
    return Migration(replace(plan, commands=commands), changes)


def _serial(
    command: Command, source: WrittenBy, target: BetaflightVersion, problems: list[str]
) -> Command:
    """`serial PORT FUNCTIONS bauds…` with the functions renumbered by name."""
    fields = command.text.split()
    if len(fields) < 3 or not fields[2].isdigit():
        return command  # not a line to renumber: the FC's validation names it
    names = {bit: name for name, bit in source.version.serial_functions.items()}
    mask = int(fields[2])
    renumbered = 0
    for bit in range(32):
        if not mask >> bit & 1:
            continue
        name = names.get(1 << bit)
        if name is None or name not in target.serial_functions:
            what = f"function {name}" if name else f"function bit {bit}"
            problems.append(f"{command.where}`{command.text}`: {target.name} has no serial {what}")
            continue
        renumbered |= target.serial_functions[name]
    return replace(command, text=" ".join([*fields[:2], str(renumbered), *fields[3:]]))


def _serial_reason(command: Command, source: WrittenBy, target: BetaflightVersion) -> str:
    """ " (FSP is 1 << 30 on Betaflight 2026.6)" for each function renumbered."""
    mask = int(command.text.split()[2])
    moved = [
        f"{name} is 1 << {target.serial_functions[name].bit_length() - 1}"
        for name, bit in source.version.serial_functions.items()
        if mask & bit and target.serial_functions.get(name, bit) != bit
    ]
    return f" ({', '.join(moved)} on {target.name})" if moved else ""
