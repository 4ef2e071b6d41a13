"""One-line user errors of the command lines (``companion`` and ``sitl``).

A user mistake (a bad config, a missing file, an option out of range) prints one
``error:`` line per problem and exits with status :data:`EXIT_USAGE`, never a traceback.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import NoReturn, TypeVar

import typer

from companion.config import CompanionConfig, ConfigError, load_config

__all__ = ["EXIT_USAGE", "config_or_exit", "fail", "load_or_exit"]

EXIT_USAGE = 2
"""Exit status of a user mistake (the same as a command-line usage error)."""

Config = TypeVar("Config")


def fail(message: str, status: int = EXIT_USAGE) -> NoReturn:
    """Print ``error: message`` on stderr and exit with ``status``."""
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(status)


def load_or_exit(path: Path, loader: Callable[[Path], Config]) -> Config:
    """``loader(path)``; a :class:`ConfigError` becomes its lines and exit status 2."""
    try:
        return loader(path)
    except ConfigError as exc:
        for line in str(exc).splitlines():
            typer.echo(f"error: {line}", err=True)
        raise typer.Exit(EXIT_USAGE) from None


def config_or_exit(path: Path) -> CompanionConfig:
    """The companion's configuration in ``path`` (:func:`load_or_exit`)."""
    return load_or_exit(path, load_config)
