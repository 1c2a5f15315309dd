"""The one place where known errors become ``Error: <message>`` on stderr and a non-zero exit."""

from __future__ import annotations

import click

from rlpgo_gtsam.errors import RlpgoError


class RlpgoCommand(click.Command):
    """A click command that reports package errors and OS errors on one line, no traceback."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except RlpgoError as error:
            raise click.ClickException(str(error)) from None
        except OSError as error:
            where = f"{error.filename}: " if error.filename else ""
            raise click.ClickException(f"{where}{error.strerror or error}") from None
