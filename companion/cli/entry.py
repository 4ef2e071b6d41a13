"""How the console scripts (``companion``, ``sitl``) run their typer apps.

Two things both command lines share, written once here (``sitl`` imports it; this module
knows nothing of ``sitl``):

- ``--version`` on the root command (:data:`VersionOption`): the installed distribution's
  version, from its metadata;
- a usage error (an unknown option, a missing argument, a value of the wrong type) is one
  ``error:`` line on stderr naming the command and exit status 2 (:func:`run`), instead of
  typer's block of usage, hint and message.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version
from typing import Annotated, NoReturn

import typer

# typer ships its own copy of click; its usage-error classes are not re-exported at the top.
from typer._click import Context
from typer._click.exceptions import ClickException, NoArgsIsHelpError, UsageError

from companion.cli.usage import EXIT_USAGE

__all__ = ["DISTRIBUTION", "VersionOption", "installed_version", "run", "usage_line"]

DISTRIBUTION = "aerial-manipulator-companion"
"""The distribution both console scripts come from (``pyproject.toml``'s ``name``)."""


def installed_version(distribution: str = DISTRIBUTION) -> str:
    """The installed version of ``distribution``, or ``unknown (not installed)`` when the
    packages are imported from a checkout that was never installed."""
    try:
        return version(distribution)
    except PackageNotFoundError:
        return "unknown (not installed)"


def _print_version(ctx: typer.Context, value: bool) -> None:
    if value and not ctx.resilient_parsing:
        typer.echo(f"{ctx.find_root().info_name} {installed_version()}")
        raise typer.Exit()


VersionOption = Annotated[
    bool,
    typer.Option(
        "--version",
        callback=_print_version,
        is_eager=True,
        help="Print the installed version and exit.",
    ),
]
"""The root callback's ``--version`` flag: ``def _root(version: VersionOption = False)``."""


def usage_line(error: UsageError, prog_name: str) -> str:
    """``error`` as one line: ``error: COMMAND PATH: MESSAGE; try 'COMMAND PATH --help'``.

    The command is the innermost one being parsed when the error was raised: click gives
    some errors (an option missing its value) the root command's context instead.
    """
    context = error.ctx
    frame = error.__traceback__
    while frame is not None:
        candidate = frame.tb_frame.f_locals.get("ctx")
        if isinstance(candidate, Context):
            context = candidate
        frame = frame.tb_next
    path = context.command_path if context is not None else prog_name
    lines = (line.strip() for line in error.format_message().splitlines())
    message = "; ".join(line for line in lines if line).rstrip(".")
    return f"error: {path}: {message}; try '{path} --help'"


def run(app: typer.Typer, prog_name: str, args: Sequence[str] | None = None) -> NoReturn:
    """Run ``app`` as the console script ``prog_name`` and exit with its status.

    0 on success, the status of a ``typer.Exit``, 2 with one line (:func:`usage_line`) on
    a usage error, 1 on an abort (end of input at a prompt). Without arguments the root
    command prints its help and exits 2, as typer does.
    """
    command = typer.main.get_command(app)
    argv = list(sys.argv[1:] if args is None else args)
    try:
        result = command.main(args=argv, prog_name=prog_name, standalone_mode=False)
    except NoArgsIsHelpError as exc:
        exc.show()
        sys.exit(EXIT_USAGE)
    except UsageError as exc:
        typer.echo(usage_line(exc, prog_name), err=True)
        sys.exit(EXIT_USAGE)
    except ClickException as exc:  # e.g. a file option that cannot be opened
        typer.echo(f"error: {prog_name}: {exc.format_message()}", err=True)
        sys.exit(exc.exit_code)
    except typer.Abort:
        typer.echo("error: aborted", err=True)
        sys.exit(1)
    # Without standalone mode a typer.Exit comes back as its status; commands return None.
    sys.exit(result if isinstance(result, int) and not isinstance(result, bool) else 0)
