"""Console-script entry points that stay quiet on Ctrl-C even while a command is still
importing (GTSAM, numpy and torch take a while): one line and exit code 130.

Start-up and exit are most of a small graph's run (rlpgo-init on an 800-pose file: about
0.2 s of work in 1.2 s), so the launcher trims both. The imports run with Python's cycle
collector off (they allocate much and free little: its passes there find nothing) and what
they loaded is frozen out of later passes. ``rlpgo-init`` and ``rlpgo-compare`` leave
through :func:`_leave`: once the command has returned, its files written (atomically,
closed) and stdout and stderr flushed, the process ends with ``os._exit`` and the command's
exit code, skipping the interpreter's teardown of GTSAM, numpy and SciPy (0.1-0.2 s); where
a flush fails (a closed pipe) the ordinary exit runs instead and reports it as Python does.
Both also start OpenBLAS with the one thread their hot calls use anyway
(``rlpgo_gtsam.numerics``), keep SciPy's import from loading numpy's tooling
(:class:`_NumpyToolingUnloaded`) and from rewriting its own docstrings
(:class:`_ScipyDocsUnparsed`), and run it, when a step brings it, with the collector off
too (:class:`_CollectorOffDuring`).
"""

from __future__ import annotations

import gc
import importlib
import os
import signal
import sys

INTERRUPTED_EXIT = 130  # here, not in rlpgo_cli.errors: this module must import nothing heavy


def _interrupted(error: BaseException | None) -> bool:
    """True for Ctrl-C, also when an extension module's initialization turned it into an
    ImportError ("initialization failed")."""
    while error is not None:
        if isinstance(error, KeyboardInterrupt):
            return True
        error = error.__cause__ or error.__context__
    return False


def _exit_during_start_up(_signum, _frame) -> None:
    """Ctrl-C or SIGTERM while the command still imports: nothing to clean up yet."""
    os.write(2, b"Error: interrupted\n")
    os._exit(INTERRUPTED_EXIT)


def _leave(code: object) -> None:
    """End the process with ``code`` (``SystemExit``'s) without the interpreter's teardown,
    once stdout and stderr are flushed; return (for the ordinary exit) if a flush fails or
    the code is not a number or None."""
    if code is not None and not isinstance(code, int):
        return  # sys.exit("message"): Python prints it
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):
        return
    os._exit(code or 0)


# numpy submodules that SciPy's array-API copy of the numpy namespace would load and that
# nothing on a command's path uses (numpy's build and test tooling, masked arrays, ...)
_NUMPY_TOOLING = ("f2py", "testing", "ma", "polynomial", "ctypeslib", "char", "rec", "strings")


def _exec_wrapped(name: str, path, around) -> object:
    """The spec of module ``name`` as the path finders find it, its execution run through
    ``around(run, module)``; the spec unchanged where its loader has no ``exec_module``."""
    from importlib.machinery import PathFinder

    spec = PathFinder.find_spec(name, path)
    if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
        return spec
    run = spec.loader.exec_module
    spec.loader.exec_module = lambda module: around(run, module)  # type: ignore[method-assign]
    return spec


class _OnFirstImport:
    """A meta-path finder for a command's own process that runs module :attr:`TARGET`
    through :meth:`around` the first time it is imported, then leaves ``sys.meta_path``."""

    TARGET = ""

    def find_spec(self, name, path, target=None):
        if name != self.TARGET:
            return None
        sys.meta_path.remove(self)  # once
        return _exec_wrapped(name, path, self.around)

    @staticmethod
    def around(run, module) -> None:
        run(module)


class _NumpyToolingUnloaded(_OnFirstImport):
    """While SciPy (1.17) builds its array-API copy of the numpy namespace
    (``scipy._lib.array_api_compat.numpy``, imported with ``scipy.sparse``), numpy's
    ``__all__`` and ``dir()`` leave out :data:`_NUMPY_TOOLING` not yet loaded, so the copy
    does not import them: ``from numpy import *`` loads every submodule named in
    ``__all__``, f2py's and numpy.testing's 0.1 s each among them, 0.29-0.43 s in all on this
    2-core machine with another process running (SciPy's own part: about 0.37 s). Only that
    copy lacks them; numpy itself is unchanged and restored at once. Where SciPy no longer
    has the module, nothing happens."""

    TARGET = "scipy._lib.array_api_compat.numpy"

    @staticmethod
    def around(run, module) -> None:
        import numpy

        names, listing = list(numpy.__all__), numpy.__dict__.get("__dir__")
        left_out = {n for n in _NUMPY_TOOLING if f"numpy.{n}" not in sys.modules}
        numpy.__all__[:] = [n for n in names if n not in left_out]
        if listing is not None:
            numpy.__dir__ = lambda: [n for n in listing() if n not in left_out]  # type: ignore[method-assign]
        try:
            run(module)
        finally:
            numpy.__all__[:] = names
            if listing is not None:
                numpy.__dir__ = listing  # type: ignore[method-assign]


