"""The one way a file a user names is opened: refused by what it is before it is read.

A command line is handed paths by people (and by scripts that get them wrong): a FIFO
waits for a writer that never comes, ``/dev/zero`` never ends, a directory or a loop of
symbolic links is no file at all. Every reader of a user's file (configurations,
scenarios, campaign specs, signing keys, flight logs) comes through here:

- :func:`check_regular_file` looks at the path with :func:`os.stat` (which never blocks)
  and refuses anything but a regular file: missing, a loop of links, a directory, a FIFO,
  a character or block device, a socket;
- :func:`open_regular_file` opens what that admitted without blocking and checks it is
  still the same regular file: a file read as a stream (a flight log, which may be large);
- :func:`read_small_file` reads a small file whole, refusing it by its size before reading
  (and never reading more than its limit, should it grow meanwhile).

Each refusal is a :class:`UserFileError` whose ``reason`` reads after the path:
``PATH: cannot read: a named pipe (FIFO), not a regular file``.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path
from typing import BinaryIO

__all__ = [
    "SMALL_FILE_LIMIT_BYTES",
    "UserFileError",
    "check_regular_file",
    "describe_size",
    "file_kind",
    "open_regular_file",
    "read_small_file",
]

SMALL_FILE_LIMIT_BYTES = 1 << 20
"""The largest configuration, scenario or campaign spec read [bytes] (1 MiB): the largest
shipped one is under 10 KiB; anything bigger is not one of them."""

_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


class UserFileError(ValueError):
    """A file a user named that is refused: missing, not a regular file, or too large.

    ``str()`` is ``PATH: REASON``; readers put ``reason`` after their own prefix.
    """

    def __init__(self, path: str | Path, reason: str) -> None:
        self.path, self.reason = str(path), reason
        super().__init__(f"{path}: {reason}")


def describe_size(n_bytes: int) -> str:
    """A size in bytes, KiB, MiB or GiB, as a person reads it."""
    size = float(n_bytes)
    for unit in ("bytes", "KiB", "MiB", "GiB"):
        if size < 1024.0 or unit == "GiB":
            return f"{n_bytes} bytes" if unit == "bytes" else f"{size:.1f} {unit}"
        size /= 1024.0
    raise AssertionError("unreachable")


def file_kind(mode: int) -> str:
    """What a file of status ``mode`` is: ``a directory``, ``a named pipe (FIFO)``, ...,
    ``a regular file``."""
    if stat.S_ISREG(mode):
        return "a regular file"
    return next((name for test, name in _KINDS if test(mode)), "not a file")


def _os_reason(exc: OSError) -> str:
    if exc.errno == errno.ELOOP:
        return "cannot read: a loop of symbolic links"
    return f"cannot read file ({exc.strerror or exc})"


def check_regular_file(path: str | Path) -> os.stat_result:
    """The status of ``path`` if it is a regular file (after symbolic links); else
    :class:`UserFileError` saying what it is. Nothing is opened."""
    try:
        status = os.stat(path)
    except OSError as exc:
        raise UserFileError(path, _os_reason(exc)) from None
    except ValueError as exc:  # a NUL byte in the path
        raise UserFileError(path, f"cannot read file ({exc})") from None
    if stat.S_ISREG(status.st_mode):
        return status
    raise UserFileError(path, f"cannot read: {file_kind(status.st_mode)}, not a regular file")


def open_regular_file(path: str | Path) -> BinaryIO:
    """``path`` opened for reading in binary, if it is a regular file
    (:func:`check_regular_file`). The open does not block even if a FIFO took the file's
    place after the check; what was opened is checked again."""
    before = check_regular_file(path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    except OSError as exc:
        raise UserFileError(path, _os_reason(exc)) from None
    try:
        opened = os.fstat(fd)
        if not stat.S_ISREG(opened.st_mode) or opened.st_ino != before.st_ino:
            raise UserFileError(path, "cannot read: it changed while being opened")
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_small_file(path: str | Path, limit_bytes: int, kind: str) -> bytes:
    """The whole of a small regular file: a ``kind`` (``"a configuration TOML"``) of at
    most ``limit_bytes``. A larger one is refused by its size before anything is read;
    no more than the limit is ever read (a file that grows meanwhile)."""
    status = check_regular_file(path)
    if status.st_size > limit_bytes:
        raise UserFileError(path, _too_large(describe_size(status.st_size), limit_bytes, kind))
    with open_regular_file(path) as f:
        try:
            data = f.read(limit_bytes + 1)
        except OSError as exc:
            raise UserFileError(path, _os_reason(exc)) from None
    if len(data) > limit_bytes:
        raise UserFileError(path, _too_large("over the limit", limit_bytes, kind))
    return data


def _too_large(size: str, limit: int, kind: str) -> str:
    return f"too large ({size}): {kind} holds at most {describe_size(limit)}"
