"""An independent, dense check of a certificate: is the certified estimate really the global
optimum of the relaxation?

    python benchmarks/verify_certificate.py ../shared/datasets/M3500C.g2o

Builds the relaxation's data matrix Q densely from the module docstring's formula with code
of its own (no helper of rlpgo_gtsam.certified is used), as the Schur complement of the full
quadratic form in (translations, rotations) with the first translation fixed; then takes
the estimate of ``synchronize`` and checks (1) its cost z^H Q z against the certificate's,
(2) the smallest eigenvalues of S = Q - Lambda(z) by a dense Hermitian eigensolver: S >= 0
proves z optimal for the semidefinite relaxation, hence for the rotation problem. n^3 work:
meant for graphs up to a few thousand poses. Writes benchmarks/results/verify_<name>.json.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import write_result  # noqa: E402
from rlpgo_gtsam import PoseGraph2D, read_g2o  # noqa: E402
from rlpgo_gtsam.certified import synchronize  # noqa: E402


def dense_q(pose_graph: PoseGraph2D) -> np.ndarray:
    """Q of f(z) = min_t sum_e 2 kappa |z_j - z_i r_e|^2 + tau |t_j - t_i - z_i c_e|^2."""
    g = pose_graph
    n, m = g.num_poses, g.num_edges
    i, j, e = g.edges[:, 0], g.edges[:, 1], np.arange(m)
    kappa = g.information[:, 2, 2]
    tau = 2.0 / np.trace(np.linalg.inv(g.information[:, :2, :2]), axis1=1, axis2=2)
    r = np.exp(1j * g.measured[:, 2])
    c = g.measured[:, 0] + 1j * g.measured[:, 1]

    def rows(values, columns):
        return sp.coo_matrix((values, (np.concatenate([e, e])[: len(values)], columns)),
                             shape=(m, n)).tocsr()

    rotation = rows(np.concatenate([np.sqrt(2 * kappa), -np.sqrt(2 * kappa) * r]),
                    np.concatenate([j, i]))
    translation_t = rows(np.concatenate([np.sqrt(tau), -np.sqrt(tau)]).astype(complex),
                         np.concatenate([j, i]))
    translation_z = rows(-np.sqrt(tau) * c, i)
    m_zz = (rotation.conj().T @ rotation + translation_z.conj().T @ translation_z).toarray()
    m_tt = (translation_t.conj().T @ translation_t).toarray()[1:, 1:]
    m_tz = (translation_t.conj().T @ translation_z).toarray()[1:]
    q = m_zz - m_tz.conj().T @ la.solve(m_tt, m_tz, assume_a="her")
    return 0.5 * (q + q.conj().T)


def main() -> None:
    path = Path(sys.argv[1])
    graph, values = read_g2o(path)
    pose_graph = PoseGraph2D.from_gtsam(graph, values)
    theta, certificate = synchronize(pose_graph)
    start = time.perf_counter()
    q = dense_q(pose_graph)
    z = np.exp(1j * theta)
    cost = float(np.real(z.conj() @ q @ z))
    multipliers = np.real(np.conj(z) * (q @ z))
    lowest = la.eigvalsh(q - np.diag(multipliers), subset_by_index=[0, 2])
    record = {
        "file": path.name, "poses": pose_graph.num_poses,
        "certificate": certificate.record(), "dense_cost": cost,
        "dense_trace_lambda": float(multipliers.sum()),
        "dense_lowest_eigenvalues": lowest.tolist(),
        "dense_seconds": time.perf_counter() - start,
    }
    print(f"{path.name}: certificate says certified={certificate.certified}, estimate cost "
          f"{certificate.estimate_cost:.10g}, lambda_min {certificate.min_eigenvalue:.3g}")
    print(f"dense check: z^H Q z = {cost:.10g}, tr(Lambda) = {multipliers.sum():.10g}, "
          f"three lowest eigenvalues of S: {', '.join(f'{w:.3g}' for w in lowest)}")
    print(f"wrote {write_result(f'verify_{path.stem}', record)}")


if __name__ == "__main__":
    main()
