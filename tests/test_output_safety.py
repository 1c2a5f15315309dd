"""Outputs never destroy an input or an existing file, and every failure is one clear line.

Each case runs once where its code lives: the atomic writers (:func:`write_g2o`,
:mod:`rlpgo_gtsam.files`) for bad output paths and failed writes, the commands' policy
(:class:`RunFiles`) for "the output may never be an input". Then one smoke path per command
shows that the command feeds its outputs and inputs to that policy and turns the refusal into
``Error: <message>``, exit 1, with nothing written.
"""

from __future__ import annotations

import errno
import os
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from rlpgo_cli.compare import main as compare_main
from rlpgo_cli.evaluate import main as eval_main
from rlpgo_cli.generate import main as generate_main
from rlpgo_cli.init import main as init_main
from rlpgo_cli.output import RunFiles
from rlpgo_cli.train import main as train_main

from rlpgo_gtsam import OutputError, read_g2o, write_g2o
from rlpgo_gtsam.files import write_bytes, write_text, write_together
from rlpgo_gtsam.rl.agent.checkpoint import load_model, save_model
from rlpgo_gtsam.rl.agent.networks import Actor
from rlpgo_gtsam.rl.episode import PRESETS
from rlpgo_gtsam.synthetic import generate
from tests.conftest import cli_error

REFUSED = "is an input of this run; refusing to overwrite it"
OLD = b"VERTEX_SE2 0 0 0 0\n# an existing output that must survive a failed write\n"


@pytest.fixture
def input_file(tmp_path: Path) -> Path:
    """A 40-pose generated graph written as ``tmp_path/input.g2o``."""
    sample = generate(40, 0.3, 0.05, 3.0, 0.5, np.random.default_rng(1), noisy_measurements=True)
    path = tmp_path / "input.g2o"
    write_g2o(path, sample.graph, sample.initial)
    return path


@pytest.fixture
def guard_dev(monkeypatch):
    """Make sure no write ever *replaces* something under /dev (we may be running as root)."""
    real_replace = os.replace

    def replace(src, dst, *args, **kwargs):
        if os.path.abspath(os.fspath(dst)).startswith("/dev/"):
            raise OSError(errno.EPERM, "test guard: refusing to replace a device", dst)
        return real_replace(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", replace)


def _snapshot(folder: Path) -> dict[str, bytes | None]:
    """Every entry below ``folder`` with its bytes (None for folders and links)."""
    entries = {}
    for path in sorted(folder.rglob("*")):
        key = str(path.relative_to(folder))
        entries[key] = path.read_bytes() if path.is_file() and not path.is_symlink() else None
    return entries


def _temp_files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob(".*"))


# --------------------------------------------------------------------------- bad output paths


def _directory(tmp: Path) -> Path:
    (tmp / "out").mkdir()
    (tmp / "out" / "keep.txt").write_text("keep\n")
    return tmp / "out"


def _in_a_regular_file(tmp: Path) -> Path:
    (tmp / "file.txt").write_text("a regular file\n")
    return tmp / "file.txt" / "out.g2o"


def _read_only_folder(tmp: Path) -> Path:
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        pytest.skip("running as root: folder permissions are not enforced")
    folder = tmp / "locked"
    folder.mkdir()
    (folder / "old.g2o").write_bytes(OLD)
    folder.chmod(0o500)
    return folder / "old.g2o"


def _dev_full(tmp: Path) -> Path:
    if not os.path.exists("/dev/full"):
        pytest.skip("/dev/full not available")
    return Path("/dev/full")


