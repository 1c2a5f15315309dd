"""Option types shared by the commands: finite, bounded numbers, checked at parse time."""

from __future__ import annotations

import math
import os
from pathlib import Path

import click

# Bounds of the integer options: large enough for any real use, small enough that no
# value reaches an overflow or an allocation that cannot succeed.
SEED = click.IntRange(0, 2**32 - 1)
ITERATIONS = click.IntRange(0, 100_000)
COUNT = click.IntRange(1, 1_000_000)
# Batched agent rollouts: each holds a copy of the graph's orientation state.
ROLLOUTS = click.IntRange(1, 100)


class FiniteFloat(click.ParamType):
    """A float within [minimum, maximum] (``minimum`` excluded if ``min_open``, ``maximum``
    if ``max_open``), never nan or inf; the range shows in ``--help``."""

    name = "float"

    def __init__(self, minimum: float, maximum: float, min_open: bool = False,
                 max_open: bool = False) -> None:
        self.minimum, self.maximum = minimum, maximum
        self.min_open, self.max_open = min_open, max_open

    def _range(self) -> str:
        low, high = "(" if self.min_open else "[", ")" if self.max_open else "]"
        return f"{low}{self.minimum:g}, {self.maximum:g}{high}"

    def get_metavar(self, param: click.Parameter, ctx: click.Context | None = None) -> str:
        return f"FLOAT {self._range()}"

    def convert(self, value, param, ctx) -> float:
        try:
            number = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not a number", param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        below = number <= self.minimum if self.min_open else number < self.minimum
        above = number >= self.maximum if self.max_open else number > self.maximum
        if below or above:
            self.fail(f"{number:g} is not in {self._range()}", param, ctx)
        return number


class OutputFile(click.ParamType):
    """A file to write, as a :class:`pathlib.Path`; a name ending in "/" (which names a
    folder, and which ``pathlib`` would silently drop) is refused."""

    name = "path"

    def convert(self, value, param, ctx) -> Path:
        if isinstance(value, Path):
            return value
        text = str(value)
        if not text or text.endswith(("/", os.sep)):
            self.fail(f"{text!r} names a folder; give a file name", param, ctx)
        return Path(text)
