"""Output files written all or none: each to a temporary file beside its target, then all
renamed over their targets together.

The library only writes safely; which paths a command may write (never one of its inputs)
is the command's policy (``rlpgo_cli.output``).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path

from rlpgo_gtsam.errors import OutputError

__all__ = ["write_text", "write_bytes", "write_together", "check_output", "check_folder",
           "check_name", "is_stream"]

_LONGEST_NAME = 255  # bytes: the usual file-name limit (ext4, xfs, btrfs)

Folders = Iterable[str | os.PathLike[str]]


def check_name(path: str | os.PathLike[str]) -> None:
    """Raise :class:`OutputError` if the name of ``path``, or of a folder on the way to it,
    is longer than the usual file-system limit (255 bytes)."""
    path = Path(path)
    if len(os.fsencode(path.name)) > _LONGEST_NAME:
        raise OutputError(f"{path}: file name longer than {_LONGEST_NAME} bytes")
    if any(len(os.fsencode(part)) > _LONGEST_NAME for part in path.parent.parts):
        raise OutputError(f"{path}: a folder name in it is longer than {_LONGEST_NAME} bytes")


def check_output(path: str | os.PathLike[str], folders: Folders = ()) -> None:
    """Raise :class:`OutputError` now if ``path`` could not be written later.

    ``folders``: folders the write may make (:func:`write_together`); a ``path`` in one of
    them that does not exist yet is checked by :func:`check_folder`.
    """
    path = Path(path)
    check_name(path)
    if path.is_dir():
        raise OutputError(f"{path}: is a directory; give a file name for the output")
    folder = path.parent
    if not folder.exists() and folder in {Path(f) for f in folders}:
        check_folder(folder)
        return
    if not folder.exists():
        raise OutputError(f"{path}: folder {folder} does not exist")
    if not folder.is_dir():
        raise OutputError(f"{path}: {folder} is not a folder")
    if not is_stream(path):
        _probe(folder, path)


def check_folder(folder: str | os.PathLike[str]) -> None:
    """Raise :class:`OutputError` now if files could not be written in ``folder``, or it could
    not be made where it does not exist (the folders above it included)."""
    folder = Path(folder)
    check_name(folder / "x")
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{folder}: exists and is not a folder")
    above = folder
    while not above.exists() and above != above.parent:
        above = above.parent
    if not above.is_dir():
        raise OutputError(f"{folder}: {above} is not a folder")
    if above == folder:
        _probe(folder, folder)
        return
    try:  # the one test that holds for every user and file system: make one and remove it
        made = tempfile.mkdtemp(prefix=".rlpgo-", suffix=".tmp", dir=above)
    except OSError as error:
        raise OutputError(f"{folder}: cannot make a folder in {above}: "
                          f"{error.strerror or error}") from None
    os.rmdir(made)


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
    write_together([(path, data)])


def is_stream(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is written through, not replaced: a device, pipe or /dev, /proc name
    (``/dev/stdout`` is a symlink to /proc/self/fd/1, which may point at a regular file:
    replacing it would replace the symlink)."""
    path = Path(path)
    if path.exists() and not path.is_file():
        return True
    resolved = str(path.resolve())
    return resolved.startswith(("/dev/", "/proc/")) or str(path.absolute()).startswith(
        ("/dev/", "/proc/"))


def write_together(items: Sequence[tuple[str | os.PathLike[str], bytes]],
                   folders: Folders = ()) -> None:
    """Write several files so that either every one is written or none is.

    In order: each regular file's data is written and synced to a temporary file beside it;
    then each device or pipe among the targets (``/dev/null``, ``/dev/stdout``) is written
    through, in the order given; only when all of that succeeded are the temporary files
    renamed over their targets. A failure at any step (``/dev/full``, a full disk, Ctrl-C)
    removes the temporary files, puts back any file already replaced, and leaves no new
    file. A device written before the failing step cannot be taken back.

    ``folders``: folders that may be made for the files (a plot folder); those that did not
    exist are made with their missing parents just before the write, and removed again if
    the write fails.

    Raises:
        OutputError: a target is a directory, or cannot be written.
    """
    targets = [(Path(path), data) for path, data in items]
    made: list[Path] = []
    written = False
    try:
        for folder in folders:
            made += _make_folder(Path(folder))
        for path, _ in targets:
            check_output(path)
        _write_checked(targets)
        written = True
    finally:
        if not written:
            for folder in reversed(made):
                try:
                    folder.rmdir()
                except OSError:
                    pass  # something else put a file there: it stays


