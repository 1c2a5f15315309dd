"""Commands timed as a user runs them: one process each, its wall seconds from start to exit
and its peak memory, alone or beside a competing CPU-bound process; and ``rlpgo-init`` run
with timestamps around its phases. Shared by ``benchmarks/process.py`` and
``benchmarks/scale.py``.

Two modes run as processes of their own (this module imports only the standard library at
its top, so neither pays for anything the measured command does not):

    python benchmarks/processes.py spawn RECORD OUT ERR TIMEOUT_S -- COMMAND...
    python -X importtime benchmarks/processes.py probe RECORD -- RLPGO_INIT_ARGS...

``spawn`` is the launcher behind :func:`run`: it forks, execs COMMAND with its stdout and
stderr in the files OUT and ERR, waits for it with ``wait4`` and writes RECORD (JSON): the
wall seconds from the fork to the child's exit (the launcher's own start-up is outside
them), the exit status, and the child's peak resident set (``ru_maxrss`` of ``wait4``: the
child's alone, where ``getrusage(RUSAGE_CHILDREN)`` in a large parent or ``RUSAGE_SELF`` in
the child would report a parent's). Linux carries the forking process's high-water mark
into the child, so that peak has a floor, the launcher's own resident set;
:func:`launcher_floor_mb` measures it (about 10 MB). After TIMEOUT_S the child is killed.

``probe`` runs the ``rlpgo-init`` console script's entry point
(``rlpgo_cli.launch.init``: the code the command runs) in its own process with monotonic
timestamps around the command's steps: its imports, reading the file, extracting the pose
graph, the default (``staged_initialize``: the certified stage, GTSAM's LM, the rest), writing
the result and the input chi2 it prints; each step's time is taken by a wrapper put around
the name the command module calls, so a step that a later version calls under another name
falls into "other". The peak resident set (VmHWM) is read after each step. The probe runs
under ``-X importtime`` and marks each step's begin and end on stderr, so the modules
imported lazily (SciPy's, for instance) are attributed to the step that imported them, their
time being part of that step's. "start-up" runs from the fork to the probe's first line: it
includes this module's own standard-library imports (json, subprocess, tempfile, ...),
which the command imports anyway, so its "import" step is that much shorter than a plain
run's.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MARKER = "rlpgo-probe: "  # the probe's lines on stderr: "begin STEP", "end STEP", "end import"
# The names rlpgo_cli.init calls for each step: a step whose name is absent (a later
# version of the command) is not wrapped and its time falls into "other".
STEP_NAMES = {
    "read": ("read_input", "read_g2o", "read_g2o3d"),
    "extraction": ("extract_pose_graph", "PoseGraph2D", "PoseGraph3D"),  # classes: from_gtsam
    "default": ("staged_initialize",),
    "write": ("pose_graph_text",),  # the text; RunFiles.write_together writes it
    "input chi2": ("chi2",),
}
STEPS = ("start-up", "import", "read", "extraction", "certified", "LM", "default rest",
         "write", "input chi2", "other", "exit")
"""The phases of one ``rlpgo-init`` run, in order (see :func:`phases`)."""


@dataclass
class Run:
    """One command run as its own process.

    Attributes:
        command: what ran.
        seconds: wall seconds from the fork to the exit (None: it could not start).
        returncode: its exit status (negative: the signal that ended it).
        timed_out: it was killed at the time limit.
        peak_mb: its peak resident set, MB (ru_maxrss; with the launcher's floor).
        stdout, stderr: what it printed.
        cpu_seconds: its user + system CPU seconds (``wait4``'s, its threads included).
        started, ended: ``time.monotonic()`` at the fork and at the exit (system-wide clock).
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
    extra: dict = field(default_factory=dict)

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


def run(command: Sequence[str], timeout_s: float, env: dict[str, str] | None = None,
        python_flags: Sequence[str] = ()) -> Run:
    """Run ``command`` through the launcher (``spawn``, module docstring) and return it."""
    command = [str(part) for part in command]
    with tempfile.TemporaryDirectory(prefix="rlpgo_run_") as folder:
        record, out, err = (Path(folder) / name for name in ("run.json", "out.txt", "err.txt"))
        launcher = [sys.executable, *python_flags, __file__, "spawn", str(record), str(out),
                    str(err), str(timeout_s), "--", *command]
        done = subprocess.run(launcher, env=env, stdin=subprocess.DEVNULL,
                              capture_output=True, text=True, check=False)
        if done.returncode != 0 or not record.is_file():
            message = (done.stderr.strip().splitlines() or ["no message"])[-1]
            return Run(command, None, done.returncode, False, None, "", f"launcher: {message}")
        data = json.loads(record.read_text())
        text = {path: path.read_text(errors="replace") for path in (out, err)}
    return Run(command, data["seconds"], data["returncode"], data["timed_out"],
               data["peak_mb"], text[out], text[err], data["started"], data["ended"],
               data.get("cpu_seconds"))


def launcher_floor_mb() -> float | None:
    """The peak the launcher reports for a command that uses almost no memory (``true``):
    the floor under every ``peak_mb``."""
    return run(["true"], 10.0).peak_mb


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
    returncode = os.waitstatus_to_exitcode(status)
    Path(record).write_text(json.dumps({
        "seconds": ended - started, "started": started, "ended": ended,
        "returncode": returncode, "timed_out": bool(timed_out),
        "peak_mb": usage.ru_maxrss / 1024.0,
        "cpu_seconds": usage.ru_utime + usage.ru_stime}))
    return 0


# --- the instrumented rlpgo-init --------------------------------------------------------------

def vmhwm_mb() -> float | None:
    """This process's peak resident set so far (VmHWM), MB."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


class _Timed:
    """Wraps a callable: adds its seconds to ``seconds[step]``, notes the peak after it, and
    hands its result to ``seen`` (if given)."""

    def __init__(self, function, step: str, seconds: dict, peaks: dict, seen=None) -> None:
        self.function, self.step, self.seconds, self.peaks, self.seen = \
            function, step, seconds, peaks, seen

    def __call__(self, *args, **kwargs):
        os.write(2, f"{MARKER}begin {self.step}\n".encode())
        start = time.monotonic()
        try:
            result = self.function(*args, **kwargs)
        finally:
            self.seconds[self.step] = self.seconds.get(self.step, 0.0) + time.monotonic() - start
            self.peaks[self.step] = vmhwm_mb()
            os.write(2, f"{MARKER}end {self.step}\n".encode())
        if self.seen is not None:
            self.seen(result)
        return result


class _Extraction:
    """Stands for PoseGraph2D/3D in the command's module: ``from_gtsam`` is timed, every
    other attribute is the class's own."""

    def __init__(self, cls, timed: _Timed) -> None:
        self._cls, self.from_gtsam = cls, timed

    def __getattr__(self, name: str):
        return getattr(self._cls, name)


def _default_record(result) -> dict:
    """What the probe keeps of the default's result: its stages' seconds and how it ended."""
    rows = list(getattr(result, "rows", []))
    return {
        "certified_s": sum(getattr(r, "init_seconds", None) or 0.0 for r in rows),
        "lm_s": sum(getattr(r, "refine_seconds", None) or 0.0 for r in rows),
        "stages": [getattr(r, "method", "?") for r in rows],
        "certified": getattr(result, "certified", None),
        "stopped": getattr(result, "stopped", None),
        "library_seconds": getattr(result, "seconds", None),
    }


def _probe(argv: list[str]) -> int:
    started = time.monotonic()
    record_path, args = argv[0], argv[2:]  # argv[1] is "--"
    import importlib

    if sys.path and Path(sys.path[0]).resolve() == Path(__file__).resolve().parent:
        del sys.path[0]  # benchmarks/ is not on a user's path (it holds robust.py, ...)

    sys.argv = ["rlpgo-init", *args]
    launch = importlib.import_module("rlpgo_cli.launch")
    importer = getattr(launch, "_import", None)  # as the command imports itself
    command = importer("init", True) if importer else importlib.import_module("rlpgo_cli.init")
    imported = time.monotonic()
    os.write(2, f"{MARKER}end import\n".encode())
    seconds: dict[str, float] = {}
    peaks: dict[str, float | None] = {"import": vmhwm_mb()}
    default: dict = {}
    for step, names in STEP_NAMES.items():
        for name in names:
            original = getattr(command, name, None)
            if original is None:
                continue
            if step == "extraction" and isinstance(original, type):
                setattr(command, name, _Extraction(
                    original, _Timed(original.from_gtsam, step, seconds, peaks)))
            else:
                seen = (lambda result: default.update(_default_record(result))) \
                    if step == "default" else None
                setattr(command, name, _Timed(original, step, seconds, peaks, seen))
    files = getattr(command, "RunFiles", None)
    for method in ("write_g2o", "write_together"):
        if files is not None and hasattr(files, method):
            timed = _Timed(getattr(files, method), "write", seconds, peaks)
            setattr(files, method, lambda self, *a, _timed=timed, **k: _timed(self, *a, **k))
    main_began = time.monotonic()

    def write_record(code: object) -> None:
        record = {"started": started, "imported": imported, "main_began": main_began,
                  "main_ended": time.monotonic(), "seconds": seconds, "peaks_mb": peaks,
                  "peak_mb": vmhwm_mb(), "default": default,
                  "exit_code": code if isinstance(code, int) or code is None else 1}
        Path(record_path).write_text(json.dumps(record))

    leave = getattr(launch, "_leave", None)
    if leave is not None:  # the command ends the process itself: the record first
        def record_and_leave(code: object) -> None:
            write_record(code)
            leave(code)

        launch._leave = record_and_leave
    code: int | str | None = 0
    try:
        launch.init()
    except SystemExit as stop:
        code = stop.code
    write_record(code)
    return code if isinstance(code, int) else (0 if code is None else 1)


def imports_by_step(stderr: str) -> dict[str, list[tuple[str, float]]]:
    """The top-level ``-X importtime`` lines of a probe's stderr as (module, cumulative
    seconds), slowest first, per step: ``import`` before the marker of the eager imports,
    a step's name between its begin and end markers, ``other`` elsewhere."""
    found: dict[str, list[tuple[str, float]]] = {}
    step = "import"
    for line in stderr.splitlines():
        if line.startswith(MARKER):
            words = line[len(MARKER):].split(maxsplit=1)
            step = words[1] if words[0] == "begin" else "other"
            continue
        parts = line.split("|")
        if not line.startswith("import time:") or len(parts) != 3:
            continue
        if parts[2].startswith(" ") and not parts[2].startswith("  "):
            try:
                found.setdefault(step, []).append((parts[2].strip(), int(parts[1]) / 1e6))
            except ValueError:
                continue  # the header line
    return {key: sorted(items, key=lambda item: -item[1]) for key, items in found.items()}


def probe(args: Sequence[str], timeout_s: float) -> dict:
    """Run ``rlpgo-init ARGS`` instrumented (module docstring) and return its phases:
    ``seconds`` per step of :data:`STEPS` (None where the step was not seen), ``total`` (the
    process's wall seconds, start to exit), ``peaks_mb`` after each step, ``peak_mb``,
    ``imports`` (:func:`imports_by_step`, five a step) and ``lazy_imports_s`` (the seconds
    of the imports after the eager ones), the default's record, and ``failure`` (None if it
    exited 0)."""
    with tempfile.TemporaryDirectory(prefix="rlpgo_probe_") as folder:
        record_path = Path(folder) / "probe.json"
        done = run([sys.executable, "-X", "importtime", __file__, "probe", str(record_path),
                    "--", *args], timeout_s)
        record = json.loads(record_path.read_text()) if record_path.is_file() else None
    result = {"total": done.seconds, "peak_mb": done.peak_mb, "failure": done.failure,
              "stdout": done.stdout}
    if record is None or done.started is None:
        return {**result, "seconds": dict.fromkeys(STEPS), "peaks_mb": {}, "default": {},
                "imports": {}, "lazy_imports_s": None}
    steps = record["seconds"]
    default = record["default"]
    seconds: dict[str, float | None] = dict.fromkeys(STEPS)
    seconds["start-up"] = record["started"] - done.started
    seconds["import"] = record["imported"] - record["started"]
    for step in ("read", "extraction", "write", "input chi2"):
        seconds[step] = steps.get(step)
    if "default" in steps and default:
        seconds["certified"] = default["certified_s"]
        seconds["LM"] = default["lm_s"]
        seconds["default rest"] = steps["default"] - default["certified_s"] - default["lm_s"]
    main = record["main_ended"] - record["main_began"]
    seconds["other"] = main - sum(steps.values())
    seconds["other"] += record["main_began"] - record["imported"]  # the probe's wrapping
    seconds["exit"] = done.ended - record["main_ended"]
    imports = imports_by_step(done.stderr)
    return {**result, "seconds": seconds, "peaks_mb": record["peaks_mb"],
            "peak_mb": record["peak_mb"] or done.peak_mb, "default": default,
            "imports": {step: items[:5] for step, items in imports.items()},
            "lazy_imports_s": sum(seconds for step, items in imports.items()
                                  if step != "import" for _, seconds in items)}


# --- rlpgo-init's printed lines, generated graphs -----------------------------------------

def init_outcome(stdout: str) -> dict:
    """What ``rlpgo-init``'s default printed: ``certified`` (True / False / None when it
    said nothing about it), the ``certificate:`` line, the ``stopped:`` line and the last
    line (chi2, seconds, file written)."""
    lines = [line.strip() for line in stdout.splitlines() if line.strip()]
    certificate = next((line.removeprefix("certificate:").strip() for line in lines
                        if line.startswith("certificate:")), None)
    stopped = next((line.removeprefix("stopped:").strip() for line in lines
                    if line.startswith("stopped:")), None)
    certified = None
    if certificate is not None:
        certified = certificate.startswith("certified optimal")
    return {"certified": certified, "certificate": certificate, "stopped": stopped,
            "last": lines[-1] if lines else None}


def generated_graph(folder: Path, n: int, sigma_r: float, seed: int, *, sigma_t: float = 0.05,
                    d: float = 3.0, lc: float = 0.5, noisy: bool = True) -> Path:
    """The file ``rlpgo-generate`` writes for these settings, made once and kept in
    ``folder`` (a later call reuses it)."""
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


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "spawn":
        sys.exit(_spawn(sys.argv[2:]))
    if len(sys.argv) > 1 and sys.argv[1] == "probe":
        sys.exit(_probe(sys.argv[2:]))
    sys.exit(__doc__)
