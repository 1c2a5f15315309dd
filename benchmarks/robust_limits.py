"""How many wrong closures could any decision reject? Each one's innovation against the right map.

    python benchmarks/robust_limits.py [--cases MIT,Intel] [--modes random,local,group,localgroup]
        [--fraction 0.1] [--probability 0.9999]

Per case and policy (the wrong closures of ``benchmarks/robust.py``: seed 1, around the
certified + LM optimum of the outlier-free graph), every wrong closure is tested against
that optimum with the map's own uncertainty: ``b^T (I + A P A^T)^-1 b`` (whitened residual
``b`` and Jacobian ``A`` from GTSAM's linearization, ``P`` GTSAM's joint marginal of its two
poses in the outlier-free graph). A wrong closure below the chi-square bar (3 dof, 0.9999:
21.1) fits the right map as well as a true one may: no test of single closures at that
inlier probability rejects it, so ``1 - passing / wrong`` bounds the recall of such tests.
``--probability`` sets another bar (0.99: 11.3, which a true closure exceeds one time in a
hundred). Prints one line per case and policy.

``--oracle``: the best any single-closure test can do that knows the right map and its
uncertainty. Each true loop closure (an edge of the outlier-free graph off its odometry
chain, :func:`~rlpgo_gtsam.graph.odometry_edges`) gets its deleted-residual innovation
``b^T (I - A P A^T)^-1 b`` (its residual against the map made without it); a test rejects
every closure at or above a bar ``t``; over all bars, the line gives the largest
``min(precision, recall)`` and the bar that reaches it. Where that is below 0.98, no
single-closure decision reaches precision and recall 0.98 on that row, however it is made.
Per case it also prints how the true closures' innovations spread (median, 99th percentile,
largest) and what a bar scaled by the variance factor their median gives (the a-posteriori
variance factor of geodesy's tau test, robust form: median over chi-square's median) would
do: how many true closures it rejects, and per policy how many wrong ones still pass it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import gtsam
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.robust import clean_case, corrupted  # noqa: E402
from rlpgo_gtsam.graph import PoseGraph2D, odometry_edges  # noqa: E402
from rlpgo_gtsam.robust.pipeline import DEFAULT_INLIER_PROBABILITY, chi2_quantile  # noqa: E402


def innovation(factor, optimum: gtsam.Values, marginals: gtsam.Marginals,
               held_out: bool = False) -> float:
    """The closure's chi2 against the map: a closure outside the graph the marginals belong
    to, ``b^T (I + A P A^T)^-1 b``; ``held_out``, one of its edges against the map made
    without it, ``b^T (I - A P A^T)^-1 b``."""
    jacobian, b = factor.linearize(optimum).jacobian()
    joint = marginals.jointMarginalCovariance(gtsam.KeyVector(factor.keys())).fullMatrix()
    spread = jacobian @ joint @ jacobian.T
    return float(b @ np.linalg.solve(np.eye(3) + (-spread if held_out else spread), b))


def best_split(wrong: np.ndarray, true: np.ndarray) -> tuple[float, float, float, float]:
    """(min(precision, recall), precision, recall, bar) of the best bar: closures at or above
    it rejected."""
    best = (-1.0, 0.0, 0.0, 0.0)
    for bar in np.unique(np.concatenate([wrong, true])):
        hit, false = int((wrong >= bar).sum()), int((true >= bar).sum())
        precision = hit / (hit + false) if hit + false else 1.0
        recall = hit / len(wrong)
        if min(precision, recall) > best[0]:
            best = (min(precision, recall), precision, recall, float(bar))
    return best


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--cases", default="MIT,Intel")
    parser.add_argument("--modes", default="random,local,group,localgroup")
    parser.add_argument("--fraction", type=float, default=0.1)
    parser.add_argument("--probability", type=float, default=DEFAULT_INLIER_PROBABILITY)
    parser.add_argument("--oracle", action="store_true")
    args = parser.parse_args()
    bar = chi2_quantile(args.probability, 3)
    for name in args.cases.split(","):
        graph, values, optimum, _ = clean_case(name)
        pinned = gtsam.NonlinearFactorGraph(graph)
        anchor = int(min(optimum.keys()))
        pinned.add(gtsam.PriorFactorPose2(anchor, optimum.atPose2(anchor),
                                          gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
        marginals = gtsam.Marginals(pinned, optimum)
        true = None
        if args.oracle:  # every edge of the outlier-free graph off its odometry chain
            closures = np.flatnonzero(~odometry_edges(PoseGraph2D.from_gtsam(graph, values)))
            true = np.array([innovation(graph.at(int(k)), optimum, marginals, held_out=True)
                             for k in closures])
            factor = float(np.median(true)) / chi2_quantile(0.5, 3)
            print(f"{name}: {len(true)} true closures, innovations median "
                  f"{np.median(true):.2f}, 99th percentile {np.percentile(true, 99):.2f}, "
                  f"largest {true.max():.2f}; variance factor from the median {factor:.3f}: "
                  f"bar {factor * bar:.2f} rejects {int((true >= factor * bar).sum())} of them",
                  flush=True)
        for mode in args.modes.split(","):
            bad, wrong = corrupted(name, graph, optimum, args.fraction, mode)
            scores = np.array([innovation(bad.at(k), optimum, marginals) for k in wrong])
            passing = int((scores < bar).sum())
            print(f"{name} {mode} {args.fraction:g}: {passing} of {len(wrong)} wrong closures fit "
                  f"the right map (innovation < {bar:.1f}; lowest {scores.min():.1f}): recall of "
                  f"single-closure tests at most {1 - passing / len(wrong):.3f}", flush=True)
            if true is not None:
                both, precision, recall, cut = best_split(scores, true)
                print(f"  oracle: {len(true)} true closures; best bar {cut:.1f}: precision "
                      f"{precision:.3f}, recall {recall:.3f} (min {both:.3f}); the scaled "
                      f"bar passes {int((scores < factor * bar).sum())} wrong closures",
                      flush=True)


if __name__ == "__main__":
    main()
