"""The commands' output policy: every file a run writes is checked before any work starts,
never replaces one of the run's inputs (however the path names it), and all of a run's
files are written together by the library, every one or none, once the run has succeeded."""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path

from rlpgo_gtsam.errors import OutputError
from rlpgo_gtsam.files import Folders, check_output, is_stream, write_together


def _same_place(a: Path, b: Path) -> bool:
    """True if two output paths name one file: the same file where both exist, else the
    same path once symbolic links (``d/up/out.g2o`` through a linked folder) are resolved."""
    try:
        if os.path.samefile(a, b):
            return True
    except OSError:
        pass
    return os.path.realpath(a) == os.path.realpath(b)


def json_ready(data: object) -> object:
    """``data`` with every non-finite float (NaN, +-inf) replaced by None: strict JSON has
    no such numbers, and parsers other than Python's refuse ``NaN`` and ``Infinity``."""
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if isinstance(data, dict):
        return {key: json_ready(value) for key, value in data.items()}
    if isinstance(data, list | tuple):
        return [json_ready(value) for value in data]
    return data


def json_text(data: object) -> str:
    """Strict JSON text of ``data`` (see :func:`json_ready`), indented, ending in a newline."""
    import json  # only a run that writes JSON pays its import

    return json.dumps(json_ready(data), indent=2, allow_nan=False) + "\n"


class RunFiles:
    """The inputs of one command run, and the checks and writes of its outputs.

    An output that already exists as a regular file is refused unless ``overwrite`` (by
    default: whether the running command was given ``--overwrite``); devices and pipes
    (``/dev/null``) are written through.
    """

    def __init__(self, inputs: Iterable[str | os.PathLike[str]] = (),
                 overwrite: bool | None = None) -> None:
        self.inputs = [Path(path) for path in inputs]
        if overwrite is None:
            import click

            from rlpgo_cli.errors import OVERWRITE

            context = click.get_current_context(silent=True)
            overwrite = bool(context is not None and context.meta.get(OVERWRITE, False))
        self.overwrite = overwrite

    def add_input(self, path: str | os.PathLike[str]) -> None:
        self.inputs.append(Path(path))

    def is_input(self, path: str | os.PathLike[str]) -> bool:
        """True if ``path`` names the same file as an input (symlink, relative path, hard link)."""
        for source in self.inputs:
            try:
                if os.path.samefile(source, path):
                    return True
            except OSError:
                continue
        return False

    def check(self, *paths: str | os.PathLike[str] | None, folders: Folders = ()) -> None:
        """Refuse, before any work, outputs that could not be written or would replace an
        input. ``folders``: folders the run will make for its files (a plot folder)."""
        folders = list(folders)
        seen: list[Path] = []
        for path in paths:
            if path is None:
                continue
            path = Path(path)
            check_output(path, folders)  # first: a name the system cannot hold fails here
            if self.is_input(path):
                raise OutputError(f"{path}: is an input of this run; refusing to overwrite it")
            # a device twice (-o /dev/null --json /dev/null) takes each output in turn
            if not is_stream(path) and any(_same_place(path, other) for other in seen):
                raise OutputError(f"{path}: given as two different outputs")
            if not self.overwrite and path.is_file():
                raise OutputError(f"{path}: exists; give --overwrite to replace it")
            seen.append(path)

    def write_json(self, path: Path, data: object) -> None:
        """Write ``data`` as strict JSON (:func:`json_text`): a run's one output."""
        self.write_together([(path, json_text(data).encode())])

    def write_together(self, items: Sequence[tuple[Path, bytes]],
                       folders: Folders = ()) -> None:
        """Write all of a run's files, every one or none, making ``folders`` where they do
        not exist (see :func:`rlpgo_gtsam.files.write_together`): the one way a command
        writes. Call it once, after the run has succeeded: a run that fails writes nothing."""
        folders = list(folders)
        self.check(*(path for path, _ in items), folders=folders)
        write_together(items, folders)
