"""The relaxation itself: how the certified stage scales against SE-Sync, and an independent
dense check of a certificate.

    python benchmarks/relaxation.py scale [--base /tmp/other-checkout] [--cap 600]
        [--easy 5000,10000,20000,50000] [--hard 1000:0.3:0.5,1000:0.5:0.5,500:3:1,2000:3:1]
        [--sesync BINARY|none] [--sesync-cap 600] [--cache DIR] [--append]
    python benchmarks/relaxation.py verify ../shared/datasets/M3500C.g2o

``scale``. Easy generated graphs from 5k to 50k poses (growth) and hard ones where the
relaxation is not exact (every status, chi2 after GTSAM LM30), each case run in a fresh
process on this checkout ("ours") and, with ``--base``, on another ("base"), then SE-Sync.
Graphs: ``rlpgo-generate --n N --sigma-r S --lc LC --noisy-measurements --seed 1`` (sigma_t
0.05, d 3), cached under ``--cache``; easy: sigma_R 0.05, lc 0.3; hard ones are ``N:S:LC``.
Per run: CPU seconds (one BLAS thread) of the certified stage as ``rlpgo-init --method
certified --refine none`` runs it (chordal start, staircase, translations), its status, final
rank, trust-region steps and Hessian products; on hard graphs also chi2 after LM30 from its
estimate. SE-Sync (its driver, default options, one thread; skipped without a binary): CPU
seconds of its whole process (file reading and the driver's eigenvalue check included, so an
upper bound), its wall seconds of the ``SESync`` call, status, rank and chi2 after LM30. A
run over ``--cap`` (SE-Sync: ``--sesync-cap``) wall seconds is killed and reported as
``cap``. ``--append`` adds the rows to those of an earlier run of the same name.

``verify FILE``. Builds the planar relaxation's data matrix Q densely with code of its own
(no helper of the package's relaxation), as the Schur complement of the full quadratic form in
(translations, rotations) with the first translation fixed; then takes the estimate of
``synchronize`` and checks its cost z^H Q z against the certificate's and the smallest
eigenvalues of S = Q - Lambda(z) by a dense Hermitian eigensolver: S >= 0 proves z optimal
for the semidefinite relaxation, hence for the rotation problem. n^3 work: meant for graphs up
to a few thousand poses. Writes ``benchmarks/results/verify_<stem>.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness  # noqa: E402
from benchmarks.harness import RESULTS  # noqa: E402

WORKER = r"""
import json, sys, time
from rlpgo_gtsam import extract_pose_graph, make_initializer, read_g2o, refine
from rlpgo_gtsam.numerics import bounded_threads
import importlib

# the module whose trust-region loop calls truncated_cg, in this checkout's layout
for name in ("rlpgo_gtsam.relaxation.trust_region", "rlpgo_gtsam.staircase"):
    try:
        steps = importlib.import_module(name)
        break
    except ImportError:
        continue

path, with_lm = sys.argv[1], sys.argv[2] == "1"
graph, values = read_g2o(path)
pose_graph = extract_pose_graph(graph, values)
counts = {"steps": 0, "hessian_products": 0}
truncated_cg = steps.truncated_cg

def counted(grad, hess, pre, radius, *args, **kwargs):
    counts["steps"] += 1
    def product(v):
        counts["hessian_products"] += 1
        return hess(v)
    return truncated_cg(grad, product, pre, radius, *args, **kwargs)

steps.truncated_cg = counted
with bounded_threads():
    cpu, wall = time.process_time(), time.perf_counter()
    result = make_initializer("certified").run(pose_graph)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
certificate = result.certificate
row = {"cpu_s": cpu, "wall_s": wall, "rank": certificate.rank,
       "status": str(certificate.status), "estimate_cost": certificate.estimate_cost, **counts}
if with_lm:
    row["lm30_chi2"] = refine(graph, result.values, "lm", 30).chi2
print("RESULT " + json.dumps(row))
"""

SESYNC_LM = r"""
import json, sys
import numpy as np
from rlpgo_gtsam import extract_pose_graph, read_g2o, refine
graph, values = read_g2o(sys.argv[1])
pose_graph = extract_pose_graph(graph, values)
poses = np.array(json.loads(sys.stdin.read()))
print("RESULT " + json.dumps({"lm30_chi2": refine(graph, pose_graph.to_values(poses), "lm",
                                                   30).chi2}))
