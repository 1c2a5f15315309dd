"""What the robust path reports: one record per step, and the run's result.

Each step is a small frozen dataclass; :meth:`Step.record` gives its JSON-ready form (the
keys ``rlpgo-init --robust --json`` writes), :meth:`RobustResult.record` the whole run's.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import gtsam
import numpy as np

__all__ = ["Step", "AllEdgesStep", "JudgedStep", "ConsistencyStep", "VerifyStep",
           "RobustResult"]


@dataclass(frozen=True, kw_only=True)
class Step:
    """One step of the robust path: its name and wall time."""

    name: str
    seconds: float

    def record(self) -> dict[str, Any]:
        """JSON-ready: ``step`` (the name), ``seconds`` and the step's own fields."""
        return {"step": self.name, "seconds": self.seconds}


@dataclass(frozen=True, kw_only=True)
class AllEdgesStep(Step):
    """The clean default on every edge (the all-edges check).

    Attributes:
        certified: whether the relaxation of every edge was certified (None: skipped).
        worst_edge_chi2: the largest edge chi2 at the refined optimum, judged at the noise
            level the odometry shows (None: not computed, no refined optimum).
        passed: whether every edge fits: the run stops here and rejects nothing.
        noise_scale: per tangent component, the odometry's noise over its stated noise
            (None: not computed).
        skipped: why the step did not run (None: it ran).
    """

    name: str = "all edges"
    certified: bool | None
    worst_edge_chi2: float | None
    passed: bool
    noise_scale: list[float] | None = None
    skipped: str | None = None

    def record(self) -> dict[str, Any]:
        found = super().record() | {"certified": self.certified,
                                    "worst_edge_chi2": self.worst_edge_chi2}
        if self.skipped is not None:
            return found | {"passed": self.passed, "skipped": self.skipped}
        return found | {"noise_scale": self.noise_scale, "passed": self.passed}


@dataclass(frozen=True, kw_only=True)
class JudgedStep(Step):
    """A step that judges the edges (start, gnc; the base of consistency and verify).

    Attributes:
        iterations: the step's solves or rounds (None: not counted).
        judged: edges judged (not trusted).
        kept: judged edges kept after the step.
        rejected: judged edges rejected after the step.
    """

    iterations: int | None
    judged: int
    kept: int
    rejected: int

    @classmethod
    def counted(cls, name: str, seconds: float, iterations: int | None, kept: np.ndarray,
                known: np.ndarray, **more: Any) -> JudgedStep:
        """The step's counts from the ``kept`` and ``known`` (trusted) masks over the edges."""
        judged = ~known
        return cls(name=name, seconds=seconds, iterations=iterations, judged=int(judged.sum()),
                   kept=int((kept & judged).sum()), rejected=int((~kept & judged).sum()),
                   **more)

    def record(self) -> dict[str, Any]:
        return super().record() | {"iterations": self.iterations, "judged": self.judged,
                                   "kept": self.kept, "rejected": self.rejected}


@dataclass(frozen=True, kw_only=True)
class ConsistencyStep(JudgedStep):
    """The pairwise consistency step: ``pairs`` of closures tested, ``conflicts`` among them,
    ``ambiguous`` groups of conflicts that could have gone either way."""

    pairs: int
    conflicts: int
    ambiguous: int

    def record(self) -> dict[str, Any]:
        return super().record() | {"pairs": self.pairs, "conflicts": self.conflicts,
                                   "ambiguous": self.ambiguous}


@dataclass(frozen=True, kw_only=True)
class VerifyStep(JudgedStep):
    """The verify step (``iterations``: its rounds): ``restarts`` from the kept edges'
    relaxation, and ``unlikely_fits``, the closures the false-rejection bar rejected."""

    restarts: int
    unlikely_fits: int

    def record(self) -> dict[str, Any]:
        return super().record() | {"restarts": self.restarts,
                                   "unlikely_fits": self.unlikely_fits}


@dataclass
class RobustResult:
    """What :func:`~rlpgo_gtsam.robust.robust_initialize` found.

    Attributes:
        values: the guess GTSAM's GNC-LM hands over (refined on the edges it kept).
        rejected: factor indices (into the caller's graph) of the loop closures judged wrong,
            ascending.
        weights: (graph.size(),) the final weight of every factor: GNC-LM's for the edges it
            judged, 0 for edges the earlier steps rejected, 1 for trusted edges and priors,
            NaN for empty factor slots.
        chi2: g2o chi2 of ``values`` on the graph without the rejected factors.
        seconds: wall time of the whole call, extraction included.
        steps: what each step did, in order.
        trusted: factor indices of the edges treated as known inliers.
        ambiguous: what the consistency step and the verify step's exchange could not tell
            apart: per group of conflicting closures, the factor indices kept there and those
            of a rejected alternative that is (nearly) as well supported and consistent in
            itself (the consistency step's: the later steps decided by the map's fit; the
            exchange's: each set fits the map without the other, the larger was kept, of two
            as large the one whose map has the lower chi2); empty when nothing was ambiguous.
        stopped: why the run ended where it did, in words.
        doubtful: ``(factor index, p-value)`` of the loop closures kept whose fit at the
            verified map is poor (the verify step's statistic, p-value below
            ``RobustSettings.doubtful_below``), smallest first. The evidence did not reject
            them and cannot tell them from wrong ones: a list to check by hand. Empty where
            the run stopped at "all edges" (every edge fits).
    """

    values: gtsam.Values
    rejected: list[int]
    weights: np.ndarray
    chi2: float
    seconds: float
    steps: list[Step] = field(default_factory=list)
    trusted: list[int] = field(default_factory=list)
    ambiguous: list[tuple[list[int], list[int]]] = field(default_factory=list)
    stopped: str = ""
    doubtful: list[tuple[int, float]] = field(default_factory=list)

    def record(self) -> dict[str, Any]:
        """JSON-ready summary: rejected indices, chi2, seconds, steps."""
        return {"rejected": self.rejected, "chi2": self.chi2, "seconds": self.seconds,
                "steps": [step.record() for step in self.steps], "trusted": len(self.trusted),
                "ambiguous": self.ambiguous, "stopped": self.stopped,
                "doubtful": [list(pair) for pair in self.doubtful]}
