"""Atomic output files: written to a temporary file beside the target, then renamed over it.

The library only writes safely; which paths a command may write (never one of its inputs)
is the command's policy (``rlpgo_cli.output``).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from pathlib import Path

from rlpgo_gtsam.errors import OutputError

__all__ = ["write_text", "write_bytes", "write_together", "check_output", "check_name"]

_LONGEST_NAME = 255  # bytes: the usual file-name limit (ext4, xfs, btrfs)


def check_name(path: str | os.PathLike[str]) -> None:
    """Raise :class:`OutputError` if the name of ``path``, or of a folder on the way to it,
    is longer than the usual file-system limit (255 bytes)."""
    path = Path(path)
    if len(os.fsencode(path.name)) > _LONGEST_NAME:
        raise OutputError(f"{path}: file name longer than {_LONGEST_NAME} bytes")
    if any(len(os.fsencode(part)) > _LONGEST_NAME for part in path.parent.parts):
        raise OutputError(f"{path}: a folder name in it is longer than {_LONGEST_NAME} bytes")


def check_output(path: str | os.PathLike[str]) -> None:
    """Raise :class:`OutputError` now if ``path`` could not be written later."""
    path = Path(path)
    check_name(path)
    if path.is_dir():
        raise OutputError(f"{path}: is a directory; give a file name for the output")
    folder = path.parent
    if not folder.exists():
        raise OutputError(f"{path}: folder {folder} does not exist")
    if not folder.is_dir():
        raise OutputError(f"{path}: {folder} is not a folder")
    if not _is_stream(path):
        _probe(folder, path)


def _probe(folder: Path, path: Path) -> None:
    """Create and remove a temporary file in ``folder``: the one test of writability that
    holds for every user (root included) and file system (read-only mounts included)."""
    try:
        descriptor, temp_name = tempfile.mkstemp(prefix=".rlpgo-", suffix=".tmp", dir=folder)
    except OSError as error:
        raise OutputError(f"{path}: cannot write in {folder}: "
                          f"{error.strerror or error}") from None
    os.close(descriptor)
    Path(temp_name).unlink(missing_ok=True)


def write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically: see :func:`write_bytes`."""
    write_bytes(path, text.encode("utf-8"))


def write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically; an existing file is untouched on any failure.

    A device or pipe (``/dev/null``, ``/dev/full``) is written through, since it cannot be
    replaced.

    Raises:
        OutputError: ``path`` is a directory or cannot be written.
    """
    path = Path(path)
    check_output(path)
    if _is_stream(path):
        _write_through(path, data)
    else:
        _write_atomic(path, data)


def _is_stream(path: Path) -> bool:
    """A device, pipe or /dev, /proc name (``/dev/stdout`` is a symlink to /proc/self/fd/1,
    which may point at a regular file: replacing it would replace the symlink)."""
    if path.exists() and not path.is_file():
        return True
    resolved = str(path.resolve())
    return resolved.startswith(("/dev/", "/proc/")) or str(path.absolute()).startswith(
        ("/dev/", "/proc/"))


def write_together(items: Sequence[tuple[str | os.PathLike[str], bytes]]) -> None:
    """Write several files so that either every regular file is replaced or none is.

    Every regular file's data is first written and synced to a temporary file beside it;
    only when all of them succeeded are they renamed over their targets. A device or pipe
    among the targets (``/dev/null``) is written through after that.

    Raises:
        OutputError: a target is a directory, or cannot be written.
    """
    staged: list[tuple[str, Path]] = []
    through: list[tuple[Path, bytes]] = []
    try:
        for path, data in items:
            path = Path(path)
            check_output(path)
            if _is_stream(path):
                through.append((path, data))
            else:
                staged.append((_stage(path, data), path))
        while staged:
            temp_name, path = staged[0]
            try:
                os.replace(temp_name, path)
            except OSError as error:
                raise OutputError(f"{path}: cannot write: {error.strerror or error}") from None
            staged.pop(0)
    finally:
        for temp_name, _ in staged:
            Path(temp_name).unlink(missing_ok=True)
    for path, data in through:
        _write_through(path, data)


def _stage(path: Path, data: bytes) -> str:
    """A synced temporary file beside ``path`` holding ``data``; returns its name."""
    try:
        # A short temporary name: one derived from a 250-byte output name would be too long.
        descriptor, temp_name = tempfile.mkstemp(prefix=".rlpgo-", suffix=".tmp",
                                                 dir=path.parent)
    except OSError as error:
        raise OutputError(f"{path}: cannot write: {error.strerror or error}") from None
    try:
        os.chmod(temp_name, _mode_for(path))  # mkstemp's 0600 is not what users expect
        with os.fdopen(descriptor, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
    except OSError as error:
        Path(temp_name).unlink(missing_ok=True)
        raise OutputError(f"{path}: cannot write: {error.strerror or error}") from None
    except BaseException:  # Ctrl-C or a signal raised as an exception: leave nothing behind
        Path(temp_name).unlink(missing_ok=True)
        raise
    return temp_name


def _write_through(path: Path, data: bytes) -> None:
    try:
        with path.open("wb") as handle:
            handle.write(data)
    except OSError as error:
        raise OutputError(f"{path}: cannot write: {error.strerror or error}") from None


def _write_atomic(path: Path, data: bytes) -> None:
    temp_name = _stage(path, data)
    try:
        os.replace(temp_name, path)
    except OSError as error:
        Path(temp_name).unlink(missing_ok=True)
        raise OutputError(f"{path}: cannot write: {error.strerror or error}") from None
    except BaseException:
        Path(temp_name).unlink(missing_ok=True)
        raise


def _mode_for(path: Path) -> int:
    """The mode a replaced file keeps, or a new file's usual mode under the umask."""
    try:
        return path.stat().st_mode & 0o7777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask
