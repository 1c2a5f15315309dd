"""How many wrong closures could any decision reject? Each one's innovation against the right map.

    python benchmarks/robust_limits.py [--cases MIT,Intel] [--modes random,local,group,localgroup]
        [--fraction 0.1]

Per case and policy (the wrong closures of ``benchmarks/robust.py``: seed 1, around the
certified + LM optimum of the outlier-free graph), every wrong closure is tested against
that optimum with the map's own uncertainty: ``b^T (I + A P A^T)^-1 b`` (whitened residual
``b`` and Jacobian ``A`` from GTSAM's linearization, ``P`` GTSAM's joint marginal of its two
poses in the outlier-free graph). A wrong closure below the chi-square bar (3 dof, 0.9999:
21.1) fits the right map as well as a true one may: no test of single closures at that
inlier probability rejects it, so ``1 - passing / wrong`` bounds the recall of such tests.
Prints one line per case and policy.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import gtsam
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.robust import clean_case, corrupted  # noqa: E402
from rlpgo_gtsam.robust.pipeline import DEFAULT_INLIER_PROBABILITY, chi2_quantile  # noqa: E402


def innovation(factor, optimum: gtsam.Values, marginals: gtsam.Marginals) -> float:
    jacobian, b = factor.linearize(optimum).jacobian()
    joint = marginals.jointMarginalCovariance(gtsam.KeyVector(factor.keys())).fullMatrix()
    return float(b @ np.linalg.solve(np.eye(3) + jacobian @ joint @ jacobian.T, b))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--cases", default="MIT,Intel")
    parser.add_argument("--modes", default="random,local,group,localgroup")
    parser.add_argument("--fraction", type=float, default=0.1)
    args = parser.parse_args()
    bar = chi2_quantile(DEFAULT_INLIER_PROBABILITY, 3)
    for name in args.cases.split(","):
        graph, _, optimum, _ = clean_case(name)
        pinned = gtsam.NonlinearFactorGraph(graph)
        anchor = int(min(optimum.keys()))
        pinned.add(gtsam.PriorFactorPose2(anchor, optimum.atPose2(anchor),
                                          gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
        marginals = gtsam.Marginals(pinned, optimum)
        for mode in args.modes.split(","):
            bad, wrong = corrupted(name, graph, optimum, args.fraction, mode)
            scores = np.array([innovation(bad.at(k), optimum, marginals) for k in wrong])
            passing = int((scores < bar).sum())
            print(f"{name} {mode} {args.fraction:g}: {passing} of {len(wrong)} wrong closures fit "
                  f"the right map (innovation < {bar:.1f}; lowest {scores.min():.1f}): recall of "
                  f"single-closure tests at most {1 - passing / len(wrong):.3f}", flush=True)


if __name__ == "__main__":
    main()
