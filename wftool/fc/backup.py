"""Configuration backups: a `diff all` plus what the CLI cannot express, in a timestamped file.

Betaflight 2025.12 dropped RX_MSP from the CLI's feature names (PR #13494; 2026.6 names it
again), so a `diff all` of a board whose receiver is MSP does not say so. The backup
therefore records the MSP feature mask in a header comment, which the FC ignores and
`wftool restore` reads back.

A backup is only written once it is proven complete (`diff_problems`): it must have the
shape of a whole `diff all` (`cli.c` printConfig, with the sections of the FC's version)
from its version line to its final `save`, and the version line must describe the firmware
the FC reports over MSP.
"""

from __future__ import annotations

import contextlib
import re
import tempfile
from datetime import datetime, timezone
from pathlib import Path

from wftool.display import printable
from wftool.errors import ProtocolError, UsageError, WftoolError
from wftool.fc.cli_session import line_problem
from wftool.fc.msp import BoardInfo, FcIdentity
from wftool.fc.versions import BetaflightVersion

DEFAULT_BACKUP_DIR = Path("backups")
_HEADER_START = "# wftool backup of "
"""The first line of a backup file; the header runs up to the dump's `# version` line."""
_FEATURE_MASK = re.compile(r"# wftool: feature mask (0x[0-9a-fA-F]+) .*")
_VERSION = re.compile(
    r"# (?P<firmware>.+) / (?P<target>\S+) \((?P<identifier>[^)]*)\) (?P<version>\S+) "
    r"(?P<date>.+) / (?P<time>\S+) \((?P<revision>\w+)\) MSP API: (?P<api>\S+)"
)
"""`printVersion`: "# Betaflight / SITL (SITL) 2025.12.5 Nov 23 2026 / 01:44:50 (2efac68db)
MSP API: 1.47"."""
_SELECTION = re.compile(r"(\w+) (\d+)")


def check_backup_dir(directory: Path) -> None:
    """Make sure backups can be written to DIRECTORY, before anything touches the FC."""
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=directory, prefix=".wftool-write-test-"):
            pass
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise UsageError(
            f"cannot write backups to {directory}: {reason} (choose another --backup-dir; "
            "the FC was not touched)"
        ) from exc


def firmware_line(lines: list[str]) -> tuple[int, str] | None:
    """(index, Betaflight version) of a dump's version line (`# version`, then `printVersion`'s
    line), among the comments it starts with; None when it has none."""
    for index, line in enumerate(lines[:-1]):
        if line.strip() and not line.startswith("#"):
            break
        if line.strip() == "# version" and (version := _VERSION.fullmatch(lines[index + 1])):
            return index + 1, version["version"]
    return None


def _shape(version: BetaflightVersion) -> tuple[str, ...]:
    """Lines every `diff all` has, in this order (`printConfig` with DUMP_ALL | DO_DIFF)."""
    selections = tuple(f"# restore original {kind} selection" for kind in version.profile_kinds)
    return ("batch start", "defaults nosave", *selections, "# save configuration")


def diff_problems(diff: str, fc: FcIdentity, version: BetaflightVersion) -> list[str]:
    """Why DIFF is not a complete `diff all` of the FC that MSP describes as FC, running
    VERSION (empty: ok)."""
    lines = diff.splitlines()
    if lines[:1] != ["# version"] or len(lines) < 2:
        return ["it does not start with `# version` and the firmware's version line"]
    problems = []
    printed = _VERSION.fullmatch(lines[1])
    if printed is None:
        problems.append(f"its version line is not Betaflight's: {lines[1]!r}")
    else:
        reported = {
            "target": fc.board.target_name,
            "identifier": fc.board.board_identifier,
            "version": fc.version,
            "date": fc.build.date,
            "time": fc.build.time,
            "api": str(fc.api),
        }
        differ = [name for name, value in reported.items() if printed[name] != value]
        if not printed["revision"].startswith(fc.build.git_revision):
            differ.append("revision")
        if differ:
            problems.append(
                f"its version line ({', '.join(differ)}) is not what the FC reports over MSP"
            )
    position = 0
    for expected in _shape(version):
        try:
            position = lines.index(expected, position) + 1
        except ValueError:
            problems.append(f"`{expected}` is missing or out of place")
    for kind in version.profile_kinds:
        selections = (_SELECTION.fullmatch(line) for line in lines)
        numbers = [int(m[2]) for m in selections if m and m[1] == kind]
        listed = numbers[:-1]  # each profile in turn, then the one to select again
        if not listed or listed != list(range(len(listed))):
            problems.append(f"the {kind}s it lists are not 0, 1, … in turn: {numbers}")
    if lines[-2:] != ["# save configuration", "save"]:
        problems.append(f"it ends with {lines[-1]!r}, not `save`")
    return problems


def write_backup(
    directory: Path, fc: FcIdentity, version: BetaflightVersion, feature_mask: int, diff: str
) -> Path:
    """Write a backup file named after the board and the UTC time; return its path.

    Refuses (`ProtocolError`, nothing written) a DIFF that is not proven complete.
    """
    if problems := diff_problems(diff, fc, version):
        raise ProtocolError(
            f"the FC's `diff all` is incomplete, so no backup was written: {'; '.join(problems)}"
        )
    board = fc.board
    diff = _names_as_comments(diff, board)
    now = datetime.now(timezone.utc)
    label = re.sub(r"[^A-Za-z0-9_.-]", "_", board.board_name or board.target_name or "fc")
    path = directory / f"{label}-{now:%Y%m%d-%H%M%S-%f}.txt"
    header = (  # the FC's strings may hold anything, line breaks too: one line each, escaped
        f"{_HEADER_START}{printable(board.board_name or '-')} ({printable(board.target_name)}) "
        f"at {now:%Y-%m-%dT%H:%M:%SZ}\n"
        f"# wftool: feature mask 0x{feature_mask:08x} (from MSP; the CLI cannot name RX_MSP)\n"
    )
    partial = path.with_name(f".{path.name}.part")
    try:
        directory.mkdir(parents=True, exist_ok=True)
        partial.write_text(header + diff.rstrip("\n") + "\n")
        partial.rename(path)  # a backup file is whole or absent
    except OSError as exc:
        with contextlib.suppress(OSError):
            partial.unlink(missing_ok=True)
        raise WftoolError(f"cannot write the backup {path}: {exc.strerror or exc}") from exc
    return path


def _names_as_comments(diff: str, board: BoardInfo) -> str:
    """DIFF with its `board_name`/`manufacturer_id` line made a comment where the name holds
    what the CLI cannot carry. Betaflight takes any bytes as these names (MSP_SET_BOARD_INFO)
    and prints them as they are (`printBoardName`): a line break in one would put lines of
    the name's choosing among the settings a restore replays."""
    for command, value in (
        ("board_name", board.board_name),
        ("manufacturer_id", board.manufacturer_id),
    ):
        if not value or line_problem(value) is None:
            continue
        printed = f"\n{command} {value}\n".replace("\r\n", "\n")
        if printed not in diff:
            raise ProtocolError(
                f"the FC's {command} {printable(value)!r} holds characters its CLI cannot "
                "carry, and its `diff all` does not show it as the FC reports it: no backup "
                "was written"
            )
        comment = f"# {command} {printable(value)} (not replayed: the CLI takes printable ASCII)"
        diff = diff.replace(printed, f"\n{comment}\n", 1)
    return diff


def split_backup(script: str) -> tuple[list[str], list[str]]:
    """(header lines, dump lines) of a wftool backup: the header is what comes before the
    dump's `# version` line. Other scripts have no header."""
    lines = script.splitlines()
    if not lines or not lines[0].startswith(_HEADER_START):
        return [], lines
    end = next((i for i, line in enumerate(lines) if line.strip() == "# version"), len(lines))
    return lines[:end], lines[end:]


def feature_mask_of(script: str) -> int | None:
    """The MSP feature mask a backup's header recorded, or None for other scripts."""
    header, _ = split_backup(script)
    for line in header:
        if match := _FEATURE_MASK.fullmatch(line):
            return int(match[1], 16)
    return None