def _write_checked(targets: list[tuple[Path, bytes]]) -> None:
    staged: list[tuple[Path, str]] = []
    try:
        for path, data in targets:
            if not is_stream(path):
                staged.append((path, _stage(path, data)))
        for path, data in targets:
            if is_stream(path):
                _write_through(path, data)
        _replace_all(staged)
    finally:
        for _, temp_name in staged:  # gone once renamed; left over on any failure
            Path(temp_name).unlink(missing_ok=True)


def _replace_all(staged: list[tuple[Path, str]]) -> None:
    """Rename each temporary file over its target. An existing target is first kept under
    a second name (a hard link, so that it never disappears) until every rename succeeded;
    on a failure the targets replaced so far get their files back and new ones go. The
    last rename needs no such copy: its failure leaves its target as it was."""
    replaced: list[tuple[Path, Path | None]] = []  # target, its kept file (None: was new)
    try:
        for index, (path, temp_name) in enumerate(staged):
            last = index == len(staged) - 1
            kept = None if last else _keep(path)
            try:
                os.replace(temp_name, path)
            except OSError as error:
                _discard(kept)
                raise OutputError(f"{path}: cannot write: {error.strerror or error}") from None
            except BaseException:
                _discard(kept)
                raise
            replaced.append((path, kept))
    except BaseException:
        while replaced:
            path, kept = replaced.pop()
            try:
                if kept is None:
                    path.unlink(missing_ok=True)
                else:
                    os.replace(kept, path)
            except OSError:
                pass  # the kept file stays, under its second name: the user's data is not lost
        raise
    for _, kept in replaced:
        _discard(kept)


def _keep(path: Path) -> Path | None:
    """A second name for the existing ``path`` in its folder (None where there is none):
    a hard link, or a copy where the file system has no hard links."""
    if not os.path.lexists(path):
        return None
    for _ in range(100):
        kept = path.parent / f".rlpgo-{os.urandom(6).hex()}.kept"  # (secrets: 4 ms to import)
        try:
            os.link(path, kept, follow_symlinks=False)
            return kept
        except FileExistsError:
            continue
        except OSError:
            try:
                shutil.copy2(path, kept, follow_symlinks=False)
            except OSError as error:
                _discard(kept)
                raise OutputError(f"{path}: cannot keep the existing file until the other "
                                  f"outputs are written: {error.strerror or error}") from None
            return kept
    raise OutputError(f"{path}: cannot keep the existing file until the other outputs are "
                      "written: no free temporary name")


def _discard(kept: Path | None) -> None:
    if kept is not None:
        kept.unlink(missing_ok=True)


def _make_folder(folder: Path) -> list[Path]:
    """Make ``folder`` and its missing parents; returns those made, outermost first."""
    missing = []
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    made: list[Path] = []
    try:
        for path in reversed(missing):
            try:
                path.mkdir()
            except FileExistsError:
                if not path.is_dir():
                    raise OutputError(f"{path}: exists and is not a folder") from None
                continue
            except OSError as error:
                raise OutputError(f"{path}: cannot make the folder: "
                                  f"{error.strerror or error}") from None
            made.append(path)
    except BaseException:
        for path in reversed(made):
            try:
                path.rmdir()
            except OSError:
                pass
        raise
    return made


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


def _mode_for(path: Path) -> int:
    """The mode a replaced file keeps, or a new file's usual mode under the umask."""
    try:
        return path.stat().st_mode & 0o7777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask
