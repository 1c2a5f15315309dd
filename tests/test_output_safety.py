"""Outputs never destroy an input or an existing file, and every failure is one clear line.

Covered: ``rlpgo-init`` and ``rlpgo-generate`` (through click's CliRunner) and
:func:`write_g2o` directly. For the CLIs a failed write must give exit code 1, exactly one
``Error: ...`` line on stderr, nothing on stdout and no traceback; the input and any file
already at the output path must keep their bytes, and no temporary file (``.rlpgo-*.tmp``) may
be left beside the output.
"""

from __future__ import annotations

import errno
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result
from rlpgo_cli.generate import main as generate_main
from rlpgo_cli.init import main as init_main
from rlpgo_cli.output import RunFiles

from rlpgo_gtsam import OutputError, read_g2o, write_g2o
from rlpgo_gtsam.synthetic import generate

REFUSED = "is an input of this run; refusing to overwrite it"


# --------------------------------------------------------------------------- helpers


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


def _dev_full() -> str:
    if not os.path.exists("/dev/full"):
        pytest.skip("/dev/full not available")
    return "/dev/full"


def _skip_if_root() -> None:
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        pytest.skip("running as root: folder permissions are not enforced")


def run_init(input_path: str | Path, output: str | Path, *extra: str) -> Result:
    """rlpgo-init with a fast classical method (no model needed)."""
    return CliRunner().invoke(
        init_main, [str(input_path), "-o", str(output), "--method", "chordal",
                    "--refine", "none", *extra]
    )


def run_generate(output: str | Path, *extra: str) -> Result:
    return CliRunner().invoke(
        generate_main, ["--n", "40", "--seed", "1", "--noisy-measurements", "-o", str(output),
                        *extra]
    )


def _snapshot(folder: Path) -> dict[str, bytes | None]:
    """Every entry below ``folder`` with its bytes (None for folders and links)."""
    entries = {}
    for path in sorted(folder.rglob("*")):
        key = str(path.relative_to(folder))
        entries[key] = path.read_bytes() if path.is_file() and not path.is_symlink() else None
    return entries


def _temp_files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob(".*"))


def assert_clean_failure(result: Result, message: str | None = None) -> str:
    """Exit 1, one ``Error: ...`` line on stderr, empty stdout, no traceback; returns it."""
    # CliRunner swallows an uncaught exception: it would be a traceback in a real run.
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(
        result.exception
    )
    assert "Traceback" not in result.output + result.stderr
    assert result.exit_code == 1, (result.exit_code, result.output)
    assert result.stdout == ""
    assert result.stderr.startswith("Error: ") and result.stderr.endswith("\n")
    assert result.stderr.count("\n") == 1, result.stderr
    if message is not None:
        assert result.stderr == f"Error: {message}\n"
    return result.stderr[len("Error: "):-1]


# --------------------------------------------------------------------------- output == input

# Each form builds, inside tmp_path (the current directory where it chdirs), the
# (input argument, output argument) pair naming the same file.
Form = Callable[[Path, Path, pytest.MonkeyPatch], tuple[str, str]]


def _same_path(tmp: Path, source: Path, mp: pytest.MonkeyPatch) -> tuple[str, str]:
    return str(source), str(source)


def _symlink_output(tmp: Path, source: Path, mp: pytest.MonkeyPatch) -> tuple[str, str]:
    (tmp / "link.g2o").symlink_to(source)
    return str(source), str(tmp / "link.g2o")


def _symlink_input(tmp: Path, source: Path, mp: pytest.MonkeyPatch) -> tuple[str, str]:
    (tmp / "link.g2o").symlink_to(source.name)  # a relative link
    return str(tmp / "link.g2o"), str(source)


def _hard_link(tmp: Path, source: Path, mp: pytest.MonkeyPatch) -> tuple[str, str]:
    os.link(source, tmp / "hard.g2o")
    return str(source), str(tmp / "hard.g2o")


def _relative(tmp: Path, source: Path, mp: pytest.MonkeyPatch) -> tuple[str, str]:
    mp.chdir(tmp)
    return str(source), source.name


def _relative_input(tmp: Path, source: Path, mp: pytest.MonkeyPatch) -> tuple[str, str]:
    mp.chdir(tmp)
    return source.name, str(source)


def _dot_slash(tmp: Path, source: Path, mp: pytest.MonkeyPatch) -> tuple[str, str]:
    mp.chdir(tmp)
    return source.name, f"./{source.name}"


def _dot_dot(tmp: Path, source: Path, mp: pytest.MonkeyPatch) -> tuple[str, str]:
    (tmp / "dir").mkdir()
    mp.chdir(tmp)
    return str(source), f"./dir/../{source.name}"


def _absolute_dot_dot(tmp: Path, source: Path, mp: pytest.MonkeyPatch) -> tuple[str, str]:
    (tmp / "dir").mkdir()
    return str(source), f"{tmp}/dir/../{source.name}"


