"""Running git: one place that turns a failed git command into a readable error."""

from __future__ import annotations

import os
import subprocess
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from wftool.errors import BuildError

# Fixed settings so that git's output does not depend on a user's configuration or language.
_STABLE_CONFIG = ("-c", "advice.detachedHead=false", "-c", "core.quotePath=false")
TEXT_ERRORS = "surrogateescape"
"""How git's bytes become text and back: patches and commits need not be UTF-8 (a Latin-1
comment), and every byte must survive the round trip (`read_text(errors=TEXT_ERRORS)`)."""


def git(
    args: Sequence[str],
    cwd: Path,
    *,
    env: Mapping[str, str] | None = None,
    input: str | None = None,
    check: bool = True,
    error: type[BuildError] = BuildError,
) -> subprocess.CompletedProcess[str]:
    """Run `git ARGS` in CWD and return the finished process (text mode: UTF-8, any other
    byte kept as a surrogate, see TEXT_ERRORS).

    With check=True a non-zero exit raises ERROR carrying git's own last message line.
    """
    full_env = {**os.environ, "LC_ALL": "C", "GIT_TERMINAL_PROMPT": "0", **(env or {})}
    try:
        proc = subprocess.run(
            ["git", *_STABLE_CONFIG, *args],
            cwd=cwd,
            env=full_env,
            input=input,
            capture_output=True,
            encoding="utf-8",
            errors=TEXT_ERRORS,
            check=False,
        )
    except FileNotFoundError as exc:
        raise error("git is not installed (needed to fetch and patch Betaflight)") from exc
    if check and proc.returncode != 0:
        message = last_line(proc.stderr) or last_line(proc.stdout) or f"exit {proc.returncode}"
        raise error(f"git {' '.join(args[:2])} failed in {cwd}: {message}")
    return proc


def git_out(args: Sequence[str], cwd: Path, **kwargs: Any) -> str:
    """Run git and return its stdout without the trailing newline."""
    return git(args, cwd, **kwargs).stdout.rstrip("\n")


def last_line(text: str) -> str:
    """The last non-empty line of TEXT, stripped (git puts its reason there)."""
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[-1] if lines else ""
