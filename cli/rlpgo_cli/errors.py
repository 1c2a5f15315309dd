"""The one place where known errors become ``Error: <message>`` on stderr and a non-zero exit."""

from __future__ import annotations

import signal

import click

from rlpgo_gtsam.errors import RlpgoError

INTERRUPTED_EXIT = 130


class _Terminated(Exception):
    """SIGTERM, raised as an exception so that ``finally`` blocks remove temporary files."""


def _on_sigterm(_signum, _frame) -> None:
    raise _Terminated


class RlpgoCommand(click.Command):
    """A click command that reports package errors and OS errors on one line, no traceback;
    Ctrl-C and SIGTERM end it with one line and exit code 130, temporary files removed."""

    def invoke(self, ctx: click.Context):
        previous = signal.signal(signal.SIGTERM, _on_sigterm)
        try:
            return super().invoke(ctx)
        except RlpgoError as error:
            raise click.ClickException(str(error)) from None
        except OSError as error:
            where = f"{error.filename}: " if error.filename else ""
            raise click.ClickException(f"{where}{error.strerror or error}") from None
        except (KeyboardInterrupt, _Terminated):
            click.echo("Error: interrupted", err=True)
            ctx.exit(INTERRUPTED_EXIT)
        finally:
            signal.signal(signal.SIGTERM, previous)