def _from_subfolder(tmp: Path, source: Path, mp: pytest.MonkeyPatch) -> tuple[str, str]:
    (tmp / "dir").mkdir()
    mp.chdir(tmp / "dir")
    return str(source), f"../{source.name}"


SAME_FILE_FORMS = {
    "same_path": _same_path,
    "symlink_output": _symlink_output,
    "symlink_input": _symlink_input,
    "hard_link": _hard_link,
    "relative_output": _relative,
    "relative_input": _relative_input,
    "dot_slash": _dot_slash,
    "dot_dot": _dot_dot,
    "absolute_dot_dot": _absolute_dot_dot,
    "parent_of_cwd": _from_subfolder,
}


def _shown(output: str) -> str:
    # The CLIs take -o as a pathlib.Path, which drops a leading "./" (and nothing else):
    # "./dir/../input.g2o" is reported as "dir/../input.g2o".
    return str(Path(output))


@pytest.mark.parametrize("form", SAME_FILE_FORMS.values(), ids=SAME_FILE_FORMS.keys())
def test_init_refuses_to_overwrite_its_input(tmp_path, input_file, monkeypatch, form):
    input_arg, output_arg = form(tmp_path, input_file, monkeypatch)
    before = _snapshot(tmp_path)
    result = run_init(input_arg, output_arg)
    assert_clean_failure(result, f"{_shown(output_arg)}: {REFUSED}")
    assert _snapshot(tmp_path) == before  # input bytes kept, no temp file, links intact
    assert (tmp_path / "input.g2o").is_file() and not (tmp_path / "input.g2o").is_symlink()


@pytest.mark.parametrize("form", SAME_FILE_FORMS.values(), ids=SAME_FILE_FORMS.keys())
def test_a_run_refuses_an_output_that_names_an_input(tmp_path, input_file, monkeypatch, form):
    """The policy lives in the commands: RunFiles compares real files (os.path.samefile)."""
    input_arg, output_arg = form(tmp_path, input_file, monkeypatch)
    before = _snapshot(tmp_path)
    with pytest.raises(OutputError) as excinfo:
        RunFiles([input_arg]).check(output_arg)
    assert str(excinfo.value) == f"{Path(output_arg)}: {REFUSED}"
    assert _snapshot(tmp_path) == before


def test_the_library_writer_has_no_process_wide_input_marks(tmp_path, input_file):
    graph, values = read_g2o(input_file)
    copy = tmp_path / "copy.g2o"
    write_g2o(copy, graph, values)  # reading a file does not make it unwritable for the API
    graph2, _ = read_g2o(copy)
    write_g2o(copy, graph2, values)
    assert read_g2o(copy)[1].size() == values.size()


def test_generate_refuses_the_same_path_twice(tmp_path):
    result = run_generate(tmp_path / "graph.g2o", "--ground-truth", str(tmp_path / "graph.g2o"))
    assert_clean_failure(result, f"{tmp_path / 'graph.g2o'}: given as two different outputs")
    assert not (tmp_path / "graph.g2o").exists()


# --------------------------------------------------------------------------- bad output paths


def test_init_output_is_a_directory(tmp_path, input_file):
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "keep.txt").write_text("keep\n")
    before = _snapshot(tmp_path)
    result = run_init(input_file, folder)
    assert_clean_failure(result, f"{folder}: is a directory; give a file name for the output")
    assert _snapshot(tmp_path) == before


def test_generate_output_is_a_directory(tmp_path):
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "keep.txt").write_text("keep\n")
    before = _snapshot(tmp_path)
    result = run_generate(folder)
    assert_clean_failure(result, f"{folder}: is a directory; give a file name for the output")
    assert _snapshot(tmp_path) == before


def test_write_g2o_output_is_a_directory(tmp_path, input_file):
    graph, values = read_g2o(input_file)
    folder = tmp_path / "out"
    folder.mkdir()
    before = _snapshot(tmp_path)
    with pytest.raises(OutputError, match="is a directory"):
        write_g2o(folder, graph, values)
    assert _snapshot(tmp_path) == before


def _check_missing_folder(message: str, output: Path) -> None:
    assert message.startswith(f"{output}: ")
    assert "does not exist" in message or "No such file or directory" in message


def test_init_output_folder_missing(tmp_path, input_file):
    output = tmp_path / "missing" / "out.g2o"
    before = _snapshot(tmp_path)
    _check_missing_folder(assert_clean_failure(run_init(input_file, output)), output)
    assert _snapshot(tmp_path) == before  # the folder is not created either


def test_generate_output_folder_missing(tmp_path):
    output = tmp_path / "missing" / "deeper" / "out.g2o"
    _check_missing_folder(assert_clean_failure(run_generate(output)), output)
    assert list(tmp_path.iterdir()) == []


