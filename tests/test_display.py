"""What the FC or the user supplies is shown as text: no markup, no terminal control."""

from __future__ import annotations

import io

from rich.console import Console

from wftool.display import printable, shown


def test_control_characters_are_spelled_not_sent() -> None:
    hostile = "Q\x1b[2J\x1b]8;;http://x\x1b\\link\nset x\r\x07\x7f\x9b\u202eevil\udcff"
    assert printable(hostile) == (
        "Q\\x1b[2J\\x1b]8;;http://x\\x1b\\link\\nset x\\r\\x07\\x7f\\x9b\\u202eevil\\udcff"
    )
    assert printable("Quad [v2] µ ✓ 🚁") == "Quad [v2] µ ✓ 🚁"


def test_shown_text_is_never_markup_or_emoji() -> None:
    console = Console(record=True, width=200, color_system="truecolor", file=io.StringIO())
    for text in ("Rick[/x]", "[/]", "Quad[v2]", "[bold red]x", ":fire:", "Q\x1b[2J"):
        console.print(shown(text))
    lines = console.export_text(styles=False).splitlines()
    assert lines == ["Rick[/x]", "[/]", "Quad[v2]", "[bold red]x", ":fire:", "Q\\x1b[2J"]
