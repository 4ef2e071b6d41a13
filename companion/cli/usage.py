"""One-line user errors of the command lines (``companion`` and ``sitl``).

A user mistake (a bad config, a missing file, an option out of range, an output directory
that cannot be written) prints one ``error:`` line per problem and exits with status
:data:`EXIT_USAGE`, never a traceback. Output directories are chosen before any work is
done and never overwritten (:func:`output_dir_or_exit`).
"""

from __future__ import annotations

import errno
import math
import stat
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import NoReturn, TypeVar

import typer

from companion.config import CompanionConfig, ConfigError, load_config
from companion.user_files import file_kind

__all__ = [
    "EXIT_USAGE",
    "check_range",
    "config_or_exit",
    "fail",
    "load_or_exit",
    "output_dir_or_exit",
    "remove_if_unused",
]

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


def check_range(value: float, option: str, low: float, high: float, unit: str, why: str) -> float:
    """``value`` if it is a number in [low, high]; otherwise one ``error:`` line naming
    ``option``, the range and ``why`` it is that range, and exit status 2."""
    if not (math.isfinite(value) and low <= value <= high):
        fail(f"{option} must lie in [{low:g}, {high:g}] {unit} ({why}), got {value:g}")
    return value


def output_dir_or_exit(out: Path, writes: Iterable[str], option: str = "--out") -> Path:
    """The directory a command writes its results into, created before any work is done.

    ``out`` itself when it is new, or an existing directory holding none of the files the
    command ``writes``. Results are never overwritten: when ``out`` already holds one of
    them (an earlier run), the results go to the first free ``OUT-2``, ``OUT-3``, ...
    beside it, and a ``note:`` line says so. ``out`` naming a file, or a place that cannot
    be created or written, is one ``error:`` line and exit status 2.
    """
    names = tuple(writes)
    base = out if out.name else out.resolve()
    if not base.name:
        fail(f"{option} {out}: not a directory results can go into; name a new one")
    try:
        candidate = _fresh_dir(out, base, names, option)
        with tempfile.TemporaryFile(dir=candidate):
            pass
    except OSError as exc:
        fail(f"{option} {out}: cannot write there ({_why_not(exc, out)})")
    if candidate != out:
        typer.echo(
            f"note: {out} holds an earlier run's results, which are never overwritten; "
            f"writing to {candidate}",
            err=True,
        )
    return candidate


def _why_not(exc: OSError, out: Path) -> str:
    """Why nothing can be written at ``out``: the system's reason, unless that reason is
    "No such file or directory" for a directory that exists (/proc, /sys: file systems
    that take no new files)."""
    if exc.errno == errno.ENOENT:
        existing = next((p for p in (out, *out.parents) if p.is_dir()), None)
        if existing is not None:
            return f"the directory {existing} exists but takes no new files"
    return exc.strerror or str(exc)


_MADE: dict[Path, Path] = {}
"""The directories :func:`output_dir_or_exit` made in this process, each with the topmost
directory made with it (its new parents): what :func:`remove_if_unused` may take away."""


def remove_if_unused(out: Path) -> None:
    """Take away ``out`` and the parents made with it if :func:`output_dir_or_exit` made
    them and they are still empty: a command that stops on a user mistake after choosing
    its output leaves nothing behind. A directory the user had, or one holding anything,
    stays."""
    top = _MADE.pop(out, None)
    if top is None:
        return
    for directory in (out, *out.parents):
        try:
            directory.rmdir()  # only an empty directory goes
        except OSError:
            return
        if directory == top:
            return


def _not_a_directory(path: Path) -> str | None:
    """What ``path`` is if it is there but no directory (a file, a FIFO, a device, a link
    that leads nowhere or loops), else None. Looked at with stat, never opened."""
    try:
        mode = path.stat().st_mode
    except OSError:
        return "is a symbolic link that leads nowhere (or loops)" if path.is_symlink() else None
    if stat.S_ISDIR(mode):
        return None
    return "is a file" if stat.S_ISREG(mode) else f"is {file_kind(mode)}"


def _fresh_dir(out: Path, base: Path, names: tuple[str, ...], option: str) -> Path:
    n, candidate = 1, out
    while True:
        what = _not_a_directory(candidate)
        if what is not None and candidate == out:
            fail(f"{option} {out}: {what}, not a directory; name a new or empty directory")
        if what is None and not candidate.exists():
            top = candidate
            while not top.parent.exists() and top.parent != top:
                top = top.parent
            try:
                candidate.mkdir(parents=True)
            except FileExistsError:
                continue  # another run took it meanwhile: look at it again
            _MADE[candidate] = top
            return candidate
        if candidate.is_dir() and not any((candidate / name).exists() for name in names):
            return candidate
        n += 1
        candidate = base.with_name(f"{base.name}-{n}")
