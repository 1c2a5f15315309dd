"""What every benchmark script shares: the graphs, process-to-process timing, the anchors and
the results files.

- **Graphs.** :data:`FILES_2D` and :data:`FILES_3D` name the shared files (``$RLPGO_DATASETS``,
  by default ``../shared/datasets`` and its ``3d/``); :func:`shared_file` finds one,
  :func:`example_file` one of the gtsam wheel's example files (``Data/``), :func:`graph_file`
  either (or a path); :func:`read_graph` reads either dimension through the package's
  reader, and :func:`generated_graph` makes a ``rlpgo-generate`` file once into a cache.
- **Processes.** :func:`run` times a command as a user runs it: wall seconds from the fork to
  the exit, peak resident set and CPU seconds from ``wait4``; :func:`competing` keeps one
  core busy beside it; :func:`run_init` and :func:`run_baseline` are the two sides of the
  process benchmarks (``rlpgo-init FILE -o OUT`` against SE-Sync's driver then GTSAM LM30).
- **Anchors.** :func:`gtsam_lm` (GTSAM's LM, first pose fixed), :func:`gnc` (GTSAM's
  ``GncLMOptimizer``), :func:`dcs` (LM with every closure under GTSAM's DCS m-estimator),
  :func:`gtsam_staircase` (GTSAM's ``RiemannianStaircaseOptimizer`` on the rotations, where
  the wheel has it) and SE-Sync (:mod:`benchmarks.sesync`, optional).
- **Results.** :func:`write_result` writes ``benchmarks/results/<name>.json`` (the command
  line, the machine, the rows) and ``<name>.md`` (the command line and the table).

``python benchmarks/harness.py spawn RECORD OUT ERR TIMEOUT_S -- COMMAND...`` is the
launcher behind :func:`run` (this file imports only the standard library at its top, so the
launcher pays for nothing the measured command does not): it forks, execs COMMAND with its
stdout and stderr in OUT and ERR, waits with ``wait4`` and writes RECORD (JSON): wall
seconds from the fork to the child's exit, the exit status, the child's own peak resident
set (``ru_maxrss`` of ``wait4``; Linux carries the forking process's high-water mark into
the child, so it has a floor, the launcher's own resident set, :func:`launcher_floor_mb`)
and its CPU seconds. After TIMEOUT_S the child is killed.
"""

from __future__ import annotations

import contextlib
import gc
import json
import os
import platform
import shlex
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
DATASETS = Path(os.environ.get("RLPGO_DATASETS", ROOT.parent / "shared" / "datasets"))
LM30_SCRIPT = ROOT / "benchmarks" / "sesync" / "lm30.py"
FILES_2D = ("M3500", "M3500A", "M3500B", "M3500C", "Intel", "MIT", "City10K", "FR079")
FILES_3D = ("tinyGrid3D", "smallGrid3D", "parking-garage", "sphere2500", "torus3D", "cubicle",
            "sphere_bignoise_vertex3")


# --- graphs -----------------------------------------------------------------------------------

def shared_file(name: str) -> Path:
    """The shared file ``name`` (with or without ``.g2o``): planar ones in ``DATASETS``,
    3D ones in ``DATASETS/3d``."""
    stem = name.removesuffix(".g2o")
    folder = DATASETS / "3d" if stem in FILES_3D else DATASETS
    return folder / f"{stem}.g2o"


def graph_file(name: str) -> Path:
    """A graph named on a command line: a path that exists, else a shared file, else one of
    the gtsam wheel's example files (``noisyToyGraph.txt``, ``pose3example.txt``, ...)."""
    if Path(name).is_file():
        return Path(name)
    path = shared_file(name)
    return path if path.is_file() else example_file(name)


def example_file(name: str) -> Path:
    """One of the gtsam wheel's example files (its ``Data/`` folder), e.g. ``noisyToyGraph.txt``."""
    import gtsam

    return Path(gtsam.findExampleDataFile(name))


def read_graph(path: str | os.PathLike[str]):
    """``(graph, values)`` of a planar or 3D g2o file, read by the package's reader."""
    from rlpgo_gtsam import read_g2o

    return read_g2o(Path(path))


def graph_size(path: Path) -> tuple[int, int]:
    """(poses, edges) of a g2o file, counted from its ``VERTEX_`` and ``EDGE_`` lines."""
    poses = edges = 0
    with path.open() as handle:
        for line in handle:
            poses += line.startswith("VERTEX_SE")
            edges += line.startswith("EDGE_")
    return poses, edges


def generated_graph(folder: Path, n: int, sigma_r: float, seed: int, *, sigma_t: float = 0.05,
                    d: float = 3.0, lc: float = 0.5, noisy: bool = True) -> Path:
    """The file ``rlpgo-generate`` writes for these settings, made once into ``folder`` and
    reused by later calls."""
    name = (f"lawn_n{n}_r{sigma_r:g}_t{sigma_t:g}_d{d:g}_lc{lc:g}"
            f"{'_noisy' if noisy else ''}_seed{seed}.g2o")
    path = folder / name
    if not path.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        command = [command_path("rlpgo-generate"), "--n", str(n), "--sigma-r", f"{sigma_r:g}",
                   "--sigma-t", f"{sigma_t:g}", "--d", f"{d:g}", "--lc", f"{lc:g}",
                   "--seed", str(seed), "-o", str(path)]
        if noisy:
            command.append("--noisy-measurements")
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return path


# --- small helpers of every script ------------------------------------------------------------

def timed(function: Callable[[], Any]) -> tuple[Any, float]:
    """``function()`` and its wall seconds."""
    began = time.perf_counter()
    result = function()
    return result, time.perf_counter() - began


def collected_timed(function: Callable[[], Any]) -> tuple[Any, float]:
    """:func:`timed` after a garbage collection (an earlier row's garbage is not charged)."""
    gc.collect()
    return timed(function)


def repeated_row(parts: Callable[[], list[tuple[dict, dict]]], repeats: int,
                 others: Sequence[str], margin: float) -> dict:
    """One graph's in-process row over ``repeats`` runs of ``parts()`` (each part: figures,
    seconds): the first run's figures, the medians of the seconds; ``ours_best`` where
    ``ours_chi2`` is at most ``1 + margin`` times the lowest of the ``others`` chi2 columns,
    and ``ours_over_lowest_other``."""
    row: dict = {}
    times: dict[str, list] = {}
    for repeat in range(repeats):
        for figures, seconds in parts():
            if repeat == 0:
                row.update(figures)
            for key, value in seconds.items():
                times.setdefault(key, []).append(value)
    row.update({key: median(values) for key, values in times.items()})
    lowest = [row[key] for key in others if row.get(key) is not None]
    row["ours_best"] = bool(lowest) and row["ours_chi2"] <= min(lowest) * (1 + margin)
    row["ours_over_lowest_other"] = row["ours_chi2"] / min(lowest) - 1 if lowest else None
    return row


def chi2_cell(chi2, failure=None) -> str:
    """A chi2 cell, or why there is none."""
    if failure:
        return f"fails: {failure[:30]}"
    return cell(chi2, ".7g")


def numbers(text: str, kind=int) -> list:
    """The comma-separated numbers of a command-line value."""
    return [kind(part) for part in text.split(",") if part.strip()]


def median(values: Sequence[float | None]) -> float | None:
    """The median of the values that are not None (None if there are none)."""
    present = [v for v in values if v is not None]
    return statistics.median(present) if present else None


def scores(rejected, wrong) -> tuple[float, float]:
    """(precision, recall) of the rejected factor indices against the wrong ones."""
    rejected, wrong = set(rejected), set(wrong)
    hit = len(rejected & wrong)
    return (hit / len(rejected) if rejected else 1.0), (hit / len(wrong) if wrong else 1.0)


def cell(value, digits: str = ".2f") -> str:
    """A table cell: ``-`` for None, yes/no for a bool, else ``value`` formatted."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    return format(value, digits)


# --- processes --------------------------------------------------------------------------------

@dataclass
class Run:
    """One command run as its own process.

    Attributes:
        command: what ran.
        seconds: wall seconds from the fork to the exit (None: it could not start).
        returncode: its exit status (negative: the signal that ended it).
        timed_out: it was killed at the time limit.
        peak_mb: its peak resident set, MB (``ru_maxrss``; with the launcher's floor).
        stdout, stderr: what it printed.
        started, ended: ``time.monotonic()`` at the fork and at the exit.
        cpu_seconds: its user + system CPU seconds, its threads included.
    """

    command: list[str]
    seconds: float | None
    returncode: int
    timed_out: bool
    peak_mb: float | None
    stdout: str
    stderr: str
    started: float | None = None
    ended: float | None = None
    cpu_seconds: float | None = None

    @property
    def failure(self) -> str | None:
        """Why the run gave no result: None when it exited with status 0."""
        if self.timed_out:
            return f"timed out after {self.seconds:.0f} s"
        if self.returncode == 0:
            return None
        lines = [line for line in (self.stderr + "\n" + self.stdout).splitlines()
                 if line.strip() and not line.startswith("import time:")]
        return f"exit status {self.returncode}: " + (lines[-1].strip() if lines else "no message")


def command_path(name: str) -> str:
    """A console script of this environment (beside ``sys.executable``), else on PATH."""
    beside = Path(sys.executable).parent / name
    if beside.is_file():
        return str(beside)
    found = shutil.which(name)
    if found is None:
        raise SystemExit(f"{name} not found beside {sys.executable} nor on PATH")
    return found


@contextlib.contextmanager
def competing(busy: bool) -> Iterator[None]:
    """With ``busy``, one CPU-bound process (a Python busy loop) runs for the duration:
    started before, given half a second to be spinning, killed (by its id) after."""
    if not busy:
        yield
        return
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"],
                           stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL)
    try:
        time.sleep(0.5)
        yield
    finally:
        hog.kill()
        hog.wait()


def run(command: Sequence[str | os.PathLike[str]], timeout_s: float,
        env: dict[str, str] | None = None, python_flags: Sequence[str] = ()) -> Run:
    """Run ``command`` through the launcher (``spawn``, module docstring) and return it."""
    parts = [str(part) for part in command]
    with tempfile.TemporaryDirectory(prefix="rlpgo_run_") as folder:
        record, out, err = (Path(folder) / name for name in ("run.json", "out.txt", "err.txt"))
        launcher = [sys.executable, *python_flags, __file__, "spawn", str(record), str(out),
                    str(err), str(timeout_s), "--", *parts]
        done = subprocess.run(launcher, env=env, stdin=subprocess.DEVNULL,
                              capture_output=True, text=True, check=False)
        if done.returncode != 0 or not record.is_file():
            message = (done.stderr.strip().splitlines() or ["no message"])[-1]
            return Run(parts, None, done.returncode, False, None, "", f"launcher: {message}")
        data = json.loads(record.read_text())
        text = {path: path.read_text(errors="replace") for path in (out, err)}
    return Run(parts, data["seconds"], data["returncode"], data["timed_out"], data["peak_mb"],
               text[out], text[err], data["started"], data["ended"], data.get("cpu_seconds"))


def launcher_floor_mb() -> float | None:
    """The peak the launcher reports for a command that uses almost no memory (``true``):
    the floor under every ``peak_mb``."""
    return run(["true"], 10.0).peak_mb


def cache_bytecode() -> None:
    """Let the measured Python processes use cached bytecode, as an installed package does:
    no PYTHONDONTWRITEBYTECODE in their environment, and this checkout's modules compiled now
    into their ``__pycache__`` folders, so that no measured run compiles them (about 0.1 s
    for ``rlpgo-init``)."""
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    folders = [str(ROOT / name) for name in ("rlpgo_gtsam", "cli", "benchmarks")]
    subprocess.run([sys.executable, "-m", "compileall", "-q", *folders], check=True,
                   stdout=subprocess.DEVNULL)


def _spawn(argv: list[str]) -> int:
    record, out, err, timeout_s = argv[0], argv[1], argv[2], float(argv[3])
    command = argv[5:]  # argv[4] is "--"
    out_fd = os.open(out, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    err_fd = os.open(err, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    started = time.monotonic()
    pid = os.fork()
    if pid == 0:  # the child: its output into the files, then the command
        try:
            os.dup2(out_fd, 1)
            os.dup2(err_fd, 2)
            os.execvp(command[0], command)
        finally:
            os._exit(127)
    timed_out = []

    def stop(_signum, _frame) -> None:
        timed_out.append(True)
        os.kill(pid, signal.SIGKILL)

    signal.signal(signal.SIGALRM, stop)
    signal.setitimer(signal.ITIMER_REAL, timeout_s)
    _, status, usage = os.wait4(pid, 0)
    ended = time.monotonic()
    signal.setitimer(signal.ITIMER_REAL, 0)
    Path(record).write_text(json.dumps({
        "seconds": ended - started, "started": started, "ended": ended,
        "returncode": os.waitstatus_to_exitcode(status), "timed_out": bool(timed_out),
        "peak_mb": usage.ru_maxrss / 1024.0, "cpu_seconds": usage.ru_utime + usage.ru_stime}))
    return 0


def vmhwm_mb() -> float | None:
    """This process's peak resident set so far (VmHWM, which exec resets), MB."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


def init_outcome(stdout: str) -> dict:
    """What ``rlpgo-init``'s default printed: ``certified`` (True / False / None when it said
    nothing about it), its ``certificate:`` and ``stopped:`` lines and its last line."""
    lines = [line.strip() for line in stdout.splitlines() if line.strip()]

    def after(tag: str) -> str | None:
        return next((line.removeprefix(tag).strip() for line in lines if line.startswith(tag)),
                    None)

    certificate = after("certificate:")
    return {"certified": None if certificate is None else
            certificate.startswith("certified optimal"), "certificate": certificate,
            "stopped": after("stopped:"), "last": lines[-1] if lines else None}


def run_init(path: Path, out: Path, timeout: float, options: Sequence[str] = ()) -> dict:
    """``rlpgo-init PATH -o OUT [OPTIONS]`` as a process (OUT removed first): its seconds,
    CPU seconds, peak, failure and what it printed (:func:`init_outcome`)."""
    out.unlink(missing_ok=True)
    done = run([command_path("rlpgo-init"), path, "-o", out, *options], timeout)
    return {"seconds": done.seconds, "cpu_seconds": done.cpu_seconds, "peak_mb": done.peak_mb,
            "failure": done.failure, **init_outcome(done.stdout)}


def run_baseline(path: Path, folder: Path, sesync: str, threads: str, timeout: float,
                 busy: bool) -> dict:
    """SE-Sync + GTSAM LM30 as two processes, one after the other: the ``sesync_rounded``
    driver with BLAS at ``threads`` threads (``default``: as BLAS likes), then
    ``benchmarks/sesync/lm30.py`` writing ``folder/sesync_lm30.g2o``; with ``busy``, beside
    one competing process. The driver's own timing of the ``SESync()`` call is kept too."""
    from benchmarks.sesync.runner import THREAD_VARIABLES

    record, out = folder / "sesync.json", folder / "sesync_lm30.g2o"
    for file in (record, out):
        file.unlink(missing_ok=True)
    env = dict(os.environ)
    if threads != "default":
        env.update({name: threads for name in THREAD_VARIABLES})
    with competing(busy):
        sesync_run = run([sesync, path, record], timeout, env=env)
        lm30 = None
        if sesync_run.failure is None:
            lm30 = run([sys.executable, LM30_SCRIPT, path, record, out], timeout)
    row = {"sesync_seconds": sesync_run.seconds, "sesync_peak_mb": sesync_run.peak_mb,
           "sesync_cpu_seconds": sesync_run.cpu_seconds, "sesync_failure": sesync_run.failure}
    if sesync_run.failure is None:
        data = json.loads(record.read_text())
        row.update(sesync_call_seconds=data["seconds"], sesync_certified=data["certified"],
                   sesync_status=data["status"], sesync_bound=data["suboptimality_bound"])
    if lm30 is not None:
        row.update(lm30_seconds=lm30.seconds, lm30_peak_mb=lm30.peak_mb,
                   lm30_cpu_seconds=lm30.cpu_seconds, lm30_failure=lm30.failure)
        if lm30.failure is None:
            line = json.loads(lm30.stdout.strip().splitlines()[-1])
            row.update(lm30_chi2=line["chi2"], lm30_iterations=line["iterations"],
                       lm30_steps=line["seconds"])
    return row


def chi2_of(graph, path: Path, dim: int) -> float | None:
    """2 x GTSAM error of ``graph`` at the poses of the g2o file ``path`` (None if absent)."""
    import gtsam

    if not path.is_file():
        return None
    _, values = gtsam.readG2o(str(path), dim == 3)
    return 2.0 * graph.error(values)


def sesync_binary(given: str | None) -> str | None:
    """The SE-Sync driver: ``given`` (it must exist), else ``$RLPGO_SESYNC_BINARY``, else None."""
    from benchmarks.sesync.runner import default_binary

    if given is not None:
        if not Path(given).is_file():
            raise SystemExit(f"--sesync: {given} not found")
        return given
    found = default_binary()
    return None if found is None else str(found)


# --- anchors: GTSAM's own optimizers ----------------------------------------------------------

def _first_key(values) -> int:
    """The lowest pose key (landmarks, ``l``-symbols or not, are never the anchor)."""
    import gtsam

    poses = gtsam.utilities.allPose3s(values) if _is_spatial(values) else \
        gtsam.utilities.allPose2s(values)
    return int(min(poses.keys()))


def _is_spatial(values) -> bool:
    """Whether the values hold Pose3 (else Pose2)."""
    import gtsam

    return gtsam.utilities.allPose3s(values).size() > 0


def _pose_types(values, key: int):
    """(prior factor class, between factor class, dof, pose at key) for the values' poses."""
    import gtsam

    if _is_spatial(values):
        return gtsam.PriorFactorPose3, gtsam.BetweenFactorPose3, 6, values.atPose3(key)
    return gtsam.PriorFactorPose2, gtsam.BetweenFactorPose2, 3, values.atPose2(key)


def gtsam_lm(graph, values, iterations: int = 30) -> tuple[float | None, float, str | None]:
    """GTSAM's Levenberg-Marquardt with its default parameters, ``iterations`` at most and
    the first pose held by a constrained prior: (chi2 = 2 x the graph's error at the result,
    CPU seconds, failure or None)."""
    _, chi2, seconds, failure = gtsam_lm_result(graph, values, iterations)
    return chi2, seconds, failure


def gtsam_lm_result(graph, values, iterations: int = 30):
    """:func:`gtsam_lm` with its result: (values or None, chi2 or None, CPU seconds,
    failure or None)."""
    import gtsam

    key = _first_key(values)
    prior, _, dof, pose = _pose_types(values, key)
    fixed = gtsam.NonlinearFactorGraph(graph)
    fixed.add(prior(key, pose, gtsam.noiseModel.Constrained.All(dof)))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(iterations)
    start = time.process_time()
    try:
        result = gtsam.LevenbergMarquardtOptimizer(fixed, values, params).optimize()
    except RuntimeError as error:
        return None, None, time.process_time() - start, str(error).strip().splitlines()[0]
    return result, 2.0 * graph.error(result), time.process_time() - start, None


def gnc(graph, start, known_inliers: Sequence[int], params=None):
    """GTSAM's ``GncLMOptimizer`` (truncated least squares, inlier thresholds at probability
    0.9999) from ``start`` with ``known_inliers`` (factor indices): (values, the factor
    indices it weighs below 0.5)."""
    import gtsam
    import numpy as np

    gnc_params = gtsam.GncLMParams(params if params is not None else
                                   gtsam.LevenbergMarquardtParams())
    gnc_params.setLossType(gtsam.GncLossType.TLS)
    gnc_params.setKnownInliers(list(known_inliers))
    optimizer = gtsam.GncLMOptimizer(graph, start, gnc_params)
    optimizer.setInlierCostThresholdsAtProbability(0.9999)
    result = optimizer.optimize()
    weights = np.asarray(optimizer.getWeights(), float).ravel()
    return result, [k for k in range(graph.size()) if weights[k] < 0.5]


def dcs(graph, start, robust_factors: Sequence[int], params=None):
    """GTSAM's LM from ``start`` with the noise model of each factor of ``robust_factors``
    (between factors, by index) wrapped in the DCS m-estimator (Phi = 1), the first pose
    held by a prior of sigma 1e-8: the result's values."""
    import gtsam

    chosen = set(robust_factors)
    key = _first_key(start)
    prior, between, dof, pose = _pose_types(start, key)
    robust = gtsam.NonlinearFactorGraph()
    for k in range(graph.size()):
        factor = graph.at(k)
        if not isinstance(factor, between):
            continue
        model = factor.noiseModel()
        if k in chosen:
            model = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.DCS(1.0), model)
        i, j = factor.keys()
        robust.add(between(i, j, factor.measured(), model))
    robust.add(prior(key, pose, gtsam.noiseModel.Isotropic.Sigma(dof, 1e-8)))
    return gtsam.LevenbergMarquardtOptimizer(
        robust, start, params if params is not None else gtsam.LevenbergMarquardtParams()
    ).optimize()


def _rotation_weight(information, spatial: bool) -> float:
    """SE-Sync's rotational weight kappa of one edge: the rotation's information in 2D,
    3 / (2 tr of the rotation block's covariance) in 3D (GTSAM orders Pose3's tangent as
    rotation, then translation)."""
    import numpy as np

    if not spatial:
        return float(information[2, 2])
    return 3.0 / (2.0 * float(np.trace(np.linalg.inv(information[:3, :3]))))


def gtsam_staircase(graph, values, max_rank_step: int = 3) -> dict | None:
    """GTSAM's ``RiemannianStaircaseOptimizer`` on the rotation part of a pose graph
    (Frobenius between factors of the measured rotations, isotropic with SE-Sync's
    rotational weights), started from the values' rotations: ``certified``, ``rank``,
    ``seconds`` (its own), ``min_eigenvalue`` and ``rotations`` (key -> rotation matrix of its
    rounded estimate, turned so that the first key's equals the values'; None if it rounded
    none). None where the gtsam wheel has no such optimizer."""
    import gtsam
    import numpy as np

    if not hasattr(gtsam, "RiemannianStaircaseOptimizer"):
        return None
    spatial = _is_spatial(values)
    rot, size = ("Rot3", 9) if spatial else ("Rot2", 4)
    between = getattr(gtsam, f"FrobeniusBetweenFactor{rot}")
    pose_type = gtsam.BetweenFactorPose3 if spatial else gtsam.BetweenFactorPose2
    at = values.atPose3 if spatial else values.atPose2
    rotations, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for key in values.keys():  # the optimizer's variables are transposed rotations
        initial.insert(key, at(key).rotation().matrix().T)
    for k in range(graph.size()):
        factor = graph.at(k)
        if isinstance(factor, pose_type):
            i, j = factor.keys()
            sigma = 1.0 / np.sqrt(_rotation_weight(factor.noiseModel().information(), spatial))
            rotations.add(between(i, j, factor.measured().rotation(),
                                  gtsam.noiseModel.Isotropic.Sigma(size, sigma)))
    params = gtsam.RiemannianStaircaseParams()
    params.pMin = 3 if spatial else 2
    params.pMax = params.pMin + max_rank_step
    result = gtsam.RiemannianStaircaseOptimizer(rotations, initial, params).optimize()
    found = None
    if result.hasRoundedSolution():
        rounded = result.roundedValues()
        key0 = _first_key(values)
        turn = at(key0).rotation().matrix() @ rounded.atMatrix(key0)  # R_0 (R'_0)^T
        found = {int(k): turn @ rounded.atMatrix(k).T for k in rounded.keys()}
    return {"certified": bool(result.certified), "rank": int(result.finalRank),
            "seconds": float(result.totalTime), "min_eigenvalue": float(result.minEigenvalue),
            "rotations": found}


