"""The staircase's rate-limited progress lines: what a long relaxation prints while it runs."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

from rlpgo_gtsam.relaxation.certificate import Check

__all__ = ["Progress", "Run", "PROGRESS_EVERY_S"]

PROGRESS_EVERY_S = 2.0  # at most one progress line this often inside a trust region


class Progress:
    """Rate-limited progress lines of a staircase (``progress`` None: silent)."""

    def __init__(self, progress: Callable[[str], None] | None, started: float) -> None:
        self.progress = progress
        self.started = started
        self.last = started

    def iteration(self, rank: int, iteration: int, cost: float, gradient: float) -> None:
        self._every(lambda: f"rank {rank}: iteration {iteration}, cost {cost:.9g}, gradient "
                            f"{gradient:.3g}")

    def verifying(self, rank: int, solves: int) -> None:
        self._every(lambda: f"rank {rank}: verifying S, {solves} eigen-solver solves")

    def _every(self, line: Callable[[], str]) -> None:
        """``line()`` and the seconds so far, at most every ``PROGRESS_EVERY_S``."""
        if self.progress is None:
            return
        now = time.perf_counter()
        if now - self.last >= PROGRESS_EVERY_S:
            self.last = now
            self.progress(f"{line()}, {now - self.started:.1f} s")

    def rank(self, rank: int, run: Run, check: Check, note: str = "") -> None:
        if self.progress is not None:
            self.last = now = time.perf_counter()
            self.progress(f"rank {rank}: {run.iterations} iterations, cost {run.cost:.9g}, "
                          f"gradient {run.gradient:.3g}, lambda_min "
                          f"{check.min_eigenvalue:.3g}, {now - self.started:.1f} s"
                          + (f" ({note})" if note else ""))


@dataclass(eq=False)
class Run:
    """What one rank's trust region did (for the progress lines)."""

    iterations: int = 0
    cost: float = math.nan
    gradient: float = math.nan
