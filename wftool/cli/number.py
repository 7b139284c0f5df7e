"""`Number`: the type of every option that takes a real number. It takes a finite number in
its range or nothing: NaN, ±inf, words and values out of range are one-line usage errors
when the options are parsed, before anything runs."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import click

from wftool.errors import UsageError
from wftool.verify.live import check_duration


class Number(click.FloatRange):
    """A finite float from `min` to `max` (either end open, or left out), in `unit` (for
    the message). `check(value, name)`: the API's own check of the value, which raises
    `UsageError` in the API's words (and runs first: its message is the one said)."""

    def __init__(
        self,
        min: float | None = None,
        max: float | None = None,
        *,
        min_open: bool = False,
        max_open: bool = False,
        unit: str = "",
        check: Callable[[float, str], object] | None = None,
    ) -> None:
        super().__init__(min, max, min_open=min_open, max_open=max_open)
        self.unit = unit
        self.check = check

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        name = param.opts[0] if param is not None and param.opts else "the value"
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise UsageError(f"{name} must be {self.describe()}, not {value!r}") from None
        if self.check is not None:
            self.check(number, name)
        if not (math.isfinite(number) and self.admits(number)):
            raise UsageError(f"{name} must be {self.describe()}, not {number:g}")
        return number

    def admits(self, number: float) -> bool:
        """Whether `number` (finite) is in the range."""
        low, high = self.min, self.max
        if low is not None and (number <= low if self.min_open else number < low):
            return False
        return not (high is not None and (number >= high if self.max_open else number > high))

    def describe(self) -> str:
        """The range in words: "a number from 0 to 150 ms", "above 0 s", ..."""
        unit = f" {self.unit}" if self.unit else ""
        low, high = self.min, self.max
        if low is not None and high is not None and not (self.min_open or self.max_open):
            return f"a number from {low:g} to {high:g}{unit}"
        bounds = []
        if low is not None:
            bounds.append(f"above {low:g}" if self.min_open else f"at least {low:g}")
        if high is not None:
            bounds.append(f"below {high:g}" if self.max_open else f"at most {high:g}")
        if not bounds:
            return f"a finite number ({self.unit})" if self.unit else "a finite number"
        return f"{' and '.join(bounds)}{unit}"


SECONDS = Number(0, min_open=True, unit="s", check=check_duration)
"""How long a run lasts (verify, sitl --verify, ros2, record msp)."""
