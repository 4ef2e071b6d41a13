"""Writing calibrated values into a config TOML in place, comments and layout kept (pure).

:mod:`companion.config` reads configs; this module rewrites one, text to text, with
tomlkit (a style-preserving TOML library): every comment, blank line and key order stays
as it was, a changed value keeps its line and its comment (moved so the comment column
does not shift), a new key goes at the end of its table with a comment saying where it
came from. The result is validated as the companion would load it before it is returned.
"""

from __future__ import annotations

from collections.abc import Mapping

import tomlkit
import tomlkit.exceptions
from tomlkit.items import Item, Table

from companion.config import ConfigError, parse_config

__all__ = ["with_joint_values"]


def with_joint_values(
    text: str,
    values: Mapping[str, Mapping[str, float | bool]],
    note: str,
    path: str = "<string>",
) -> str:
    """``text`` (a config TOML) with ``values[joint][key]`` set in the
    ``[[arm_bus.joints]]`` entry named ``joint``.

    Parameters
    ----------
    text
        The config file's text.
    values
        Joint name -> key -> value (SI units, as the keys name them).
    note
        Comment for a key the entry did not have (e.g. ``"companion arm calibrate,
        2026-12-02"``); a key it had keeps its own comment.
    path
        The file's name, for errors.

    Raises
    ------
    ConfigError
        ``text`` is not TOML, has no such joint, or does not load with the new values.
    """
    try:
        document = tomlkit.parse(text)
    except tomlkit.exceptions.ParseError as exc:
        raise ConfigError(path, "", f"invalid TOML: {exc}") from None
    section = document.get("arm_bus")
    joints = section.get("joints") if isinstance(section, Table) else None
    entries = {str(entry.get("name")): entry for entry in (joints or [])}
    for name, keys in values.items():
        if name not in entries:
            raise ConfigError(path, "arm_bus.joints", f"no joint named {name!r}")
        entry = entries[name]
        for key, value in keys.items():
            if key in entry:
                _replace(entry, key, value)
            else:
                _add(entry, key, value, note)
    edited = document.as_string()
    parse_config(tomlkit.parse(edited).unwrap(), path)
    return edited


def _add(entry: Table, key: str, value: float | bool, note: str) -> None:
    """Append ``key = value`` to ``entry`` with ``note`` in the column of its comments."""
    item = tomlkit.item(value).comment(note)
    columns = [
        len(name.as_string() + name.sep + old.as_string() + old.trivia.comment_ws)
        for name, old in entry.value.body
        if name is not None and old.trivia.comment
    ]
    if columns:
        width = max(columns, key=columns.count) - len(f"{key} = {item.as_string()}")
        item.trivia.comment_ws = " " * max(1, width)
    entry.add(key, item)


def _replace(entry: Table, key: str, value: float | bool) -> None:
    """Set ``entry[key]`` keeping its comment in the same column."""
    old: Item = entry[key]
    new = tomlkit.item(value)
    trivia = old.trivia
    new.trivia.indent, new.trivia.trail = trivia.indent, trivia.trail
    if trivia.comment:
        width = len(trivia.comment_ws) + len(old.as_string()) - len(new.as_string())
        new.trivia.comment_ws = " " * max(1, width)
        new.trivia.comment = trivia.comment
    entry[key] = new