# (builder of the output path, what the message says after "<output>: ")
BAD_OUTPUTS = {
    "directory": (_directory, "is a directory; give a file name for the output"),
    "folder_missing": (lambda tmp: tmp / "missing" / "deeper" / "out.g2o",
                       "folder {tmp}/missing/deeper does not exist"),
    "inside_a_regular_file": (_in_a_regular_file, "{tmp}/file.txt is not a folder"),
    "name_too_long": (lambda tmp: tmp / ("y" * 252 + ".g2o"), "file name longer than 255 bytes"),
    "folder_name_too_long": (lambda tmp: tmp / ("p" * 256) / "out.g2o",
                             "a folder name in it is longer than 255 bytes"),
    "read_only_folder": (_read_only_folder, "cannot write: Permission denied"),
    "full_disk": (_dev_full, "cannot write: No space left on device"),
}


@pytest.mark.parametrize("build, reason", BAD_OUTPUTS.values(), ids=BAD_OUTPUTS.keys())
def test_write_g2o_refuses_a_bad_output_and_changes_nothing(tmp_path, input_file, guard_dev,
                                                            build, reason):
    graph, values = read_g2o(input_file)
    output = build(tmp_path)
    before = _snapshot(tmp_path)
    try:
        with pytest.raises(OutputError) as excinfo:
            write_g2o(output, graph, values)
    finally:
        if output.parent.name == "locked":
            output.parent.chmod(0o700)
    assert str(excinfo.value) == f"{output}: {reason.format(tmp=tmp_path)}"
    assert _snapshot(tmp_path) == before  # no folder made, no temporary file left


def test_the_longest_file_name_is_written(tmp_path, input_file):
    graph, values = read_g2o(input_file)
    longest = tmp_path / ("x" * 251 + ".g2o")  # 255 bytes
    write_g2o(longest, graph, values)
    assert read_g2o(longest)[1].size() == values.size()


# --------------------------------------------------------------------------- failed writes


def _fail(monkeypatch, step: str) -> None:
    """Make one step of the atomic write fail as a full or broken disk would."""
    def fail(*args, **kwargs):
        raise OSError(errno.EIO, "Input/output error")

    module, name = step.split(".")
    monkeypatch.setattr({"os": os, "tempfile": tempfile}[module], name, fail)


WRITERS: dict[str, Callable[[Path, bytes], None]] = {
    "write_bytes": write_bytes,
    "write_together": lambda path, data: write_together([(path, data)]),
}


@pytest.mark.parametrize("existing", [True, False], ids=["existing", "new"])
@pytest.mark.parametrize("step", ["tempfile.mkstemp", "os.fsync", "os.replace"])
@pytest.mark.parametrize("writer", WRITERS.values(), ids=WRITERS.keys())
def test_a_failed_write_keeps_the_existing_file(tmp_path, monkeypatch, writer, step, existing):
    output = tmp_path / "out.g2o"
    if existing:
        output.write_bytes(OLD)
    _fail(monkeypatch, step)
    with pytest.raises(OutputError) as excinfo:
        writer(output, b"new\n")
    # a temporary file that cannot be made fails the writability probe, before any data
    where = f" in {tmp_path}" if step == "tempfile.mkstemp" else ""
    assert str(excinfo.value) == f"{output}: cannot write{where}: Input/output error"
    assert _snapshot(tmp_path) == ({"out.g2o": OLD} if existing else {})  # no temporary file


def test_write_together_writes_every_file_or_none(tmp_path):
    (tmp_path / "a.txt").write_bytes(OLD)
    with pytest.raises(OutputError, match="missing/b.txt: folder .* does not exist"):
        write_together([(tmp_path / "a.txt", b"new\n"), (tmp_path / "missing" / "b.txt", b"x")])
    assert _snapshot(tmp_path) == {"a.txt": OLD}  # a.txt was staged, then dropped