def test_write_g2o_output_folder_missing(tmp_path, input_file):
    graph, values = read_g2o(input_file)
    output = tmp_path / "missing" / "out.g2o"
    with pytest.raises(OutputError) as excinfo:
        write_g2o(output, graph, values)
    _check_missing_folder(str(excinfo.value), output)
    assert not (tmp_path / "missing").exists()


def _check_not_a_folder(message: str, output: Path) -> None:
    """The message must say that the parent is a file, not that it does not exist."""
    assert message.startswith(f"{output}: ")
    assert "does not exist" not in message
    assert "not a folder" in message or "not a directory" in message.lower()


def _regular_file(tmp_path: Path) -> Path:
    blocker = tmp_path / "file.txt"
    blocker.write_text("a regular file\n")
    return blocker


def test_init_output_inside_a_regular_file(tmp_path, input_file):
    output = _regular_file(tmp_path) / "out.g2o"
    before = _snapshot(tmp_path)
    result = run_init(input_file, output)
    assert _snapshot(tmp_path) == before
    _check_not_a_folder(assert_clean_failure(result), output)


def test_generate_output_inside_a_regular_file(tmp_path):
    output = _regular_file(tmp_path) / "out.g2o"
    before = _snapshot(tmp_path)
    result = run_generate(output)
    assert _snapshot(tmp_path) == before
    _check_not_a_folder(assert_clean_failure(result), output)


def test_write_g2o_output_inside_a_regular_file(tmp_path, input_file):
    graph, values = read_g2o(input_file)
    output = _regular_file(tmp_path) / "out.g2o"
    with pytest.raises(OutputError) as excinfo:
        write_g2o(output, graph, values)
    assert (tmp_path / "file.txt").read_text() == "a regular file\n"
    _check_not_a_folder(str(excinfo.value), output)


def test_output_inside_a_regular_file_is_still_one_clean_line(tmp_path, input_file):
    """Whatever the wording, this failure is already clean: one line, exit 1, file kept."""
    output = _regular_file(tmp_path) / "out.g2o"
    before = _snapshot(tmp_path)
    for result in (run_init(input_file, output), run_generate(output)):
        assert assert_clean_failure(result).startswith(f"{output}: ")
    assert _snapshot(tmp_path) == before


@pytest.fixture
def read_only_folder(tmp_path):
    _skip_if_root()
    folder = tmp_path / "locked"
    folder.mkdir()
    (folder / "old.g2o").write_text("old\n")
    folder.chmod(0o500)
    yield folder
    folder.chmod(0o700)


def _check_permission(message: str, output: Path) -> None:
    assert message.startswith(f"{output}: ")
    assert "Permission denied" in message or "permission denied" in message


def test_init_unwritable_folder(read_only_folder, input_file):
    for name in ("new.g2o", "old.g2o"):
        output = read_only_folder / name
        _check_permission(assert_clean_failure(run_init(input_file, output)), output)
    assert sorted(p.name for p in read_only_folder.iterdir()) == ["old.g2o"]
    assert (read_only_folder / "old.g2o").read_text() == "old\n"


def test_generate_unwritable_folder(read_only_folder):
    output = read_only_folder / "new.g2o"
    _check_permission(assert_clean_failure(run_generate(output)), output)
    assert sorted(p.name for p in read_only_folder.iterdir()) == ["old.g2o"]


def test_write_g2o_unwritable_folder(read_only_folder, input_file):
    graph, values = read_g2o(input_file)
    output = read_only_folder / "old.g2o"
    with pytest.raises(OutputError) as excinfo:
        write_g2o(output, graph, values)
    _check_permission(str(excinfo.value), output)
    assert (read_only_folder / "old.g2o").read_text() == "old\n"


def test_init_permission_denied_simulated(tmp_path, input_file, monkeypatch):
    """The same failure where root cannot see it: the temporary file cannot be created."""
    import tempfile

    def denied(*args, dir=None, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", dir)

    monkeypatch.setattr(tempfile, "mkstemp", denied)
    output = tmp_path / "out.g2o"
    output.write_bytes(OLD)
    _check_permission(assert_clean_failure(run_init(input_file, output)), output)
    assert output.read_bytes() == OLD


def _check_full(message: str) -> None:
    assert message.startswith("/dev/full: ")
    assert "No space left on device" in message


def test_init_full_disk(input_file, guard_dev):
    before = input_file.read_bytes()
    _check_full(assert_clean_failure(run_init(input_file, _dev_full())))
    assert input_file.read_bytes() == before


def test_generate_full_disk(guard_dev):
    _check_full(assert_clean_failure(run_generate(_dev_full())))


def test_generate_full_disk_for_ground_truth(tmp_path, guard_dev):
    result = run_generate(tmp_path / "graph.g2o", "--ground-truth", _dev_full())
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert result.exit_code == 1
    assert "Traceback" not in result.output
    assert result.stderr.count("\n") == 1
    _check_full(result.stderr.removeprefix("Error: ").rstrip("\n"))


def test_write_g2o_full_disk(input_file, guard_dev):
    graph, values = read_g2o(input_file)
    with pytest.raises(OutputError) as excinfo:
        write_g2o(_dev_full(), graph, values)
    _check_full(str(excinfo.value))
    assert "\n" not in str(excinfo.value)


def test_write_g2o_writes_through_dev_null(input_file, guard_dev):
    if not os.path.exists("/dev/null"):
        pytest.skip("/dev/null not available")
    graph, values = read_g2o(input_file)
    write_g2o("/dev/null", graph, values)
    assert not Path("/dev/null").is_file()


# --------------------------------------------------------------------------- failed writes

OLD = b"VERTEX_SE2 0 0 0 0\n# an existing output that must survive a failed write\n"


def _fail(monkeypatch, name: str) -> None:
    def fail(*args, **kwargs):
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(os, name, fail)


@pytest.mark.parametrize("step", ["replace", "fsync"])
def test_write_g2o_failure_keeps_the_existing_file(tmp_path, input_file, monkeypatch, step):
    graph, values = read_g2o(input_file)
    folder = tmp_path / "outputs"
    folder.mkdir()
    output = folder / "out.g2o"
    output.write_bytes(OLD)
    _fail(monkeypatch, step)
    with pytest.raises(OutputError) as excinfo:
        write_g2o(output, graph, values)
    assert str(excinfo.value) == f"{output}: cannot write: Input/output error"
    assert output.read_bytes() == OLD
    assert sorted(p.name for p in folder.iterdir()) == ["out.g2o"]  # no temporary file left


def test_write_g2o_failure_creates_nothing(tmp_path, input_file, monkeypatch):
    graph, values = read_g2o(input_file)
    folder = tmp_path / "outputs"
    folder.mkdir()
    _fail(monkeypatch, "replace")
    with pytest.raises(OutputError):
        write_g2o(folder / "out.g2o", graph, values)
    assert list(folder.iterdir()) == []


def test_init_failed_write_keeps_the_existing_output(tmp_path, input_file, monkeypatch):
    output = tmp_path / "out.g2o"
    output.write_bytes(OLD)
    _fail(monkeypatch, "replace")
    message = assert_clean_failure(run_init(input_file, output))
    assert message == f"{output}: cannot write: Input/output error"
    assert output.read_bytes() == OLD
    assert _temp_files(tmp_path) == []


def test_generate_failed_write_keeps_the_existing_output(tmp_path, monkeypatch):
    output = tmp_path / "out.g2o"
    output.write_bytes(OLD)
    _fail(monkeypatch, "replace")
    message = assert_clean_failure(run_generate(output))
    assert message == f"{output}: cannot write: Input/output error"
    assert output.read_bytes() == OLD
    assert _temp_files(tmp_path) == []


# --------------------------------------------------------------------------- successful replacement


def test_init_replaces_an_existing_output(tmp_path, input_file):
    output = tmp_path / "out.g2o"
    output.write_bytes(OLD)
    result = run_init(input_file, output)
    assert result.exit_code == 0, result.output
    assert output.read_bytes() != OLD
    graph, values = read_g2o(output)
    assert values.size() == 40
    assert _temp_files(tmp_path) == []


def test_generate_replaces_an_existing_output(tmp_path):
    output = tmp_path / "out.g2o"
    output.write_bytes(OLD)
    result = run_generate(output)
    assert result.exit_code == 0, result.output
    assert read_g2o(output)[1].size() == 40
    assert _temp_files(tmp_path) == []


def test_write_g2o_replaces_an_existing_output(tmp_path, input_file):
    graph, values = read_g2o(input_file)
    output = tmp_path / "out.g2o"
    output.write_bytes(OLD)
    write_g2o(output, graph, values)
    assert output.read_bytes() == input_file.read_bytes()  # write -> read -> write is stable
    assert _temp_files(tmp_path) == []


def test_write_g2o_replaces_a_symlink_not_its_target(tmp_path, input_file):
    """An output symlink to a non-input file: the link is replaced, the target kept."""
    graph, values = read_g2o(input_file)
    target = tmp_path / "target.g2o"
    target.write_bytes(OLD)
    link = tmp_path / "link.g2o"
    link.symlink_to(target)
    write_g2o(link, graph, values)
    assert target.read_bytes() == OLD
    assert not link.is_symlink() and link.read_bytes() == input_file.read_bytes()


def test_new_outputs_get_the_usual_mode_and_replaced_ones_keep_theirs(tmp_path):
    from rlpgo_gtsam.files import write_text

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
