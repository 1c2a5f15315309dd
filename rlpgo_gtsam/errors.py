"""The errors rlpgo_gtsam raises for problems a user can act on, and its one warning.

Every error carries a message that reads well on one line; the command-line tools print
``Error: <message>`` and exit non-zero, with no traceback. :class:`InformationWarning` says
that a reader used an input's information matrices in a documented, changed form; the
commands print it as a ``note:`` line.
"""

from __future__ import annotations

import os


class RlpgoError(Exception):
    """Base class of every error this package raises on purpose."""


class G2oFormatError(RlpgoError):
    """A g2o file that cannot be read: the message names the file and, where known, the line."""

    def __init__(self, path: str | os.PathLike[str], line: int | None, reason: str) -> None:
        self.path = os.fspath(path)
        self.line = line
        self.reason = reason
        where = self.path if line is None else f"{self.path}:{line}"
        super().__init__(f"{where}: {reason}")


class InputNotFoundError(G2oFormatError, FileNotFoundError):
    """An input file that does not exist: both the package's error (one line, the file named)
    and :class:`FileNotFoundError`, so ``except FileNotFoundError`` catches it."""

    def __init__(self, path: str | os.PathLike[str], reason: str = "no such file") -> None:
        G2oFormatError.__init__(self, path, None, reason)
        self.filename = self.path

    def __str__(self) -> str:
        return f"{self.path}: {self.reason}"


class GraphError(RlpgoError):
    """A graph that an algorithm cannot work on (disconnected, unsupported factor types, ...)."""


class OutputError(RlpgoError):
    """An output that cannot be written safely (it is an input, a directory, unwritable, ...)."""


class SolverError(RlpgoError):
    """A solver or initializer that failed on a graph (indeterminate system, divergence)."""


class ModelError(RlpgoError):
    """A model file that cannot be loaded (missing, tampered, wrong format version)."""


class InformationWarning(UserWarning):
    """A file's information matrices were read in a changed form, by a documented rule (the
    3D reader's: :func:`rlpgo_gtsam.information.information_rule_3d`); the message names the file,
    how many edges and the first one's line."""


def one_line(error: BaseException) -> str:
    """A third-party exception's text on one line (GTSAM's span several lines and end in
    a general explanation that starts "Thrown when": that part is dropped)."""
    text = " ".join(str(error).split()).split(" Thrown when ")[0]
    return text or type(error).__name__
