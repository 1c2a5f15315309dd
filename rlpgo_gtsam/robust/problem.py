"""The problem the robust steps share: the graph they judge, its extraction, and the optimum
of the edges they keep.

The steps decide with masks over the extraction's edges (``kept``, ``known``); a
:class:`Problem` turns such a mask into GTSAM's graph of the kept edges and solves it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import gtsam
import numpy as np

from rlpgo_gtsam.errors import GraphError, SolverError
from rlpgo_gtsam.graph import PoseGraph, chi2, component_labels, odometry_edges
from rlpgo_gtsam.groups import Group, group_of
from rlpgo_gtsam.initializers import Initializer, make_initializer
from rlpgo_gtsam.robust.settings import RobustSettings
from rlpgo_gtsam.solvers import RefineResult, refine, solver_params

__all__ = ["Problem", "edge_factor_indices", "without_factors", "relaxation",
           "relaxation_rotations"]

@dataclass(frozen=True)
class Problem:
    """The judged graph, read once.

    Attributes:
        graph: the graph the steps judge (the caller's, or its covariances scaled or read by
            their printed blocks: :mod:`rlpgo_gtsam.robust.noise`).
        g: its extraction.
        factor_of_edge: (m,) the factor index of each edge.
        settings: the run's settings.
    """

    graph: gtsam.NonlinearFactorGraph
    g: PoseGraph
    factor_of_edge: np.ndarray
    settings: RobustSettings

    @property
    def group(self) -> Group:
        return group_of(self.g)

    @cached_property
    def edges(self) -> gtsam.NonlinearFactorGraph:
        """The between factors alone, in edge order (what the verify step linearizes)."""
        edges = gtsam.NonlinearFactorGraph()
        for k in self.factor_of_edge.tolist():
            edges.add(self.graph.at(k))
        return edges

    @cached_property
    def noise(self) -> np.ndarray:
        """(m, dof, samples) whitened noise drawn on the edges, seeded: the verify step's
        covariance estimates use the same draws in every round (drawn once, not per round:
        MIT's 827 edges took 4 ms a round of about 30)."""
        rng = np.random.default_rng(self.settings.draw_seed)
        return rng.standard_normal((self.g.num_edges, self.group.dof, self.settings.samples))

    @cached_property
    def information_factor(self) -> np.ndarray:
        """(m, dof, dof) each edge's upper information factor, ``R^T R = information``: read
        by every round of the verify step, factored once."""
        return np.linalg.cholesky(self.g.information).transpose(0, 2, 1)

    @cached_property
    def chain(self) -> np.ndarray:
        """(m,) the odometry chain (:func:`~rlpgo_gtsam.graph.odometry_edges`): it spans the
        graph."""
        return odometry_edges(self.g)

    def unplaced(self, kept: np.ndarray) -> np.ndarray:
        """Indices of the poses the ``kept`` edges do not estimate: the held ones, and those
        they join to no held pose (where untrusted odometry on both sides of a pose was
        rejected; held where the map left them)."""
        held = self.g.held[0]
        if (kept | ~self.chain).all():  # the chain is kept: every pose is joined
            return held
        labels = component_labels(self.g.num_poses, self.g.edges[kept])
        return np.union1d(held, np.flatnonzero(~np.isin(labels, labels[held])))

    def spanning(self, kept: np.ndarray, back: np.ndarray, order: np.ndarray) -> np.ndarray:
        """``kept``, with the fewest edges of ``back`` (tried in ``order``, edge indices best
        first) that join every pose to a held one again: no map places a pose without an
        edge, so the last that could place it stays, whatever the evidence against it
        (untrusted odometry around a FIXed pose). ``kept`` itself where every pose is
        joined."""
        if (kept | ~self.chain).all():
            return kept
        n = self.g.num_poses
        labels = component_labels(n, self.g.edges[kept])
        parent = list(range(n))
        placed = np.zeros(n, bool)
        placed[labels[self.g.held[0]]] = True
        loose = len(set(labels[~placed[labels]].tolist()))
        if loose == 0:
            return kept

        def root(a: int) -> int:
            while parent[a] != a:
                parent[a] = parent[parent[a]]
                a = parent[a]
            return a

        grown = kept.copy()
        for e in np.asarray(order)[back[order]].tolist():
            a, b = root(int(labels[self.g.edges[e, 0]])), root(int(labels[self.g.edges[e, 1]]))
            if a == b or (placed[a] and placed[b]):
                continue
            loose -= 1  # a loose piece joins another piece
            parent[a] = b
            placed[b] = placed[a] or placed[b]
            grown[e] = True
            if loose == 0:
                break
        return grown

    def holding(self, values: gtsam.Values) -> gtsam.Values:
        """``values`` with every held pose (the anchor, each FIXed pose) exactly where the
        graph holds it. GTSAM's solvers hold a constrained prior to its linearization's
        precision and GNC-LM by a tight prior: this makes the handed-over map keep them to
        the last digit. Unchanged (the same object) where the graph fixes no pose."""
        if len(self.g.fixed) == 0:
            return values
        held, poses = self.g.held
        exact = gtsam.Values(values)
        group = self.group
        for index, pose in zip(held.tolist(), poses, strict=True):
            exact.update(int(self.g.keys[index]), group.gtsam_pose(pose))
        return exact

    def kept_graph(self, kept: np.ndarray) -> gtsam.NonlinearFactorGraph:
        """The judged graph without the edges not ``kept`` (their slots left empty)."""
        return without_factors(self.graph, self.factor_of_edge[~kept].tolist())

    def kept_chi2(self, kept: np.ndarray, values: gtsam.Values) -> float:
        """The chi2 of ``values`` on the ``kept`` edges (and every other factor)."""
        return chi2(self.kept_graph(kept), values)

    def optimum(self, kept: np.ndarray, values: gtsam.Values, iterations: int,
                tolerance: float) -> RefineResult:
        """GTSAM's Gauss-Newton on the ``kept`` edges from ``values`` (g2o's loop: on through
        an increase), or LM where that does not lower the chi2; either stops after
        ``iterations`` or at a change of the error below ``tolerance`` (relative or absolute).
        From the maps the verify step hands it (a few closures away from their optimum) GN
        converges in a handful of steps where LM's damping takes 15-20 (Intel: 4 against 20);
        LM remains the fallback for a start that GN overshoots from.

        The kept graph has one slot per edge where the judged graph holds no prior, and then
        ``refine`` need not walk its factors to find that out (MIT: 40 ms of a 1.3 s run)."""
        graph = self.kept_graph(kept)
        has_prior = False if graph.size() == self.g.num_edges else None
        refined = refine(graph, values, "gn", iterations, pose_graph=self.g,
                         tolerance=tolerance, has_prior=has_prior)
        if refined.failure is not None or not refined.chi2 <= refined.chi2_trace[0]:
            refined = refine(graph, values, solver_params("lm", iterations, tolerance),
                             pose_graph=self.g, has_prior=has_prior)
        if refined.failure is not None:
            raise SolverError(f"robust initialization: {refined.failure}")
        return refined


def edge_factor_indices(graph: gtsam.NonlinearFactorGraph, num_edges: int,
                        between_factor: type) -> np.ndarray:
    """(m,) the factor index of each edge of the graph's extraction (edges are in graph
    order)."""
    indices = np.array([k for k in range(graph.size())
                        if isinstance(graph.at(k), between_factor)], dtype=np.int64)
    if len(indices) != num_edges:
        raise GraphError(f"the graph has {len(indices)} between factors but its extraction has "
                         f"{num_edges} edges")
    return indices


def without_factors(graph: gtsam.NonlinearFactorGraph,
                    indices: list[int]) -> gtsam.NonlinearFactorGraph:
    """A copy of ``graph`` with the factors at ``indices`` removed (their slots left empty)."""
    copy = gtsam.NonlinearFactorGraph(graph)
    for k in indices:
        copy.remove(int(k))
    return copy


def relaxation(group: Group, settings: RobustSettings, max_rank: int | None = None,
               max_iterations: int | None = None) -> Initializer:
    """The certified relaxation as the robust steps run it, the staircase's highest rank and
    trust-region iterations per rank as given; None: on planar graphs the certified
    initializer's own, in 3D the lowest rank and ``relaxation_iterations_3d``."""
    if group.dimension == 3:
        max_rank = max_rank or group.lowest_rank
        max_iterations = max_iterations or settings.relaxation_iterations_3d
    options = {"max_rank": max_rank, "max_iterations": max_iterations}
    return make_initializer("certified", **{k: v for k, v in options.items() if v is not None})


def relaxation_rotations(g: PoseGraph, max_iterations: int,
                         settings: RobustSettings) -> np.ndarray:
    """The rotations of the relaxation's estimate of ``g`` at its group's lowest rank, from
    the chordal estimate, after at most ``max_iterations`` trust-region iterations: planar,
    the descent alone (no verification); 3D, the staircase held at rank 3 (at most
    ``relaxation_iterations_3d``). Held poses (the anchor, FIXed poses) at their rotations:
    the translation step holds their positions, and a FIXed pose turned would misplace the
    closures at it."""
    from rlpgo_gtsam.relaxation import descend, synchronize

    group = group_of(g)
    if group.dimension != 3:
        rotations = descend(g, max_iterations=max_iterations)
    else:
        rotations, _ = synchronize(g, max_rank=group.lowest_rank,
                                   max_iterations=min(settings.relaxation_iterations_3d,
                                                      max_iterations))
    held, held_poses = g.held
    rotations[held] = group.rotations(held_poses)
    return rotations
