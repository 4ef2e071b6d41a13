"""Every command that reads a file, fed random bytes and random TOML.

Configurations (``--config``, ``--scenario``, ``check FILE``), flight logs (``companion
plot``) and signing keys (``--signing-key``) get random bytes, random TOML documents and
the shipped scenario with one value replaced, removed or added. The only accepted outcomes
are the documented ones: exit status 2 with ``error:`` lines that name the file or the
option at fault (``note:`` and ``warning:`` lines besides), or, for the commands that only
read (``check``, ``authority``) a file that happens to be valid, status 0. Never a
traceback. Where a valid file would start work (a simulation, a flight, a vehicle), one
option is made bad on purpose, so a valid file ends at that option: nothing runs here.
"""

from __future__ import annotations

import json
import math
import socket
import tempfile
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from companion.cli.main import app as companion_app
from sitl.cli import app as sitl_app

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
PICKUP = CONFIGS / "sitl_pickup.toml"
POINTS = ("--payload-at", "1.5,1.0,0.05", "--place-at", "-1.0,0.5,0.05")
BOUNDED = settings(max_examples=15, deadline=None)


def _closed_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


# (tool, arguments with {f} for the file and {d} for a scratch directory, accepted statuses,
# the option made bad on purpose or None)
CONFIG_COMMANDS: list[tuple[str, list[str], set[int], str | None]] = [
    ("companion", ["check", "{f}"], {0, 2}, None),
    ("companion", ["arm", "status", "--bus", "nope://x", "--config", "{f}"], {2}, "nope"),
    (
        "companion",
        ["arm", "move", "--bus", "nope://x", "--joint", "1", "--deg", "0", "--config", "{f}"],
        {2},
        "nope",
    ),
    (
        "companion",
        ["mission", "pickup", "--config", "{f}", *POINTS, "--control-rate", "0"],
        {2},
        "--control-rate",
    ),
    ("sitl", ["check", "{f}"], {0, 2}, None),
    ("sitl", ["authority", "--config", "{f}"], {0, 2}, None),
    (
        "sitl",
        ["sim", "--scenario", "{f}", "--out", "{d}/sim", "--duration", "1e9"],
        {2},
        "--duration",
    ),
    (
        "sitl",
        ["compare", "--scenario", "{f}", "--out", "{d}/cmp", "--duration", "1e9"],
        {2},
        "--duration",
    ),
    ("sitl", ["run", "--config", "{f}", "--onboard-port", "70000"], {2}, "--onboard-port"),
    ("sitl", ["sih", "--config", "{f}", "--px4-dir", "{d}/no-px4"], {2}, "no-px4"),
    (
        "sitl",
        ["demo", "--config", "{f}", "--place-at", "1e9,0,0", "--out", "{d}/demo"],
        {2},
        None,
    ),
]
"""Every command that reads a configuration file."""

OTHER_FILE_COMMANDS: list[tuple[str, list[str], set[int], str | None]] = [
    ("companion", ["plot", "{f}", "--out", "{d}/fig"], {2}, None),
    (
        "companion",
        [
            "mission",
            "pickup",
            "--config",
            str(PICKUP),
            *POINTS,
            "--signing-key",
            "{f}",
            "--out",
            "{d}/m",
            "--connect",
            "tcpout://127.0.0.1:{port}",
        ],
        {2},
        "--connect",
    ),
    (
        "sitl",
        ["run", "--config", str(PICKUP), "--signing-key", "{f}", "--physics", "nope"],
        {2},
        "--physics",
    ),
]
"""The commands that read a flight log or a signing key."""