# GTSAM's certifiable SE(d) notebooks' settings (CertifiableLandmarkSLAMPose2/3): the highest
# rank, eta, and the augmented Lagrangian's iteration cap and initial penalty (None: its own).
_SE_STAIRCASE_SETTINGS = {2: (6, 1e-3, 100, None), 3: (7, 1e-3, 200, 300.0)}
# The same settings of GTSAM's CertifiableRangeAidedSLAMPose2/3 notebooks (the Pose3 one's
# "Run and certify" cell; its initial penalty GTSAM's own), used where a graph holds ranges.
_RANGE_STAIRCASE_SETTINGS = {2: (6, 1e-3, 200, None), 3: (12, 1e-3, 200, None)}


def gtsam_se_staircase(graph, values, round_uncertified: bool = False) -> dict | None:
    """GTSAM's ``RiemannianStaircaseOptimizer`` on the whole SE(d) problem of a pose graph,
    landmarks included, built as GTSAM's ``CertifiableLandmarkSLAMPose2/3`` notebooks build
    it: per pose edge a ``FrobeniusBetweenFactorRot<d>`` (``Isotropic.Variance(1 | 3,
    1 / kappa)``) and a ``RelativeTranslationFactor<d>`` (weight tau); per bearing-range
    factor a ``RelativeTranslationFactor<d>`` from the pose to the point variable (weight nu,
    the point in the pose's frame by :func:`rlpgo_gtsam.landmarks.relative_point`). The
    weights are SE-Sync's (:func:`_rotation_weight`; ``d / tr(Sigma)`` of the translation or
    the point). The lifted start is ``values``: ``R_i^T`` (d x d), ``t_i`` and the points as
    1 x d rows; the parameters are the notebooks' (pMin = d, pMax 6 | 7, eta 1e-3, the
    augmented Lagrangian's 100 | 200 iterations, initial penalty 300 in 3D). The rounded
    solution is turned back as the notebooks do: a global reflection undone where most
    rotation blocks have a negative determinant, each block projected onto SO(d).

    Planar ranges are built as GTSAM's ``CertifiableRangeAidedSLAMPose2`` notebook builds
    them: per ``RangeFactor2D`` (pose to point) or ``RangeFactorPose2`` (pose to pose) a
    ``QuadraticRangeFactor2(T(a), L(b) | T(b), U(m), range, nu)``, the term
    ``nu || x_b - t_a - range u_m ||^2`` with its own auxiliary direction ``U(m)``, a lifted
    ``Rot2`` whose first row is the unit direction (``nu``: the range's information); its
    start is the direction from ``a`` to ``b`` in ``values`` (``Rot2(angle).matrix().T``);
    the notebook's parameters (pMax 6, eta 1e-3, the augmented Lagrangian's 200
    iterations); after rounding, each direction is recovered from the rounded positions, as
    the notebook does. 3D ranges (``RangeFactor3D``, ``RangeFactorPose3``) as the
    ``CertifiableRangeAidedSLAMPose3`` notebook builds them: ``QuadraticRangeFactor3`` with
    a lifted ``Unit3`` direction (a 1 x p unit row) started at the unit direction from ``a``
    to ``b`` (where the notebook draws a random one), its "Run and certify" cell's pMax 12,
    eta 1e-3 and 200 iterations, each direction recovered as a ``Unit3``.

    A prior on one pose fixes only the gauge (the notebooks have none): it is left out of
    the lifted problem and the rounded estimate is moved rigidly to put that pose at the
    prior's mean, where the prior costs nothing; no other term changes under a rigid motion,
    so the optimum is the same. A second pose prior, or any other factor, is a ``failure``
    that names it.

    Returns ``certified``, ``rank``, ``ranks`` (visited), ``seconds`` (its ``totalTime``),
    ``wall_seconds`` (building the problem, the staircase and the rounding), ``min_eigenvalue``,
    ``cost`` (its cost at the last level, in its own units), ``values`` (the rounded estimate
    under ``values``' keys, Pose2/Pose3 and Point2/Point3; None where it rounded none),
    ``rounded_cost`` (the lifted graph's error at the rounded estimate, directions recovered
    from the positions, in ``cost``'s units: ``cost`` bounds it from below only where
    ``certified`` and ``violation`` is near 0; not in ``wall_seconds``), ``violation`` (the
    largest ``|Y Y^T - I|`` entry of its last point's rotation and direction blocks: the
    augmented Lagrangian's constraint violation), ``ranges`` (ranges modelled),
    ``rounded_by`` (``"gtsam"``: its ``roundedValues()``; ``"benchmark"``: with
    ``round_uncertified``, where GTSAM rounded nothing (it rounds only a certified result),
    its last lifted point projected here onto the top-d right singular subspace of its
    stacked rotation blocks, as SE-Sync rounds, then turned back as above; None: not
    rounded) and ``failure`` (a factor it does not model, or its error; None). None where
    the gtsam wheel has no such optimizer, or no quadratic range factor for the graph's
    ranges.
    """
    import gtsam
    import numpy as np

    from rlpgo_gtsam.landmarks import point_weights, relative_point

    if not hasattr(gtsam, "RiemannianStaircaseOptimizer"):
        return None
    began = time.perf_counter()
    spatial = _is_spatial(values)
    d = 3 if spatial else 2
    frobenius = getattr(gtsam, f"FrobeniusBetweenFactorRot{d}")
    relative = getattr(gtsam, f"RelativeTranslationFactor{d}")
    between, bearing_range, prior, at, point_type = (
        (gtsam.BetweenFactorPose3, gtsam.BearingRangeFactor3D, gtsam.PriorFactorPose3,
         values.atPose3, gtsam.Point3)
        if spatial else
        (gtsam.BetweenFactorPose2, gtsam.BearingRangeFactor2D, gtsam.PriorFactorPose2,
         values.atPose2, gtsam.Point2))
    poses = [int(k) for k in (gtsam.utilities.allPose3s(values) if spatial
                              else gtsam.utilities.allPose2s(values)).keys()]
    pose_index = {key: index for index, key in enumerate(poses)}
    point_index: dict[int, int] = {}
    ranges: list[tuple[int, int]] = []  # (first key, second key) per direction U(m)
    gauge: list[tuple[int, Any]] = []  # (pose key, prior mean) of the one pose prior
    range_types, pose_range = ((gtsam.RangeFactor3D, gtsam.RangeFactorPose3),
                               gtsam.RangeFactorPose3) if spatial else (
        (gtsam.RangeFactor2D, gtsam.RangeFactorPose2), gtsam.RangeFactorPose2)
    quadratic = getattr(gtsam, f"QuadraticRangeFactor{d}", None)
    lifted = gtsam.NonlinearFactorGraph()
    for k in range(graph.size()):
        factor = graph.at(k)
        if isinstance(factor, between):
            i, j = (pose_index[int(key)] for key in factor.keys())
            information = factor.noiseModel().information()
            kappa = _rotation_weight(information, spatial)
            block = information[3:, 3:] if spatial else information[:2, :2]
            tau = float(point_weights(np.array([block]))[0])
            measured = factor.measured()
            lifted.add(frobenius(gtsam.symbol("R", i), gtsam.symbol("R", j),
                                 measured.rotation(),
                                 gtsam.noiseModel.Isotropic.Variance(1 if d == 2 else 3,
                                                                     1.0 / kappa)))
            lifted.add(relative(gtsam.symbol("R", i), gtsam.symbol("T", i),
                                gtsam.symbol("T", j), np.asarray(measured.translation()), tau))
        elif isinstance(factor, bearing_range):
            pose_key, point_key = (int(key) for key in factor.keys())
            i = pose_index[pose_key]
            m = point_index.setdefault(point_key, len(point_index))
            point, information = relative_point(factor)
            nu = float(point_weights(np.array([information]))[0])
            lifted.add(relative(gtsam.symbol("R", i), gtsam.symbol("T", i),
                                gtsam.symbol("L", m), point, nu))
        elif isinstance(factor, range_types):
            if quadratic is None:
                return None
            first, second = (int(key) for key in factor.keys())
            if isinstance(factor, pose_range):
                target = gtsam.symbol("T", pose_index[second])
            else:
                target = gtsam.symbol("L", point_index.setdefault(second, len(point_index)))
            nu = float(factor.noiseModel().information()[0, 0])
            lifted.add(quadratic(
                gtsam.symbol("T", pose_index[first]), target, gtsam.symbol("U", len(ranges)),
                float(factor.measured()), nu))
            ranges.append((first, second))
        elif isinstance(factor, prior) and not gauge:
            gauge.append((int(factor.keys()[0]), factor.prior()))
        elif factor is not None:
            second_prior = " (a second pose prior)" if isinstance(factor, prior) else ""
            return {"failure": f"{type(factor).__name__} is not modelled{second_prior}"}
    initial = gtsam.Values()
    for key, i in pose_index.items():
        pose = at(key)
        initial.insert(gtsam.symbol("R", i), pose.rotation().matrix().T)
        initial.insert(gtsam.symbol("T", i), np.asarray(pose.translation()).reshape(1, d))
    for key, m in point_index.items():
        initial.insert(gtsam.symbol("L", m), _point_row(values, key, d))
    for m, (first, second) in enumerate(ranges):
        initial.insert(gtsam.symbol("U", m), _unit_direction(values, first, second, spatial)
                       .reshape(1, 3) if spatial else
                       gtsam.Rot2.fromAngle(_direction_angle(values, first, second))
                       .matrix().T)
    p_max, eta, alm_iterations, alm_penalty = (_RANGE_STAIRCASE_SETTINGS[d] if ranges else
                                               _SE_STAIRCASE_SETTINGS[d])
    alm = gtsam.AugmentedLagrangianParams()
    alm.maxIterations = alm_iterations
    if alm_penalty is not None:
        alm.bclInitialPenalty = alm_penalty
    params = gtsam.RiemannianStaircaseParams()
    params.pMin, params.pMax, params.eta = d, p_max, eta
    params.setAlmParams(alm)
    try:
        result = gtsam.RiemannianStaircaseOptimizer(lifted, initial, params).optimize()
    except RuntimeError as error:
        return {"failure": str(error).strip().splitlines()[0],
                "wall_seconds": time.perf_counter() - began}
    found, rounded_by = None, None
    if result.hasRoundedSolution():
        rounded, rounded_by = result.roundedValues(), "gtsam"
    elif round_uncertified:
        rounded, rounded_by = result.values, "benchmark"
    if rounded_by is not None:
        blocks = {key: rounded.atMatrix(gtsam.symbol("R", i)).copy()
                  for key, i in pose_index.items()}
        rows = {key: rounded.atMatrix(gtsam.symbol("T", i)).copy().ravel()
                for key, i in pose_index.items()}
        rows.update({key: rounded.atMatrix(gtsam.symbol("L", m)).copy().ravel()
                     for key, m in point_index.items()})
        if rounded_by == "benchmark":  # d x p blocks: onto their top-d right singular space
            basis = np.linalg.svd(np.vstack(list(blocks.values())),
                                  full_matrices=False)[2][:d].T
            blocks = {key: block @ basis for key, block in blocks.items()}
            rows = {key: row @ basis for key, row in rows.items()}
        if sum(np.linalg.det(block) < 0.0 for block in blocks.values()) > len(blocks) // 2:
            for block in blocks.values():  # the optimizer works over O(d)
                block[:, -1] *= -1.0
            for row in rows.values():
                row[-1] *= -1.0
        found = gtsam.Values()
        for key in pose_index:
            rotation = _nearest_rotation(blocks[key].T)
            found.insert(key, gtsam.Pose3(gtsam.Rot3(rotation), gtsam.Point3(rows[key]))
                         if spatial else
                         gtsam.Pose2(float(rows[key][0]), float(rows[key][1]),
                                     float(np.arctan2(rotation[1, 0], rotation[0, 0]))))
        for key in point_index:
            found.insert(key, point_type(rows[key]))
        if gauge:
            found = _moved_onto(found, *gauge[0], spatial)
    wall_seconds = time.perf_counter() - began
    manifold_keys = ([gtsam.symbol("R", i) for i in pose_index.values()] +
                     [gtsam.symbol("U", m) for m in range(len(ranges))])
    return {"certified": bool(result.certified), "rank": int(result.finalRank),
            "violation": _stiefel_violation(result.values, manifold_keys),
            "ranks": [int(r) for r in np.asarray(result.getRanksVisited()).ravel()],
            "seconds": float(result.totalTime), "wall_seconds": wall_seconds,
            "min_eigenvalue": float(result.minEigenvalue),
            "cost": float(np.asarray(result.getCostPerLevel()).ravel()[-1]),
            "rounded_cost": None if found is None else
            _lifted_error(lifted, found, pose_index, point_index, ranges, spatial),
            "ranges": len(ranges), "values": found, "rounded_by": rounded_by, "failure": None}


def _position(values, key: int, spatial: bool):
    """The position of a pose or a point (Pose2/Point2, or Pose3/Point3) in ``values``."""
    import numpy as np

    try:
        pose = values.atPose3(key) if spatial else values.atPose2(key)
        return np.asarray(pose.translation(), float)
    except RuntimeError:  # not a pose: a point
        return np.asarray(values.atPoint3(key) if spatial else values.atPoint2(key), float)


def _direction_angle(values, first: int, second: int) -> float:
    """The angle of the direction from the position of ``first`` to that of ``second``
    (planar poses or points) in ``values``."""
    import numpy as np

    offset = _position(values, second, False) - _position(values, first, False)
    return float(np.arctan2(offset[1], offset[0]))


def _unit_direction(values, first: int, second: int, spatial: bool = True):
    """The unit direction from ``first`` to ``second`` (3D poses or points) in ``values``
    (the x axis where they coincide)."""
    import numpy as np

    offset = _position(values, second, spatial) - _position(values, first, spatial)
    length = float(np.linalg.norm(offset))
    return offset / length if length > 0.0 else np.array([1.0, 0.0, 0.0])


def _moved_onto(found, key: int, pose, spatial: bool):
    """``found`` (poses and points) moved rigidly so that ``key`` sits at ``pose``."""
    import gtsam

    at = found.atPose3 if spatial else found.atPose2
    turn = pose.compose(at(key).inverse())
    moved = gtsam.Values()
    poses = gtsam.utilities.allPose3s(found) if spatial else gtsam.utilities.allPose2s(found)
    for pose_key in poses.keys():
        moved.insert(pose_key, turn.compose(at(pose_key)))
    point_at = found.atPoint3 if spatial else found.atPoint2
    for point_key in found.keys():
        if not moved.exists(point_key):
            moved.insert(point_key, turn.transformFrom(point_at(point_key)))
    return moved


def _stiefel_violation(lifted_values, keys) -> float | None:
    """The largest ``|Y Y^T - I|`` entry over the lifted blocks ``keys`` (rows meant to be
    orthonormal): how far the staircase's last point is from its constraints (None where
    there is none)."""
    import numpy as np

    worst = None
    for key in keys:
        if not lifted_values.exists(key):
            return None
        block = np.asarray(lifted_values.atMatrix(key), float)
        gap = float(np.abs(block @ block.T - np.eye(len(block))).max())
        worst = gap if worst is None else max(worst, gap)
    return worst


def _lifted_error(lifted, found, pose_index: dict[int, int], point_index: dict[int, int],
                  ranges: list[tuple[int, int]], spatial: bool) -> float:
    """The lifted graph's error at a rounded estimate ``found`` (poses and points under the
    graph's keys), as the range notebooks evaluate it: rotations, translations, points,
    and each range's direction from the rounded positions (``Rot2``, or ``Unit3``)."""
    import gtsam

    estimate = gtsam.Values()
    for key, i in pose_index.items():
        pose = found.atPose3(key) if spatial else found.atPose2(key)
        estimate.insert(gtsam.symbol("R", i), pose.rotation())
        estimate.insert(gtsam.symbol("T", i), pose.translation())
    for key, m in point_index.items():
        estimate.insert(gtsam.symbol("L", m),
                        found.atPoint3(key) if spatial else found.atPoint2(key))
    for m, (first, second) in enumerate(ranges):
        estimate.insert(gtsam.symbol("U", m),
                        gtsam.Unit3(_unit_direction(found, first, second)) if spatial else
                        gtsam.Rot2.fromAngle(_direction_angle(found, first, second)))
    return float(lifted.error(estimate))