@pytest.mark.parametrize("existing", [True, False], ids=["existing", "new"])
@pytest.mark.parametrize("device_first", [True, False], ids=["device_first", "device_last"])
def test_a_device_that_fails_leaves_no_file_written(tmp_path, guard_dev, device_first,
                                                      existing):
    """A device cannot be staged: it is written after the files are staged and before any is
    renamed into place, so its failure (/dev/full) leaves every file as it was."""
    device = _dev_full(tmp_path)
    if existing:
        (tmp_path / "a.txt").write_bytes(OLD)
    files = [(tmp_path / "a.txt", b"new\n"), (tmp_path / "b.json", b"{}\n")]
    items = [(device, b"x"), *files] if device_first else [*files, (device, b"x")]
    before = _snapshot(tmp_path)
    with pytest.raises(OutputError, match="^/dev/full: cannot write: No space left on device$"):
        write_together(items)
    assert _snapshot(tmp_path) == before  # no file, no temporary file, the old one kept


def _fail_replacing(monkeypatch, name: str, error: BaseException) -> None:
    """Make the rename onto the file called ``name`` fail with ``error``."""
    real_replace = os.replace

    def replace(src, dst, *args, **kwargs):
        if Path(dst).name == name and Path(src).name.startswith(".rlpgo-"):
            raise error
        return real_replace(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", replace)


@pytest.mark.parametrize("error", [OSError(errno.EIO, "Input/output error"), KeyboardInterrupt()],
                         ids=["io_error", "ctrl_c"])
def test_a_failed_rename_puts_back_the_files_already_replaced(tmp_path, monkeypatch, error):
    """The third of three renames fails: the first file gets its old bytes back (the user's
    file, given with --overwrite), the second, new, is removed; nothing else is left."""
    (tmp_path / "a.g2o").write_bytes(OLD)
    (tmp_path / "a.g2o").chmod(0o640)
    (tmp_path / "c.txt").write_bytes(b"old c\n")
    before = _snapshot(tmp_path)
    _fail_replacing(monkeypatch, "c.txt", error)
    with pytest.raises(OutputError if isinstance(error, OSError) else KeyboardInterrupt):
        write_together([(tmp_path / "a.g2o", b"new a\n"), (tmp_path / "b.json", b"{}\n"),
                        (tmp_path / "c.txt", b"new c\n")])
    assert _snapshot(tmp_path) == before
    assert (tmp_path / "a.g2o").stat().st_mode & 0o777 == 0o640
    monkeypatch.undo()
    write_together([(tmp_path / "a.g2o", b"new a\n"), (tmp_path / "c.txt", b"new c\n")])
    assert _snapshot(tmp_path) == {"a.g2o": b"new a\n", "c.txt": b"new c\n"}  # none kept


@pytest.mark.parametrize("where", ["device", "rename"])
def test_a_folder_made_for_the_files_goes_when_the_write_fails(tmp_path, monkeypatch, guard_dev,
                                                               where):
    """Folders made for a write (a plot folder and its missing parents) are removed again
    when the write fails or is interrupted; one that existed stays."""
    (tmp_path / "kept").mkdir()
    folder = tmp_path / "kept" / "new" / "plots"
    items = [(folder / "a.png", b"png"), (tmp_path / "r.json", b"{}\n")]
    if where == "device":
        items.append((_dev_full(tmp_path), b"x"))
        expected: type[BaseException] = OutputError
    else:
        _fail_replacing(monkeypatch, "r.json", KeyboardInterrupt())
        expected = KeyboardInterrupt
    before = _snapshot(tmp_path)
    with pytest.raises(expected):
        write_together(items, folders=[folder])
    assert _snapshot(tmp_path) == before


# --------------------------------------------------------------------------- successful writes


def test_write_g2o_replaces_an_existing_output(tmp_path, input_file):
    graph, values = read_g2o(input_file)
    output = tmp_path / "out.g2o"
    output.write_bytes(OLD)
    write_g2o(output, graph, values)
    assert output.read_bytes() == input_file.read_bytes()  # write -> read -> write is stable
    # the library keeps no marks of what it read: a file read may be written over
    write_g2o(output, *read_g2o(output))
    assert output.read_bytes() == input_file.read_bytes()
    assert _temp_files(tmp_path) == []


def test_write_g2o_replaces_a_symlink_not_its_target(tmp_path, input_file):
    graph, values = read_g2o(input_file)
    target = tmp_path / "target.g2o"
    target.write_bytes(OLD)
    link = tmp_path / "link.g2o"
    link.symlink_to(target)
    write_g2o(link, graph, values)
    assert target.read_bytes() == OLD
    assert not link.is_symlink() and link.read_bytes() == input_file.read_bytes()


@pytest.mark.parametrize("device", ["/dev/null", "/dev/stdout"])
def test_a_device_is_written_through_not_replaced(guard_dev, device):
    path = Path(device)
    if not path.exists():
        pytest.skip(f"{device} not available")

    def kind(p: Path) -> tuple:
        return (stat.S_IFMT(p.lstat().st_mode), os.readlink(p) if p.is_symlink() else None,
                stat.S_IFMT(p.stat().st_mode))

    before = kind(path)
    write_bytes(path, b"")  # /dev/stdout: through whatever fd 1 is (pytest's capture file)
    assert kind(path) == before  # still the same device, or the same link to it


def test_new_outputs_get_the_usual_mode_and_replaced_ones_keep_theirs(tmp_path):
    umask = os.umask(0o022)
    try:
        fresh = tmp_path / "fresh.txt"
        write_text(fresh, "x\n")
        assert fresh.stat().st_mode & 0o777 == 0o644
        kept = tmp_path / "kept.txt"
        kept.write_text("old\n")
        kept.chmod(0o640)
        write_text(kept, "new\n")
        assert kept.stat().st_mode & 0o777 == 0o640
    finally:
        os.umask(umask)


# --------------------------------------------------------------------------- output == input

# Each form builds, inside tmp_path (the current directory where it chdirs), the
# (input argument, output argument) pair naming the same file.
Form = Callable[[Path, Path, pytest.MonkeyPatch], tuple[str, str]]


def _symlink_output(tmp: Path, source: Path, mp: pytest.MonkeyPatch) -> tuple[str, str]:
    (tmp / "link.g2o").symlink_to(source)
    return str(source), str(tmp / "link.g2o")


def _symlink_input(tmp: Path, source: Path, mp: pytest.MonkeyPatch) -> tuple[str, str]:
    (tmp / "link.g2o").symlink_to(source.name)  # a relative link
    return str(tmp / "link.g2o"), str(source)


def _hard_link(tmp: Path, source: Path, mp: pytest.MonkeyPatch) -> tuple[str, str]:
    os.link(source, tmp / "hard.g2o")
    return str(source), str(tmp / "hard.g2o")


def _in(folder: str, input_arg: str, output_arg: str) -> Form:
    """A form that makes ``tmp/<folder>`` (if named), changes into it and gives the two
    arguments, ``{source}`` standing for the input's absolute path, ``{name}`` its name."""
    def form(tmp: Path, source: Path, mp: pytest.MonkeyPatch) -> tuple[str, str]:
        (tmp / "dir").mkdir()
        mp.chdir(tmp / folder)
        return (input_arg.format(source=source, name=source.name, tmp=tmp),
                output_arg.format(source=source, name=source.name, tmp=tmp))

    return form


SAME_FILE_FORMS: dict[str, Form] = {
    "same_path": _in(".", "{source}", "{source}"),
    "symlink_output": _symlink_output,
    "symlink_input": _symlink_input,
    "hard_link": _hard_link,
    "relative_output": _in(".", "{source}", "{name}"),
    "relative_input": _in(".", "{name}", "{source}"),
    "dot_slash": _in(".", "{name}", "./{name}"),
    "dot_dot": _in(".", "{source}", "./dir/../{name}"),
    "absolute_dot_dot": _in(".", "{source}", "{tmp}/dir/../{name}"),
    "parent_of_cwd": _in("dir", "{source}", "../{name}"),
}


@pytest.mark.parametrize("form", SAME_FILE_FORMS.values(), ids=SAME_FILE_FORMS.keys())
def test_a_run_refuses_an_output_that_names_an_input(tmp_path, input_file, monkeypatch, form):
    """The policy lives in the commands: RunFiles compares real files (os.path.samefile)."""
    input_arg, output_arg = form(tmp_path, input_file, monkeypatch)
    before = _snapshot(tmp_path)
    with pytest.raises(OutputError) as excinfo:
        RunFiles([input_arg]).check(output_arg)
    assert str(excinfo.value) == f"{Path(output_arg)}: {REFUSED}"
    assert _snapshot(tmp_path) == before


def test_a_run_refuses_the_same_output_twice(tmp_path):
    (tmp_path / "x").mkdir()
    with pytest.raises(OutputError, match="given as two different outputs"):
        RunFiles().check(tmp_path / "a.g2o", tmp_path / "x" / ".." / "a.g2o")


# --------------------------------------------------------------------------- each command


@pytest.fixture
def model_file(tmp_path: Path) -> Path:
    path = tmp_path / "m.zip"
    save_model(path, Actor(8), PRESETS[1], {"test_cycles": 2})
    return path


def _copy_as_png(tmp: Path, graph: Path) -> Path:
    """A g2o file named .png: its plot in ``tmp`` would be itself."""
    (tmp / "input.png").write_bytes(graph.read_bytes())
    return tmp / "input.png"


def _two_of_the_same_name(tmp: Path, graph: Path) -> list[Path]:
    for folder in ("a", "b"):
        (tmp / folder).mkdir()
        (tmp / folder / "g.g2o").write_bytes(graph.read_bytes())
    return [tmp / "a" / "g.g2o", tmp / "b" / "g.g2o"]


# (command, arguments from (tmp_path, graph, model), message from the same); every refusal
# comes before any work and leaves tmp_path as it was.
COMMAND_REFUSALS = {
    "init_graph": (init_main, lambda t, g, m: [g, "-o", t / "." / g.name],
                   lambda t, g, m: f"{t / g.name}: {REFUSED}"),
    "init_model": (init_main, lambda t, g, m: [g, "-o", m, "--method", "rl", "--model", m],
                   lambda t, g, m: f"{m}: {REFUSED}"),
    "compare_model": (compare_main, lambda t, g, m: [g, "--methods", "rl", "--model", m,
                                                     "--json", m],
                      lambda t, g, m: f"{m}: {REFUSED}"),
    "compare_plot_is_input": (compare_main,
                              lambda t, g, m: [_copy_as_png(t, g), "--methods", "chordal",
                                               "--plot", t],
                              lambda t, g, m: f"{t / 'input.png'}: {REFUSED}"),
    "compare_json_is_a_plot": (compare_main, lambda t, g, m: [g, "--methods", "chordal", "--plot",
                                                              t, "--json", t / "input.png"],
                               lambda t, g, m: f"{t / 'input.png'}: given as two different "
                                               "outputs"),
    "compare_plots_collide": (compare_main,
                              lambda t, g, m: [*_two_of_the_same_name(t, g), "--methods",
                                               "chordal", "--plot", t / "plots"],
                              lambda t, g, m: f"{t / 'plots'}: two FILES have the same name; "
                                              "their plots would overwrite each other"),
    "compare_plot_name_too_long": (compare_main, lambda t, g, m: [g, "--plot",
                                                                  t / "new" / ("p" * 256)],
                                   lambda t, g, m: f"{t / 'new' / ('p' * 256)}/input.png: a "
                                                   "folder name in it is longer than 255 bytes"),
    "eval_model": (eval_main, lambda t, g, m: ["--preset", "1", "--model", m, "--json", m,
                                               "--graphs", "1"],
                   lambda t, g, m: f"{m}: {REFUSED}"),
    "generate_twice": (generate_main, lambda t, g, m: ["-o", t / "new.g2o", "--ground-truth",
                                                       t / "new.g2o"],
                       lambda t, g, m: f"{t / 'new.g2o'}: given as two different outputs"),
    "train_name_too_long": (train_main, lambda t, g, m: ["--preset", "1", "--out",
                                                         t / "new" / ("m" * 250)],
                            lambda t, g, m: f"{t / 'new' / ('m' * 250)}.train.pt: file name "
                                            "longer than 255 bytes"),
    "train_log_is_a_folder": (train_main, lambda t, g, m: ["--preset", "1", "--out", t / "d"],
                              lambda t, g, m: f"{t / 'd.csv'}: is a directory; give a file "
                                              "name for the output"),
}


@pytest.mark.parametrize("command, arguments, message", COMMAND_REFUSALS.values(),
                         ids=COMMAND_REFUSALS.keys())
def test_each_command_refuses_a_bad_output_before_work(tmp_path, input_file, model_file,
                                                       command, arguments, message):
    (tmp_path / "d.csv").mkdir()
    args = [str(a) for a in arguments(tmp_path, input_file, model_file)]
    before = _snapshot(tmp_path)
    result = CliRunner().invoke(command, args)
    cli_error(result, message(tmp_path, input_file, model_file))
    assert _snapshot(tmp_path) == before  # inputs intact, nothing made
    load_model(model_file)  # still a model


# --------------------------------------------------------------------------- all or none


def _robust_input(tmp: Path, graph: Path) -> Path:
    """The 40-pose graph with three wrong loop closures, for --robust."""
    sample = generate(40, 0.3, 0.05, 3.0, 0.5, np.random.default_rng(1), noisy_measurements=True,
                      outliers=0.05)
    path = tmp / "wrong.g2o"
    write_g2o(path, sample.graph, sample.initial)
    return path


# (command, the input builder or None, arguments with {out} for the run's folder and {input},
# the output that fails); every other output would be written, or an existing one replaced.
ONE_FAILS = {
    "init_json": (init_main, None, ["{input}", "-o", "{out}/out.g2o", "--json", "/dev/full"]),
    "init_output": (init_main, None, ["{input}", "-o", "/dev/full", "--json", "{out}/r.json"]),
    "init_robust_list": (init_main, _robust_input,
                         ["{input}", "--robust", "-o", "{out}/out.g2o", "--json",
                          "{out}/r.json", "--outliers-out", "/dev/full"]),
    "generate_truth": (generate_main, None, ["--n", "30", "-o", "{out}/g.g2o",
                                              "--ground-truth", "/dev/full",
                                              "--outliers-out", "{out}/wrong.txt"]),
    "generate_output": (generate_main, None, ["--n", "30", "-o", "/dev/full",
                                               "--ground-truth", "{out}/gt.g2o"]),
    "compare_json": (compare_main, None, ["{input}", "--methods", "odometry,chordal", "--plot",
                                          "{out}/plots/new", "--json", "/dev/full"]),
}


@pytest.mark.parametrize("existing", [False, True], ids=["new", "overwrite"])
@pytest.mark.parametrize("command, build, arguments", ONE_FAILS.values(), ids=ONE_FAILS.keys())
def test_an_output_that_fails_leaves_every_other_as_it_was(tmp_path, input_file, guard_dev,
                                                            command, build, arguments, existing):
    """A run whose last write fails (/dev/full: a full disk) exits 1 with one line and
    leaves its folder as it was: no new file, no plot folder, an existing output (given
    with --overwrite) with its old bytes."""
    _dev_full(tmp_path)
    graph = build(tmp_path, input_file) if build else input_file
    out = tmp_path / "run"
    out.mkdir()
    args = [a.format(out=out, input=graph) for a in arguments]
    if existing:
        for arg in args:
            if arg.startswith(str(out)) and "plots" not in arg:
                Path(arg).write_bytes(OLD)
        args.append("--overwrite")
    before = _snapshot(out)
    result = CliRunner().invoke(command, args)
    assert result.exit_code == 1, result.output
    assert result.stderr == "Error: /dev/full: cannot write: No space left on device\n"
    assert _snapshot(out) == before


def _failing_method(monkeypatch) -> None:
    """Register an initializer that raises, as users register theirs."""
    from rlpgo_gtsam import initializers
    from rlpgo_gtsam.errors import SolverError
    from rlpgo_gtsam.initializers import RotationInitializer, register

    class Failing(RotationInitializer):
        def rotations(self, pose_graph, start=None):
            raise SolverError("indeterminate on purpose")

    monkeypatch.setattr(initializers, "_REGISTRY", dict(initializers._REGISTRY))
    register("failing", Failing)


def test_a_compare_that_fails_writes_nothing(tmp_path, input_file, monkeypatch):
    """One method fails: the run exits 1, and neither its plot (nor the folder for it) nor
    its JSON is written; an existing JSON keeps its bytes."""
    _failing_method(monkeypatch)
    (tmp_path / "r.json").write_bytes(OLD)
    before = _snapshot(tmp_path)
    result = CliRunner().invoke(compare_main, [
        str(input_file), "--methods", "odometry,failing", "--plot", str(tmp_path / "p" / "q"),
        "--json", str(tmp_path / "r.json"), "--overwrite"])
    assert result.exit_code == 1
    assert result.stderr == ("Error: at least one method failed (see FAILED above) (nothing "
                             "written)\n")
    assert "FAILED: " in result.stdout
    assert _snapshot(tmp_path) == before


def test_an_interrupted_compare_leaves_no_plot_folder(tmp_path, input_file, monkeypatch):
    """Ctrl-C during the methods: exit 130, and the plot folder (made only with the files)
    does not exist."""
    import rlpgo_cli.compare as compare_module

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(compare_module, "compare_methods", interrupted)
    before = _snapshot(tmp_path)
    result = CliRunner().invoke(compare_main, [str(input_file), "--methods", "odometry",
                                               "--plot", str(tmp_path / "plots"),
                                               "--json", str(tmp_path / "r.json")])
    assert result.exit_code == 130 and result.stderr == "Error: interrupted\n"
    assert _snapshot(tmp_path) == before


def test_a_plot_folder_is_made_with_its_files(tmp_path, input_file):
    """The folder that --plot names, and its missing parents, appear with the PNG."""
    result = CliRunner().invoke(compare_main, [str(input_file), "--methods", "odometry",
                                               "--plot", str(tmp_path / "a" / "b")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "a" / "b" / "input.png").read_bytes()[:4] == b"\x89PNG"
    assert _temp_files(tmp_path) == []


def test_a_plot_folder_that_cannot_be_made_is_refused_before_work(tmp_path, input_file):
    """A plot folder below a file, or in a folder that cannot be written, is refused before
    any method runs."""
    (tmp_path / "file").write_text("x\n")
    result = CliRunner().invoke(compare_main, [str(input_file), "--methods", "odometry",
                                               "--plot", str(tmp_path / "file" / "plots")])
    cli_error(result, f"{tmp_path / 'file' / 'plots'}: {tmp_path / 'file'} is not a folder")
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        return  # root writes in any folder
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    try:
        result = CliRunner().invoke(compare_main, [str(input_file), "--methods", "odometry",
                                                   "--plot", str(locked / "new" / "plots")])
    finally:
        locked.chmod(0o700)
    cli_error(result, f"{locked / 'new' / 'plots'}: cannot make a folder in {locked}: "
              "Permission denied")


def test_a_device_may_take_several_outputs(tmp_path, input_file, guard_dev):
    """-o /dev/null --json /dev/null discards both (a file named twice is refused above)."""
    if not os.path.exists("/dev/null"):
        pytest.skip("/dev/null not available")
    before = _snapshot(tmp_path)
    result = CliRunner().invoke(init_main, [str(input_file), "-o", "/dev/null", "--json",
                                            "/dev/null", "--method", "odometry"])
    assert result.exit_code == 0, result.output
    assert _snapshot(tmp_path) == before
