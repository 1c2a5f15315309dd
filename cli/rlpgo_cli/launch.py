"""Console-script entry points that stay quiet on Ctrl-C even while a command is still
importing (GTSAM, numpy and torch take a while): one line and exit code 130."""

from __future__ import annotations

import importlib
import os
import signal
import sys

INTERRUPTED_EXIT = 130  # here, not in rlpgo_cli.errors: this module must import nothing heavy


def _interrupted(error: BaseException) -> bool:
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


def _run(module: str) -> None:
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
        command = importlib.import_module(f"rlpgo_cli.{module}")
        for number, handler in previous.items():
            signal.signal(number, handler)
        command.main()
    except (KeyboardInterrupt, ImportError) as error:
        if not _interrupted(error):
            raise
        print("Error: interrupted", file=sys.stderr)
        sys.exit(INTERRUPTED_EXIT)


def init() -> None:
    _run("init")


def compare() -> None:
    _run("compare")


def generate() -> None:
    _run("generate")


def train() -> None:
    _run("train")


def evaluate() -> None:
    _run("evaluate")