def _point_row(values, key: int, d: int):
    """The point at ``key`` as a 1 x d row."""
    import numpy as np

    point = values.atPoint3(key) if d == 3 else values.atPoint2(key)
    return np.asarray(point, float).reshape(1, d)


def _nearest_rotation(matrix):
    """The rotation nearest to a square matrix (Frobenius norm)."""
    import numpy as np

    left, _, right_t = np.linalg.svd(matrix)
    turn = np.eye(len(matrix))
    turn[-1, -1] = np.linalg.det(left @ right_t)
    return left @ turn @ right_t


# --- results ----------------------------------------------------------------------------------

def command_line(argv: Sequence[str] | None = None) -> str:
    """``python benchmarks/<script> ARGS``: the command that made a result."""
    argv = list(sys.argv if argv is None else argv)
    script = Path(argv[0]).resolve()
    try:
        script_name = str(script.relative_to(ROOT))
    except ValueError:
        script_name = argv[0]
    return shlex.join(["python", script_name, *argv[1:]])


def _version(name: str) -> str | None:
    from importlib import metadata

    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def machine() -> dict:
    """What the numbers were measured on."""
    facts: dict[str, Any] = {"python": platform.python_version(), "platform": platform.platform(),
                             "processor": platform.processor() or platform.machine(),
                             "cpus": os.cpu_count()}
    for name in ("gtsam", "numpy", "scipy", "torch"):
        facts[name] = _version(name)
    if hasattr(os, "getloadavg"):
        facts["load_average"] = [round(x, 2) for x in os.getloadavg()]
    return facts


def _jsonable(value: Any) -> Any:
    """What ``json`` cannot write itself: dataclasses (a typed step, a certificate) as
    dicts, numpy scalars and arrays as numbers and lists."""
    import dataclasses

    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return dataclasses.asdict(value)
    if hasattr(value, "tolist"):
        return value.tolist()
    if hasattr(value, "item"):
        return value.item()
    if isinstance(value, set | frozenset | tuple):
        return list(value)
    return str(value)


def write_result(name: str, command: str, data: dict | None, table: str | None = None) -> Path:
    """Write ``benchmarks/results/<name>.json`` (the command, the machine, ``data``; not when
    ``data`` is None) and, given a table, ``<name>.md`` (the command, then the table); return
    the path of the first written. A rerun replaces them."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.json"
    if data is not None:
        path.write_text(json.dumps({"command": command, "machine": machine(), **data},
                                   indent=1, default=_jsonable) + "\n")
    if table is not None:
        text = RESULTS / f"{name}.md"
        text.write_text(f"Made by `{command}`.\n\n{table.rstrip()}\n")
        path = path if data is not None else text
    return path


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "spawn":
        sys.exit(_spawn(sys.argv[2:]))
    print(__doc__)