class _DocUnparsed:
    """What :class:`_ScipyDocsUnparsed` puts in place of SciPy's ``FunctionDoc`` in
    ``scipy._lib._util``: the function's docstring as it is, no section parsed. Its two
    decorators there then leave a docstring unchanged: ``_apply_over_batch`` appends to an
    'Extended Summary' that is not written back, ``_transition_to_rng`` finds no
    'Parameters' (so no ``rng`` entry to rewrite)."""

    def __init__(self, function, *args, **kwargs) -> None:
        self._text = getattr(function, "__doc__", None) or ""
        self._sections: dict[str, list] = {}

    def __getitem__(self, section: str) -> list:
        return self._sections.setdefault(section, [])

    def __setitem__(self, section: str, value) -> None:
        self._sections[section] = value

    def __str__(self) -> str:
        return "\n" + self._text  # the callers drop the first line (the signature)


class _ScipyDocsUnparsed(_OnFirstImport):
    """Once ``scipy._lib._util`` has run, its ``FunctionDoc`` is :class:`_DocUnparsed`.
    SciPy (1.17) rewrites the docstrings of the functions it decorates as it imports them
    (``scipy.linalg``, ``scipy.sparse`` and ``scipy.sparse.linalg``: 75 of them, each parsed
    by numpydoc's parser and printed again, for a batch note and an ``rng`` parameter's
    text): 0.04-0.07 s of a small file's run on this 2-core machine with another process
    running, for text nobody reads in a command's process. What the functions compute is
    unchanged. Where SciPy no longer has ``FunctionDoc`` there, nothing happens."""

    TARGET = "scipy._lib._util"

    @staticmethod
    def around(run, module) -> None:
        run(module)
        if isinstance(getattr(module, "FunctionDoc", None), type):
            module.FunctionDoc = _DocUnparsed


def _collector_off(run, *args):
    """``run(*args)`` with the cycle collector off, and what it loaded frozen out of the
    collector's later passes (where the collector was on): imports allocate much and free
    little, so its passes there find nothing."""
    collecting = gc.isenabled()
    gc.disable()
    try:
        return run(*args)
    finally:
        if collecting:
            gc.freeze()
            gc.enable()


class _CollectorOffDuring(_OnFirstImport):
    """The first import of ``target``, a module a command imports only when a step needs
    it, runs as the command's own imports do (:func:`_collector_off`). For the certified
    relaxations, which load SciPy: the collector's passes during that import took 4-7 ms
    of a small file's run on this 2-core machine with another process running."""

    def __init__(self, target: str) -> None:
        self.TARGET = target

    @staticmethod
    def around(run, module) -> None:
        _collector_off(run, module)


# modules the lean commands import inside a step (rlpgo_gtsam.initializers) that bring
# SciPy with them: the relaxation's package, then its planar or spatial problem
_LOADING_SCIPY = ("rlpgo_gtsam.relaxation", "rlpgo_gtsam.relaxation.circles",
                  "rlpgo_gtsam.relaxation.stiefel")


def _import(module: str, lean: bool = False):
    """The command's module ``rlpgo_cli.<module>``, imported with the cycle collector off,
    and what it loaded frozen out of the collector's later passes; ``lean``: OpenBLAS
    started with one thread (:func:`~rlpgo_gtsam.numerics.one_thread_from_start`), and
    SciPy's import, when a step brings it, trimmed (:class:`_NumpyToolingUnloaded`,
    :class:`_ScipyDocsUnparsed`) and run with the collector off
    (:class:`_CollectorOffDuring`)."""
    if lean:
        from rlpgo_gtsam.numerics import one_thread_from_start  # before numpy loads

        one_thread_from_start()
        sys.meta_path[:0] = [_NumpyToolingUnloaded(), _ScipyDocsUnparsed(),
                             *map(_CollectorOffDuring, _LOADING_SCIPY)]
    return _collector_off(importlib.import_module, f"rlpgo_cli.{module}")


def _run(module: str, *, lean: bool = False) -> None:
    """Import and run ``rlpgo_cli.<module>``; ``lean``: OpenBLAS started with one thread
    (:func:`~rlpgo_gtsam.numerics.one_thread_from_start`) and the exit through
    :func:`_leave` (module docstring)."""
    # Until the command's module is imported, a signal ends the process with one line (an
    # exception raised inside an extension module's import can surface as a traceback).
    previous = {number: signal.signal(number, _exit_during_start_up)
                for number in (signal.SIGINT, signal.SIGTERM)}
    # A terminal whose encoding cannot show a file name (latin-1, or bytes that are not
    # UTF-8) gets escapes, not a crash after the work is done.
    for stream in (sys.stdout, sys.stderr):
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="backslashreplace")
    try:
        command = _import(module, lean)
        for number, handler in previous.items():
            signal.signal(number, handler)
        command.main()
    except (KeyboardInterrupt, ImportError) as error:
        if not _interrupted(error):
            raise
        print("Error: interrupted", file=sys.stderr)
        sys.exit(INTERRUPTED_EXIT)
    except SystemExit as stop:  # click ends every run, success included, with SystemExit
        if lean:
            _leave(stop.code)
        raise


def init() -> None:
    _run("init", lean=True)


def compare() -> None:
    _run("compare", lean=True)


def generate() -> None:
    _run("generate")


def train() -> None:
    _run("train")


def evaluate() -> None:
    _run("evaluate")


def example() -> None:
    _run("example")