"""


# --- scale --------------------------------------------------------------------------------------

def _graph(cache: Path, n: int, sigma_r: float, lc: float) -> Path:
    """The cached g2o file of one generated graph (generated once, as rlpgo-generate)."""
    path = cache / f"n{n}_s{sigma_r:g}_lc{lc:g}_seed1.g2o"
    if not path.exists():
        from rlpgo_gtsam import generate, write_g2o

        sample = generate(n, sigma_r, 0.05, 3.0, lc, np.random.default_rng(1),
                          noisy_measurements=True)
        write_g2o(path, sample.graph, sample.initial)
    return path


def _child_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _result(command: list[str], env: dict, cap: float, cwd: Path,
            stdin: str | None = None) -> dict:
    started = time.perf_counter()
    try:
        done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=cap,
                              cwd=cwd, input=stdin)
    except subprocess.TimeoutExpired:
        return {"status": "cap", "wall_s": time.perf_counter() - started}
    for line in done.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[len("RESULT "):])
    return {"status": "error", "error": (done.stderr.strip().splitlines() or ["?"])[-1]}


def _run(checkout: Path, path: Path, with_lm: bool, cap: float) -> dict:
    """The certified stage in a fresh process on ``checkout``'s code, killed at ``cap``."""
    env = {**os.environ, "PYTHONPATH": f"{checkout}{os.pathsep}{checkout / 'cli'}",
           "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    return _result([sys.executable, "-c", WORKER, str(path), "1" if with_lm else "0"], env,
                   cap, checkout)  # python -c puts the cwd first on sys.path


def _sesync(binary: str, path: Path, with_lm: bool, cap: float) -> dict:
    """SE-Sync's driver on ``path``: its process's CPU seconds, its result, LM30 from it."""
    from benchmarks.sesync.runner import run_sesync

    before = _child_cpu()
    try:
        run = run_sesync(binary, path, timeout=cap)
    except RuntimeError as error:
        text = str(error)
        return {"status": "cap" if "timed out" in text.lower() else "error", "error": text,
                "cpu_s": _child_cpu() - before, "wall_s": cap}
    row = {"cpu_s": _child_cpu() - before, "wall_s": run.seconds, "status": run.status,
           "rank": run.rank, "certified": run.certified}
    if with_lm:
        env = {**os.environ, "PYTHONPATH": f"{harness.ROOT}{os.pathsep}{harness.ROOT / 'cli'}"}
        row.update(_result([sys.executable, "-c", SESYNC_LM, str(path)], env, cap, harness.ROOT,
                           json.dumps(run.poses.tolist())))
    return row


def _cell(row: dict | None, with_lm: bool) -> str:
    if row is None:
        return "-"
    if row["status"] == "cap":
        cpu = f", {row['cpu_s']:.0f} s CPU" if "cpu_s" in row else ""
        return f"cap ({row.get('wall_s', 0):.0f} s wall{cpu})"
    if row["status"] == "error":
        return "error"
    text = f"{row['cpu_s']:.2f} s, {row['status']} r{row['rank']}"
    if "steps" in row:
        text += f", {row['steps']} steps, {row['hessian_products']} Hv"
    if with_lm and row.get("lm30_chi2") is not None:
        text += f", LM30 {row['lm30_chi2']:.8g}"
    return text


def _growth(rows: list[dict], name: str) -> None:
    """The exponent of CPU seconds against poses between consecutive easy sizes (runs that
    ended, capped ones left out)."""
    easy = [r for r in rows if r["kind"] == "easy" and (r.get(name) or {}).get("cpu_s")
            and r[name]["status"] not in ("cap", "error")]
    for a, b in zip(easy, easy[1:], strict=False):
        b[name]["growth"] = math.log(b[name]["cpu_s"] / a[name]["cpu_s"]) / \
            math.log(b["poses"] / a["poses"])


def scale(args) -> tuple[dict, str]:
    binary = None if args.sesync == "none" else harness.sesync_binary(args.sesync)
    args.cache.mkdir(parents=True, exist_ok=True)
    cases = []
    for spec in filter(None, args.hard.split(",")):
        n, sigma_r, lc = spec.split(":")
        cases.append(("hard", int(n), float(sigma_r), float(lc)))
    cases += [("easy", int(n), 0.05, 0.3) for n in filter(None, args.easy.split(","))]
    versions = [("ours", args.checkout)] + ([("base", args.base)] if args.base else [])
    columns = [name for name, _ in versions] + (["sesync"] if binary else [])
    header = ("| graph | " + " | ".join(f"{name}: CPU s, status, rank, steps, Hv, LM30 chi2"
                                         for name in columns) + " |\n|---|"
              + "---|" * len(columns))
    print(header, flush=True)
    rows: list[dict] = args.earlier_rows
    for kind, n, sigma_r, lc in cases:
        path = _graph(args.cache, n, sigma_r, lc)
        row: dict = {"graph": f"{kind} n={n} sigma_R={sigma_r:g} lc={lc:g}", "kind": kind,
                     "poses": n, "sigma_r": sigma_r, "lc": lc}
        with_lm = kind == "hard"
        for name, checkout in versions:  # one after the other, in one run
            row[name] = _run(checkout, path, with_lm, args.cap)
        if binary:
            row["sesync"] = _sesync(binary, path, with_lm, args.sesync_cap or args.cap)
        rows.append(row)
        print(f"| {row['graph']} | " + " | ".join(_cell(row[c], with_lm) for c in columns)
              + " |", flush=True)
        args.save({"rows": rows}, None)
    rows.sort(key=lambda row: (row["kind"], row["poses"], row["sigma_r"]))
    for name in columns:
        for row in rows:
            (row.get(name) or {}).pop("growth", None)
        _growth(rows, name)
    lines = [header]
    for row in rows:
        cells = []
        for name in columns:
            text = _cell(row.get(name), row["kind"] == "hard")
            if "growth" in row.get(name, {}):
                text += f" (growth n^{row[name]['growth']:.2f})"
            cells.append(text)
        lines.append(f"| {row['graph']} | " + " | ".join(cells) + " |")
    return {"rows": rows}, "\n".join(lines) + "\n"


# --- verify -------------------------------------------------------------------------------------

def dense_q(pose_graph) -> np.ndarray:
    """Q of f(z) = min_t sum_e 2 kappa |z_j - z_i r_e|^2 + tau |t_j - t_i - z_i c_e|^2."""
    import scipy.linalg as la
    import scipy.sparse as sp

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


def verify(args) -> tuple[dict, str]:
    import scipy.linalg as la

    from rlpgo_gtsam import extract_pose_graph, read_g2o
    from rlpgo_gtsam.relaxation import synchronize

    graph, values = read_g2o(args.file)
    pose_graph = extract_pose_graph(graph, values)
    theta, certificate = synchronize(pose_graph)
    start = time.perf_counter()
    q = dense_q(pose_graph)
    z = np.exp(1j * theta)
    cost = float(np.real(z.conj() @ q @ z))
    multipliers = np.real(np.conj(z) * (q @ z))
    lowest = la.eigvalsh(q - np.diag(multipliers), subset_by_index=[0, 2])
    record = {"file": args.file.name, "poses": pose_graph.num_poses,
              "certificate": certificate.record(), "dense_cost": cost,
              "dense_trace_lambda": float(multipliers.sum()),
              "dense_lowest_eigenvalues": lowest.tolist(),
              "dense_seconds": time.perf_counter() - start}
    text = (f"{args.file.name}: certificate says certified={certificate.certified}, estimate "
            f"cost {certificate.estimate_cost:.10g}, lambda_min "
            f"{certificate.min_eigenvalue:.3g}\ndense check: z^H Q z = {cost:.10g}, "
            f"tr(Lambda) = {multipliers.sum():.10g}, three lowest eigenvalues of S: "
            f"{', '.join(f'{w:.3g}' for w in lowest)}\n")
    return record, text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sc = sub.add_parser("scale", help="the certified stage on growing and hard graphs")
    sc.add_argument("--checkout", type=Path, default=harness.ROOT,
                    help="the checkout measured (default: this one)")
    sc.add_argument("--base", type=Path, help="another checkout, measured beside it")
    sc.add_argument("--cap", type=float, default=600.0, help="wall seconds per run")
    sc.add_argument("--easy", default="5000,10000,20000,50000")
    sc.add_argument("--hard", default="1000:0.3:0.5,1000:0.5:0.5,500:3:1,2000:3:1",
                    help="N:SIGMA_R:LC per hard graph")
    sc.add_argument("--sesync", help="SE-Sync driver (default: $RLPGO_SESYNC_BINARY or none); "
                    "'none' skips it")
    sc.add_argument("--sesync-cap", type=float,
                    help="wall seconds per SE-Sync run (default: --cap)")
    sc.add_argument("--cache", type=Path, default=Path("/tmp/relaxation_scale"))
    sc.add_argument("--name", default="relaxation_scale")
    sc.add_argument("--append", action="store_true",
                    help="add the rows to those of benchmarks/results/<name>.json")
    ve = sub.add_parser("verify", help="a dense check of one planar file's certificate")
    ve.add_argument("file", type=Path)
    ve.add_argument("--name", help="results file name (default: verify_<the file's stem>)")
    args = parser.parse_args()
    command = harness.command_line()
    if args.command == "verify":
        record, text = verify(args)
        print(text, end="")
        name = args.name or f"verify_{args.file.stem}"
        print(f"wrote {harness.write_result(name, command, record)}")
        return
    args.earlier_rows = []
    if args.append and (RESULTS / f"{args.name}.json").exists():
        earlier = json.loads((RESULTS / f"{args.name}.json").read_text())
        args.earlier_rows, command = earlier["rows"], f"{earlier['command']} && {command}"

    def save(data: dict, table: str | None) -> None:
        harness.write_result(args.name, command, data, table)

    args.save = save
    data, table = scale(args)
    print(table)
    save(data, table)


if __name__ == "__main__":
    main()
