"""Text from outside wftool (the FC, the user, files, other programs) made safe to show."""

from __future__ import annotations

import re

from rich.text import Text

_UNSAFE = re.compile(r"[\x00-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069\ud800-\udfff]")
"""C0 (ESC starts terminal escape sequences; a newline forges a line), DEL, C1, the
bidirectional overrides that reorder what is shown, and lone surrogates (undecodable
bytes in a file name), which a terminal cannot be given."""


def printable(value: object) -> str:
    """VALUE as text whose every unsafe character is spelled as its escape (`\\x1b`,
    `\\n`, `\\u202e`): it shows what it says and cannot steer the terminal."""
    return _UNSAFE.sub(_spelled, str(value))


def _spelled(match: re.Match[str]) -> str:
    return match[0].encode("unicode_escape", "backslashreplace").decode("ascii")


def shown(value: object, style: str = "") -> Text:
    """VALUE as a rich `Text`: shown as it is, never read as markup or emoji codes."""
    return Text(printable(value), style=style)
