"""Console-script entry points that stay quiet on Ctrl-C even while a command is still
importing (GTSAM, numpy and torch take a while): one line and exit code 130."""

from __future__ import annotations

import importlib
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


def _run(module: str) -> None:
    try:
        importlib.import_module(f"rlpgo_cli.{module}").main()
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
