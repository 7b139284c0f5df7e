"""How the API reports while it works: through callbacks; only the CLI draws (rich bars).

`Log` gets a line of news ("waiting for another wftool run", a warning). `Progress` gets
(phase, done, total) as work advances; total is None while unknown. dfu-util's reports
have their own shape (`wftool.flash.backend.Progress`: phase, percent, bytes).
"""

from __future__ import annotations

from collections.abc import Callable

Log = Callable[[str], None]
Progress = Callable[[str, int, "int | None"], None]


def quiet(_message: str) -> None:
    """The default `Log`: say nothing."""


def no_progress(_phase: str, _done: int, _total: int | None) -> None:
    """The default `Progress`: show nothing."""
