"""Markdown tables, as the reports write them (`timing`, `report`, `accfilter`)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence


def table(header: Sequence[str], rows: Iterable[Sequence[str]], align: str = "") -> list[str]:
    """The lines of a Markdown table: `header`, then `rows` of cells; `align` gives each
    column's alignment, "l" or "r" (figures), in order (the rest: "l")."""
    if any(side not in "lr" for side in align) or len(align) > len(header):
        raise ValueError(f"align {align!r}: one 'l' or 'r' per column of {len(header)} at most")
    sides = align.ljust(len(header), "l")
    return [
        "| " + " | ".join(header) + " |",
        "|" + "|".join("---:" if side == "r" else "---" for side in sides) + "|",
        *("| " + " | ".join(row) + " |" for row in rows),
    ]
