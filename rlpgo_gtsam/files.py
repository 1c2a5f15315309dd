"""Safe output files: written to a temporary file beside the target, then renamed over it."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from rlpgo_gtsam.errors import OutputError

__all__ = ["write_text", "write_bytes", "remember_input", "is_input", "check_output"]

# Files this process has read as inputs: (device, inode) -> the path they were read from.
# Outputs never replace them, whatever path (symlink, relative, hard link) names them.
_inputs: dict[tuple[int, int], str] = {}


def remember_input(path: str | os.PathLike[str]) -> None:
    """Mark ``path`` as an input of this run; :func:`write_text` will refuse to replace it."""
    stat = Path(path).stat()
    _inputs[(stat.st_dev, stat.st_ino)] = os.path.abspath(path)


def is_input(path: str | os.PathLike[str]) -> bool:
    """True if ``path`` (through any symlink or relative form) is a remembered input.

    An input deleted since it was read no longer counts, even if a new file reuses its inode.
    """
    try:
        stat = Path(path).stat()
    except OSError:
        return False
    source = _inputs.get((stat.st_dev, stat.st_ino))
    if source is None:
        return False
    try:
        return os.path.samefile(source, path)
    except OSError:
        return False


def check_output(path: str | os.PathLike[str]) -> None:
    """Raise :class:`OutputError` now if ``path`` could not be written safely later."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path}: is a directory; give a file name for the output")
    if is_input(path):
        raise OutputError(f"{path}: is an input of this run; refusing to overwrite it")
    folder = path.parent
    if not folder.exists():
        raise OutputError(f"{path}: folder {folder} does not exist")
    if not folder.is_dir():
        raise OutputError(f"{path}: {folder} is not a folder")


def write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically: see :func:`write_bytes`."""
    write_bytes(path, text.encode("utf-8"))


def write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically; an existing file is untouched on any failure.

    A device or pipe (``/dev/null``, ``/dev/full``) is written through, since it cannot be
    replaced.

    Raises:
        OutputError: ``path`` is an input of this run, a directory, or cannot be written.
    """
    path = Path(path)
    check_output(path)
    if path.exists() and not path.is_file():
        _write_through(path, data)
    else:
        _write_atomic(path, data)


def _write_through(path: Path, data: bytes) -> None:
    try:
        with path.open("wb") as handle:
            handle.write(data)
    except OSError as error:
        raise OutputError(f"{path}: cannot write: {error.strerror or error}") from None


def _write_atomic(path: Path, data: bytes) -> None:
    folder = path.parent
    temp_name = None
    try:
        descriptor, temp_name = tempfile.mkstemp(prefix=f".{path.name}.", dir=folder)
        os.chmod(temp_name, _mode_for(path))  # mkstemp's 0600 is not what users expect
        with os.fdopen(descriptor, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(temp_name, path)
        temp_name = None
    except OSError as error:
        raise OutputError(f"{path}: cannot write: {error.strerror or error}") from None
    finally:
        if temp_name is not None:
            Path(temp_name).unlink(missing_ok=True)


def _mode_for(path: Path) -> int:
    """The mode a replaced file keeps, or a new file's usual mode under the umask."""
    try:
        return path.stat().st_mode & 0o7777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask
