"""Locating the wftool project: the checkout that holds .gitmodules, patches/ and targets/.

Every build path (the Betaflight tree, the series, board configs, outputs) hangs off this
root, so commands work from any subdirectory, from --project DIR or from $WFTOOL_PROJECT.
"""

from __future__ import annotations

import fcntl
import os
import re
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from wftool.errors import UsageError

PROJECT_ENV = "WFTOOL_PROJECT"
SUBMODULE_PATH = "betaflight"

_SUBMODULE_PATH_LINE = re.compile(rf"^\s*path\s*=\s*{SUBMODULE_PATH}\s*$", re.MULTILINE)


@dataclass(frozen=True)
class Project:
    """The paths of one wftool project checkout."""

    root: Path

    @property
    def tree(self) -> Path:
        """The Betaflight submodule's work tree."""
        return self.root / SUBMODULE_PATH

    @property
    def patches_dir(self) -> Path:
        """The patch series, `NNNN-*.patch` files made by git format-patch."""
        return self.root / "patches"

    @property
    def config_dir(self) -> Path:
        """Betaflight's CONFIG_DIR: board definitions in `configs/<BOARD>/config.h`."""
        return self.root / "targets"

    @property
    def build_dir(self) -> Path:
        """Outputs: `build/<target>/` per target, object files under `build/.obj/`."""
        return self.root / "build"


def is_project(path: Path) -> bool:
    """Whether PATH is a wftool project root (its .gitmodules declares betaflight/)."""
    gitmodules = path / ".gitmodules"
    return gitmodules.is_file() and bool(_SUBMODULE_PATH_LINE.search(gitmodules.read_text()))


def find_project(explicit: Path | None = None, cwd: Path | None = None) -> Project:
    """The project named by EXPLICIT, else $WFTOOL_PROJECT, else the first one above CWD."""
    named = explicit or (Path(os.environ[PROJECT_ENV]) if os.environ.get(PROJECT_ENV) else None)
    if named is not None:
        root = named.expanduser().resolve()
        if not is_project(root):
            raise UsageError(f"{named} is not a wftool project (no betaflight submodule there)")
        return Project(root)
    start = (cwd or Path.cwd()).resolve()
    for candidate in (start, *start.parents):
        if is_project(candidate):
            return Project(candidate)
    raise UsageError(
        f"no wftool project at or above {start}; run inside a wftool checkout or pass --project"
    )


@contextmanager
def exclusive(project: Project, on_wait: Callable[[], None] | None = None) -> Iterator[None]:
    """Hold the checkout's lock: two wftool runs must not patch or build one tree at once.

    ON_WAIT is called once if another run holds the lock (then this one waits for it).
    """
    project.build_dir.mkdir(parents=True, exist_ok=True)
    with (project.build_dir / ".lock").open("w") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if on_wait is not None:
                on_wait()
            fcntl.flock(lock, fcntl.LOCK_EX)
        yield
