"""Pairwise consistency of loop closures (PCM-style), bounded in memory and time.

Two loop closures ``e = (i, j)`` and ``f = (k, l)`` close a cycle through the odometry
chain: ``Z_e^-1 D(i, k) Z_f D(l, j)`` is the identity up to noise (``D(a, b)`` the chained
odometry from pose a to pose b). Its error (the cycle's Logmap: 3 dof on SE(2), 6 on SE(3))
is scored against the cycle's covariance, propagated to first order from every measurement
in it through the group's adjoints. A score above the bar is evidence that one of the two is
wrong: a *conflict*. The group is the graph's (:mod:`rlpgo_gtsam.groups`): the same
code for planar and 3D graphs.

Following pairwise consistency maximization (Mangelson et al., ICRA 2018) the closures are
the nodes of a graph; here its edges are the conflicts, and the consistent set is a large
set of closures with no conflict among them (an independent set of the conflict graph, the
maximum clique of the consistency graph in which untested pairs count as consistent). It
is found greedily: the closure with the most conflicts goes first (ties: the one with fewer
agreeing tests), until no conflict is left. A closure that nothing contradicts is kept:
absence of support is not evidence against it. A group of wrong closures that agree with
each other (Vertigo's groups) conflicts with the many true closures it contradicts, so it
goes, not them.

Bounded: each closure is tested against at most ``consistency_near`` closures next to it in
chain order (sorted by the chain position of its nearer end) and ``consistency_far`` closures
spread evenly over the chain order (:class:`~rlpgo_gtsam.robust.settings.RobustSettings`), so
at most ``(near + far) x closures`` pairs, scored in chunks: memory and time are linear in
the number of closures, whatever their layout (5000 parallel closures on 21 poses included).

The chain is the spanning tree :func:`~rlpgo_gtsam.graph.odometry_edges` finds; ``D(a, b)``
follows the tree through the two poses' lowest common ancestor, and its covariance comes
from prefix sums of the steps' covariances in the root's frame, so every pair costs the
same whatever its length.

What it cannot tell apart: two sets of closures that conflict with each other and are
(nearly) equally supported. Each connected group of conflicts whose rejected closures form
a consistent alternative at least ``ambiguous_ratio`` times the size of what was kept
there is reported (:attr:`Consistency.ambiguous`), not decided silently.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field

import numpy as np

from rlpgo_gtsam.graph import PoseGraph, component_labels
from rlpgo_gtsam.groups import Group, group_of
from rlpgo_gtsam.robust.settings import RobustSettings

__all__ = ["Consistency", "ChainTree", "pairwise_consistency"]


@dataclass
class Consistency:
    """What :func:`pairwise_consistency` found; masks over the graph's edges.

    Attributes:
        kept: the loop closures in the consistent set (chain edges are False).
        supported: kept closures that agree with at least ``loose_support`` tested ones over
            short cycles (both ends within ``support_window`` chain steps).
        seed: kept closures with positive support, where the robust start begins: at least
            ``min_support`` agreements in tests that a wrong closure would pass by chance
            less than ``informative_chance`` of the time, or loose support. (Support chooses
            where the estimate starts; only evidence rejects.)
        pairs: pairs scored.
        conflicts: pairs in conflict.
        bar: the score below which a pair agrees (support).
        ambiguous: per connected group of conflicts that could have gone either way, the
            edge indices kept there and those of the rejected, consistent alternative.
    """

    kept: np.ndarray
    supported: np.ndarray
    seed: np.ndarray
    pairs: int = 0
    conflicts: int = 0
    bar: float = float("nan")
    ambiguous: list[tuple[list[int], list[int]]] = field(default_factory=list)


@dataclass
class ChainTree:
    """The odometry chain as a tree rooted at the anchor.

    Attributes:
        parent: (n,) each pose's parent (the root its own).
        depth: (n,) steps from the root.
        poses: (n, ...) each pose chained from the root (the root at the identity), the
            group's pose rows.
        prefix: (n, dof, dof) the covariance of the steps from the root, in the root's frame.
        position: (n,) depth-first preorder index (a path's order; subtrees contiguous).
        by_rank: (n,) the pose at each preorder index.
        shallowest: (levels, n) per level k and preorder index p, the preorder index of the
            shallowest pose among preorder indices p .. p + 2^k - 1 (a sparse table for
            :meth:`ancestor`; where that range runs past n, unused).
        group: the group the poses live in.
    """

    parent: np.ndarray
    depth: np.ndarray
    poses: np.ndarray
    prefix: np.ndarray
    position: np.ndarray
    by_rank: np.ndarray
    shallowest: np.ndarray
    group: Group

    @classmethod
    def build(cls, g: PoseGraph, chain_mask: np.ndarray, covariance: np.ndarray) -> ChainTree:
        group = group_of(g)
        n = g.num_poses
        neighbours: list[list[tuple[int, int]]] = [[] for _ in range(n)]
        for e in np.flatnonzero(chain_mask).tolist():
            i, j = g.edges[e].tolist()
            neighbours[i].append((j, e))
            neighbours[j].append((i, e))
        parent = np.arange(n)
        depth = np.zeros(n, np.int64)
        position = np.full(n, -1, np.int64)
        steps = group.identity(n)
        step_cov = np.zeros((n, group.dof, group.dof))
        reverse = np.zeros(n, bool)
        via = np.full(n, -1, np.int64)
        order: list[int] = []
        stack = [g.anchor]
        position[g.anchor] = 0
        while stack:  # depth-first preorder
            a = stack.pop()
            order.append(a)
            for b, e in reversed(neighbours[a]):
                if position[b] < 0:
                    position[b] = 0
                    parent[b], depth[b], via[b] = a, depth[a] + 1, e
                    reverse[b] = g.edges[e, 0] == b
                    stack.append(b)
        if len(order) != n:
            raise ValueError("the odometry chain does not span the graph")
        position[np.array(order)] = np.arange(n)
        child = np.flatnonzero(via >= 0)
        steps[child], step_cov[child] = _oriented(group, group.measured(g)[via[child]],
                                                  covariance[via[child]], reverse[child])
        rounds = int(depth.max()).bit_length()
        poses = _from_root(parent, rounds, steps, group.compose)
        prefix = _from_root(parent, rounds, _sandwich(group.adjoint(poses), step_cov),
                            np.add)
        # the sparse table of the shallowest pose over preorder ranges (see ancestor)
        by_rank = np.array(order, np.int64)
        rank_depth = depth[by_rank]
        shallowest = np.zeros((max(1, n.bit_length()), n), np.int64)
        shallowest[0] = np.arange(n)
        for k in range(1, len(shallowest)):
            width = 1 << (k - 1)
            left, right = shallowest[k - 1, :n - width], shallowest[k - 1, width:]
            shallowest[k, :n - width] = np.where(rank_depth[right] < rank_depth[left],
                                                 right, left)
        return cls(parent, depth, poses, prefix, position, by_rank, shallowest, group)

    def ancestor(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Lowest common ancestors of index arrays ``a`` and ``b``: for preorder indices
        ``p_a < p_b``, the parent of the shallowest pose with a preorder index in
        ``(p_a, p_b]`` (the child of the common ancestor on the way down to ``b``), found by
        two lookups in the sparse table; ``a`` itself where ``a == b``."""
        low = np.minimum(self.position[a], self.position[b])
        high = np.maximum(self.position[a], self.position[b])
        found = np.array(a, np.int64)
        differ = low < high
        first, last = low[differ] + 1, high[differ]
        level = np.frexp(last - first + 1)[1] - 1  # floor(log2(length)), exactly
        left = self.shallowest[level, first]
        right = self.shallowest[level, last - (1 << level) + 1]
        depth = self.depth[self.by_rank]
        pick = np.where(depth[right] < depth[left], right, left)
        found[differ] = self.parent[self.by_rank[pick]]
        return found

    def distance(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Steps along the tree between index arrays ``a`` and ``b``."""
        return self.depth[a] + self.depth[b] - 2 * self.depth[self.ancestor(a, b)]

    def cycles(self, i: np.ndarray, j: np.ndarray, k: np.ndarray, m: np.ndarray,
               z_e: np.ndarray, cov_e: np.ndarray, z_f: np.ndarray,
               cov_f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Errors (Logmap) and covariances of the cycles ``Z_e^-1 D(i, k) Z_f D(m, j)`` that
        closures ``e = (i, j)`` and ``f = (k, m)`` (measured ``z``, right-frame covariances
        ``cov``) close through the tree, in the cycle's end frame, to first order.

        Each measurement's error reaches the end frame through the adjoint of the inverse of
        what follows it. The chain's steps enter through ``D(i, k) = X_i^-1 X_k`` and
        ``D(m, j)``: with ``X_a = Exp(eps_a) X_a`` (``eps_a`` the root-frame sum of the steps
        above a), the error is ``A1 (eps_k - eps_i) + A2 (eps_j - eps_m)``, ``A1 = Ad((X_k
        Z_f D(m, j))^-1)``, ``A2 = Ad(X_j^-1)``, and its covariance is ``sum_ab c_a
        P(lca(a, b)) c_b^T`` over the four ends (``c_k = A1 = -c_i``, ``c_j = A2 = -c_m``):
        steps that both segments pass (the segments overlap where the closures lie apart
        along the chain) are counted once, with the coefficient ``A1 - A2``, not twice.
        """
        g, x, p = self.group, self.poses, self.prefix
        d_ik, d_mj = g.between(x[i], x[k]), g.between(x[m], x[j])
        z_inv, cov_inv = _oriented(g, z_e, cov_e, True)
        tail = g.compose(z_f, d_mj)  # what follows D(i, k)
        after = g.compose(d_ik, tail)  # what follows Z_e^-1
        a1 = g.adjoint(g.inverse(g.compose(x[k], tail)))
        a2 = g.adjoint(g.inverse(x[j]))
        near = p[i] + p[k] - 2.0 * p[self.ancestor(i, k)]
        far = p[j] + p[m] - 2.0 * p[self.ancestor(j, m)]
        shared = (p[self.ancestor(k, j)] - p[self.ancestor(k, m)] - p[self.ancestor(i, j)]
                  + p[self.ancestor(i, m)])
        cross = a1 @ shared @ np.transpose(a2, (0, 2, 1))
        total = (_sandwich(g.adjoint(g.inverse(after)), cov_inv)
                 + _sandwich(g.adjoint(g.inverse(d_mj)), cov_f) + _sandwich(a1, near)
                 + _sandwich(a2, far) + cross + np.transpose(cross, (0, 2, 1)))
        return g.logmap(g.compose(z_inv, after)), total

    def between(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``D(a, b)`` along the tree and its covariance in b's frame.

        A step's error moves every pose below it rigidly (in the root's frame); ``D(a, b) =
        X_a^-1 X_b`` sees the steps from the common ancestor down to a and down to b, each
        once: ``Ad(X_b)^-1 (P_a + P_b - 2 P_lca) Ad(X_b)^-T``.
        """
        lca = self.ancestor(a, b)
        total = self.prefix[a] + self.prefix[b] - 2.0 * self.prefix[lca]
        inv = np.linalg.inv(self.group.adjoint(self.poses[b]))
        return self.group.between(self.poses[a], self.poses[b]), _sandwich(inv, total)


def pairwise_consistency(g: PoseGraph, chain_mask: np.ndarray, threshold: float,
                         settings: RobustSettings | None = None) -> Consistency:
    """The consistent set of loop closures; see the module docstring.

    Args:
        g: the graph.
        chain_mask: (m,) the odometry chain (a spanning tree; the rest are closures).
        threshold: chi-square bar of a consistent cycle (the group's dof: 3 planar, 6 3D).
        settings: the closures tested per closure, the support and conflict scales (None:
            the defaults).
    """
    settings = settings if settings is not None else RobustSettings()
    closures = np.flatnonzero(~chain_mask)
    kept = ~chain_mask
    result = Consistency(kept=kept.copy(), supported=np.zeros(g.num_edges, bool),
                         seed=np.zeros(g.num_edges, bool))
    if len(closures) < 2:
        return result
    scored = _scored_pairs(g, chain_mask, closures, settings)
    a_idx, b_idx, scores = scored.a, scored.b, scored.scores
    # the scores' lower quartile sets the scale where nominal covariances overstate the
    # noise (real data); evidence against asks for a far larger multiple than support
    quartile = float(np.quantile(scores, 0.25))
    conflict = scores > min(threshold, settings.conflict_scale * quartile)
    bar = min(threshold, settings.data_scale * quartile)
    agreed = scores <= bar
    agree = np.bincount(np.concatenate([a_idx[agreed], b_idx[agreed]]),
                        minlength=len(closures))
    # the chance that a wrong closure agrees anyway: the agreement ellipsoid's volume over
    # that of the wrong closures' distribution (a square or cube of the chain's extent)
    group = scored.tree.group
    side = max(float(np.ptp(group.translations(scored.tree.poses), axis=0).max()), 1e-9)
    sharp = agreed & (group.agreement_chance(bar, scored.volume, side)
                      < settings.informative_chance)
    ca, cb = a_idx[conflict], b_idx[conflict]
    removed = _greedy_removal(len(closures), ca, cb, agree)
    kept[closures[removed]] = False
    result.kept = kept
    # support counts agreements with closures the conflicts left, and not with closures
    # parallel to it a few steps along (i + k, j + k): a run of wrong closures from one
    # aliased place (Vertigo's groups) agrees with itself, so a run must find its support
    # outside itself; a group of wrong closures that agree with each other supports nobody
    # once it is out; a true closure that the greedy removal took for a few conflicts with
    # true ones (linearized cycles under heavy rotation noise: 26 of 10496 true pairs on the
    # 0.2 rad graph) keeps its support from the rest and joins the seed when that outweighs
    # its conflicts with them
    near_agree = _count(len(closures), a_idx, b_idx, agreed & scored.short & ~scored.parallel,
                        ~removed)
    informed = _count(len(closures), a_idx, b_idx, sharp & ~scored.parallel, ~removed)
    against = _count(len(closures), a_idx, b_idx, conflict, ~removed)
    loose = near_agree >= settings.loose_support
    support = (informed >= settings.min_support) | loose
    result.supported[closures] = ~removed & loose
    result.seed[closures] = support & (~removed | (np.maximum(informed, near_agree) > against))
    result.pairs, result.conflicts, result.bar = len(a_idx), int(conflict.sum()), bar
    result.ambiguous = [
        (closures[k].tolist(), closures[r].tolist())
        for k, r in _ambiguous(len(closures), ca, cb, removed, agree, settings.ambiguous_ratio)]
    return result


@dataclass
class _ScoredPairs:
    """The pairs of closures tested (indices into the closures, ``a`` and ``b``), each
    pair's cycle score (chi2 of its error against its covariance), the cycle covariance's
    ``volume`` (sqrt det), whether the cycle is ``short`` (both ends within the support
    window) and whether the two closures run ``parallel`` a few steps apart."""

    tree: ChainTree
    a: np.ndarray
    b: np.ndarray
    scores: np.ndarray
    volume: np.ndarray
    short: np.ndarray
    parallel: np.ndarray


def _scored_pairs(g: PoseGraph, chain_mask: np.ndarray, closures: np.ndarray,
                  settings: RobustSettings) -> _ScoredPairs:
    """The pairs of ``closures`` to test (:func:`_pairs`), scored through the chain's tree in
    chunks of ``settings.consistency_chunk`` pairs."""
    covariance = np.linalg.inv(g.information)
    tree = ChainTree.build(g, chain_mask, covariance)
    group = tree.group
    i, j = g.edges[closures, 0].copy(), g.edges[closures, 1].copy()
    flip = tree.position[i] > tree.position[j]
    measured, closure_cov = _oriented(group, group.measured(g)[closures], covariance[closures],
                                      flip)
    i[flip], j[flip] = j[flip], i[flip].copy()
    a_idx, b_idx = _pairs(np.lexsort((tree.position[j], tree.position[i])),
                          settings.consistency_near, settings.consistency_far)
    window, chunk = settings.support_window, settings.consistency_chunk
    scored = _ScoredPairs(tree, a_idx, b_idx, np.empty(len(a_idx)), np.empty(len(a_idx)),
                          np.empty(len(a_idx), bool), np.empty(len(a_idx), bool))
    for start in range(0, len(a_idx), chunk):
        part = slice(start, start + chunk)
        a, b = a_idx[part], b_idx[part]
        error, total = tree.cycles(i[a], j[a], i[b], j[b], measured[a], closure_cov[a],
                                   measured[b], closure_cov[b])
        scored.scores[part] = np.einsum(
            "ea,ea->e", error, np.linalg.solve(total, error[..., None])[..., 0])
        scored.volume[part] = np.sqrt(np.maximum(np.linalg.det(total), 0.0))
        scored.short[part] = ((tree.distance(i[a], i[b]) <= window) &
                              (tree.distance(j[a], j[b]) <= window))
        shift_i = tree.position[i[b]] - tree.position[i[a]]
        shift_j = tree.position[j[b]] - tree.position[j[a]]
        scored.parallel[part] = (np.abs(shift_i - shift_j) <= 1) & (np.abs(shift_i) <= window)
    return scored


def _pairs(order: np.ndarray, near: int, far: int) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (a, b), a != b, each unordered pair once: for the closure at each rank of
    ``order``, the ``near`` next ranks and ``far`` ranks spread evenly over the rest."""
    m = len(order)
    offsets = np.arange(1, min(near, m - 1) + 1)
    if m - 1 > near and far > 0:
        spread = np.unique(np.linspace(near + 1, m - 1, min(far, m - 1 - near)).astype(np.int64))
        offsets = np.concatenate([offsets, spread])
    rank = np.arange(m)
    a = np.repeat(rank, len(offsets))
    b = (a + np.tile(offsets, m)) % m
    unique = np.sort(np.minimum(a, b) * m + np.maximum(a, b))
    # (sorted, then each key where it first appears: numpy 2.4's np.unique hashes, 1.8 s for
    # City10K's 0.8 M keys against 0.05 s for this)
    unique = unique[np.concatenate([[True], unique[1:] != unique[:-1]])]
    return order[unique // m], order[unique % m]


def _count(num: int, a: np.ndarray, b: np.ndarray, which: np.ndarray,
           partner: np.ndarray) -> np.ndarray:
    """(num,) per node, the pairs in ``which`` whose other node lies in ``partner``."""
    a, b = a[which], b[which]
    return (np.bincount(a[partner[b]], minlength=num) +
            np.bincount(b[partner[a]], minlength=num))


def _adjacency(num: int, a: np.ndarray, b: np.ndarray) -> list[list[int]]:
    adjacency: list[list[int]] = [[] for _ in range(num)]
    for x, y in zip(a.tolist(), b.tolist(), strict=True):
        adjacency[x].append(y)
        adjacency[y].append(x)
    return adjacency


def _greedy_removal(num: int, a: np.ndarray, b: np.ndarray, agree: np.ndarray,
                    among: np.ndarray | None = None) -> np.ndarray:
    """(num,) bool: the nodes removed until no conflict (a, b) is left, the node with the
    most conflicts first (ties: fewer agreements, then the lower index)."""
    if among is not None:
        inside = among[a] & among[b]
        a, b = a[inside], b[inside]
    adjacency = _adjacency(num, a, b)
    degree = np.bincount(np.concatenate([a, b]), minlength=num).tolist()
    agree = agree.tolist()
    heap = [(-degree[k], agree[k], k) for k in range(num) if degree[k] > 0]
    heapq.heapify(heap)
    removed = np.zeros(num, bool)
    while heap:
        d, _, k = heapq.heappop(heap)
        if removed[k] or degree[k] == 0:
            continue
        if -d != degree[k]:
            heapq.heappush(heap, (-degree[k], agree[k], k))
            continue
        removed[k] = True
        for other in adjacency[k]:
            if not removed[other]:
                degree[other] -= 1
    return removed


def _ambiguous(num: int, a: np.ndarray, b: np.ndarray, removed: np.ndarray,
               agree: np.ndarray, ratio: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per connected group of conflicts: (kept, alternative) node indices where the removed
    nodes hold a consistent alternative at least ``ratio`` x the kept side."""
    if len(a) == 0:
        return []
    # each component labelled by its smallest closure index: np.unique below walks them in
    # the order SciPy's connected_components numbered them (without its 5 ms import)
    labels = component_labels(num, np.stack([a, b], axis=1))
    involved = np.zeros(num, bool)
    involved[a] = involved[b] = True
    alternative = removed & ~_greedy_removal(num, a, b, agree, among=removed)
    found = []
    for label in np.unique(labels[involved]).tolist():
        members = involved & (labels == label)
        kept, other = np.flatnonzero(members & ~removed), np.flatnonzero(members & alternative)
        if len(kept) >= 2 and len(other) >= ratio * len(kept):
            found.append((kept, other))
    return found


def _from_root(parent: np.ndarray, rounds: int, steps: np.ndarray, combine) -> np.ndarray:
    """Per pose, ``combine`` folded over the ``steps`` from the root down to it (the root's
    own step the identity of ``combine``), by doubling: each round, every pose combines what
    its jump holds with what it holds (from the jump down to it) and jumps twice as far;
    ``rounds`` = bit length of the tree's depth reaches the root from every pose, in that
    many vectorized rounds instead of a loop over the poses."""
    jump = parent.copy()
    for _ in range(rounds):
        steps = combine(steps[jump], steps)
        jump = jump[jump]
    return steps


def _sandwich(a: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """Row-wise a C a^T."""
    return a @ covariance @ np.transpose(a, (0, 2, 1))


def _oriented(group: Group, poses: np.ndarray, covariance: np.ndarray,
              reverse: np.ndarray | bool) -> tuple[np.ndarray, np.ndarray]:
    """Relative poses (one per row) and their right-frame covariances, inverted where
    ``reverse``: ``(T Exp(d))^-1 = T^-1 Exp(-Ad(T) d)``."""
    reverse = np.broadcast_to(np.asarray(reverse, bool), (len(poses),))
    poses, covariance = poses.copy(), covariance.copy()
    covariance[reverse] = _sandwich(group.adjoint(poses[reverse]), covariance[reverse])
    poses[reverse] = group.inverse(poses[reverse])
    return poses, covariance