def _check(command: tuple[str, list[str], set[int], str | None], content: bytes) -> None:
    tool, template, statuses, bad_option = command
    with tempfile.TemporaryDirectory() as scratch:
        path = Path(scratch) / "input.toml"
        path.write_bytes(content)
        args = [a.format(f=path, d=scratch, port=_closed_port()) for a in template]
        app = companion_app if tool == "companion" else sitl_app
        result = CliRunner().invoke(app, args)
    shown = f"{tool} {' '.join(args)}\n{result.stdout}\n{result.stderr}"
    assert result.exception is None or isinstance(result.exception, SystemExit), shown
    assert result.exit_code in statuses, shown
    assert "Traceback" not in result.stdout + result.stderr, shown
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert all(line.startswith(("error: ", "note: ", "warning: ")) for line in lines), shown
    errors = [line for line in lines if line.startswith("error: ")]
    if result.exit_code == 2:
        assert errors, shown
        # A file's problems name the file; otherwise the option made bad on purpose.
        named = [str(path), "--place-at", *([bad_option] if bad_option else [])]
        assert all(any(name in line for name in named) for line in errors), shown


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        return repr(value) if math.isfinite(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return "{" + ", ".join(f"{json.dumps(k)} = {_toml_value(v)}" for k, v in value.items()) + "}"


def toml_text(document: dict[str, Any]) -> bytes:
    """A TOML document (every table inline: a valid document for any nesting)."""
    lines = [f"{json.dumps(key)} = {_toml_value(value)}" for key, value in document.items()]
    return ("\n".join(lines) + "\n").encode("utf-8", "surrogatepass")


SHIPPED = tomllib.loads(PICKUP.read_text())
KEYS = sorted({"name", "description", *SHIPPED, "mass_kg", "url", "joints", "rate_hz"})
numbers = (
    st.floats(allow_nan=True, allow_infinity=True)
    | st.integers(-(2**70), 2**70)
    | st.sampled_from([0, -1, 1e308, -1e308, 1e-308, 5e-324, 2**63, 0.0, -0.0])
)
scalars = numbers | st.booleans() | st.text(max_size=20)
values = st.recursive(
    scalars,
    lambda inner: (
        st.lists(inner, max_size=9)
        | st.dictionaries(
            st.sampled_from(KEYS) | st.text(min_size=1, max_size=8), inner, max_size=5
        )
    ),
    max_leaves=30,
)
documents = st.dictionaries(st.sampled_from(KEYS) | st.text(min_size=1, max_size=8), values)


def _leaves(node: Any, path: tuple = ()) -> list[tuple]:
    if isinstance(node, dict):
        return [p for k, v in node.items() for p in _leaves(v, (*path, k))] or [path]
    if isinstance(node, list):
        return [p for i, v in enumerate(node) for p in _leaves(v, (*path, i))] or [path]
    return [path]


@st.composite
def mutated_scenarios(draw: Callable) -> bytes:
    """The shipped pickup scenario with one value replaced, one key removed or one added."""
    document = json.loads(json.dumps(SHIPPED))  # a deep copy
    path = draw(st.sampled_from(_leaves(document)))
    *parents, last = path
    node = document
    for key in parents:
        node = node[key]
    action = draw(st.sampled_from(["replace", "remove", "add"]))
    if action == "replace":
        node[last] = draw(values)
    elif action == "remove" and isinstance(node, dict):
        del node[last]
    elif isinstance(node, dict):
        node[draw(st.text(min_size=1, max_size=12))] = draw(values)
    return toml_text(document)


@BOUNDED
@given(st.binary(max_size=400) | st.binary(max_size=8).map(lambda b: b * 40))
def test_random_bytes(content: bytes) -> None:
    for command in CONFIG_COMMANDS + OTHER_FILE_COMMANDS:
        _check(command, content)


@BOUNDED
@given(documents.map(toml_text))
def test_random_toml(content: bytes) -> None:
    for command in CONFIG_COMMANDS + OTHER_FILE_COMMANDS:
        _check(command, content)


@settings(max_examples=30, deadline=None)
@given(mutated_scenarios())
def test_the_shipped_scenario_with_one_value_changed(content: bytes) -> None:
    for command in CONFIG_COMMANDS:
        _check(command, content)


def test_the_toml_writer_round_trips_the_shipped_scenario() -> None:
    """The mutations start from the real file, not from a writer's mistake."""
    assert tomllib.loads(toml_text(SHIPPED).decode()) == SHIPPED
