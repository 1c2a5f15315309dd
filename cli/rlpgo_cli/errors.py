"""The one place where known errors become ``Error: <message>`` on stderr and a non-zero exit."""

from __future__ import annotations

import signal

import click

from rlpgo_cli.launch import INTERRUPTED_EXIT
from rlpgo_gtsam.errors import RlpgoError

_LONGEST_MESSAGE = 1000


def printable_line(text: str) -> str:
    """``text`` as one printable line: control characters (a newline in a file name)
    escaped, and cut to 1000 characters."""
    escaped = "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii")
                      for c in text)
    return escaped if len(escaped) <= _LONGEST_MESSAGE else escaped[:_LONGEST_MESSAGE] + "..."


class _Terminated(Exception):
    """SIGTERM, raised as an exception so that ``finally`` blocks remove temporary files."""


def _on_sigterm(_signum, _frame) -> None:
    raise _Terminated


OVERWRITE = "rlpgo.overwrite"  # ctx.meta key: --overwrite was given


def _version(ctx: click.Context, _param: click.Parameter, value: bool) -> None:
    if not value or ctx.resilient_parsing:
        return
    from importlib.metadata import PackageNotFoundError, version

    try:
        number = version("rlpgo-gtsam")
    except PackageNotFoundError:
        number = "unknown (not installed)"
    click.echo(f"{ctx.info_name} (rlpgo-gtsam) {number}")
    ctx.exit(0)


def _overwrite(ctx: click.Context, _param: click.Parameter, value: bool) -> None:
    ctx.meta[OVERWRITE] = bool(value)


class RlpgoCommand(click.Command):
    """A click command that reports package errors and OS errors on one line, no traceback;
    Ctrl-C and SIGTERM end it with one line and exit code 130, temporary files removed.

    Every command also takes ``-h``/``--help``, ``--version`` and ``--overwrite`` (without
    it, no existing file is replaced: :class:`rlpgo_cli.output.RunFiles` refuses it).
    """

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("context_settings", {}).setdefault("help_option_names",
                                                             ["-h", "--help"])
        super().__init__(*args, **kwargs)
        self.params.append(click.Option(
            ["--overwrite"], is_flag=True, expose_value=False, callback=_overwrite,
            help="Replace output files that already exist (without it, an existing file is "
                 "never replaced)."))
        self.params.append(click.Option(
            ["--version"], is_flag=True, expose_value=False, is_eager=True, callback=_version,
            help="Show the version and exit."))

    def make_context(self, info_name, args, parent=None, **extra) -> click.Context:
        # parsing (and printing --help) runs before invoke: click would answer a Ctrl-C here
        # with "Aborted!" and exit code 1
        try:
            return super().make_context(info_name, args, parent, **extra)
        except KeyboardInterrupt:
            click.echo("Error: interrupted", err=True)
            raise click.exceptions.Exit(INTERRUPTED_EXIT) from None
        except click.UsageError as error:
            # one line, as every other error (click prints usage and a hint besides)
            click.echo(f"Error: {printable_line(error.format_message())} (see "
                       f"{info_name} --help)", err=True)
            raise click.exceptions.Exit(error.exit_code) from None

    def invoke(self, ctx: click.Context):
        import numpy as np  # not at import: --help stays fast

        previous = signal.signal(signal.SIGTERM, _on_sigterm)
        try:
            # overflow on extreme input is checked where it matters; numpy's warnings would
            # print source lines (tracebacks under -W error)
            with np.errstate(all="ignore"):
                return super().invoke(ctx)
        except RlpgoError as error:
            raise click.ClickException(printable_line(str(error))) from None
        except OSError as error:
            where = f"{error.filename}: " if error.filename else ""
            message = f"{where}{error.strerror or error}"
            raise click.ClickException(printable_line(message)) from None
        except (KeyboardInterrupt, _Terminated):
            click.echo("Error: interrupted", err=True)
            ctx.exit(INTERRUPTED_EXIT)
        finally:
            signal.signal(signal.SIGTERM, previous)
