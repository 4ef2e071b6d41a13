"""Both command lines as a user runs them: ``--version``, and a usage error (an unknown
option, a missing argument, a value of the wrong kind) in one line with exit status 2."""

from __future__ import annotations

import subprocess
import sys
from importlib.metadata import version

import pytest

from companion.cli.entry import DISTRIBUTION

MODULES = {"companion": "companion.cli.main", "sitl": "sitl.cli"}


def run(tool: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", f"from {MODULES[tool]} import main; main()", *args],
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.parametrize("tool", ["companion", "sitl"])
def test_version_prints_the_installed_distributions_version(tool):
    done = run(tool, "--version")
    assert done.returncode == 0, done.stderr
    assert done.stdout == f"{tool} {version(DISTRIBUTION)}\n"
    assert done.stderr == ""


@pytest.mark.parametrize("tool", ["companion", "sitl"])
def test_version_is_listed_in_the_help(tool):
    done = run(tool, "--help")
    assert done.returncode == 0
    assert "--version" in done.stdout


@pytest.mark.parametrize(
    ("tool", "args", "command", "words"),
    [
        ("companion", ["mission", "pickup", "--bogus"], "companion mission pickup", ["--bogus"]),
        ("companion", ["check"], "companion check", ["Missing argument"]),
        ("companion", ["arm", "scan", "--bus"], "companion arm scan", ["--bus", "argument"]),
        ("companion", ["--bogus"], "companion", ["--bogus"]),
        ("companion", ["fly"], "companion", ["No such command", "fly"]),
        ("sitl", ["demo", "--bogus"], "sitl demo", ["--bogus"]),
        ("sitl", ["sim", "--controller", "pid"], "sitl sim", ["Invalid value", "--controller"]),
        ("sitl", ["run", "--speed", "fast"], "sitl run", ["--speed", "number"]),
    ],
)
def test_a_usage_error_is_one_line_and_status_2(tool, args, command, words):
    done = run(tool, *args)
    assert done.returncode == 2, (done.stdout, done.stderr)
    assert done.stdout == ""
    lines = done.stderr.splitlines()
    assert len(lines) == 1, done.stderr
    line = lines[0]
    assert line.startswith(f"error: {command}: "), line
    assert line.endswith(f"try '{command} --help'"), line
    for word in words:
        assert word in line, line
    assert "Usage:" not in line and "Traceback" not in done.stderr


@pytest.mark.parametrize("tool", ["companion", "sitl"])
def test_no_arguments_print_the_help_with_status_2(tool):
    done = run(tool)
    assert done.returncode == 2
    assert f"Usage: {tool} [OPTIONS] COMMAND" in done.stdout + done.stderr
    assert "--version" in done.stdout + done.stderr


def test_a_mistake_found_by_a_command_keeps_its_own_line(tmp_path):
    missing = tmp_path / "missing.toml"
    done = run("companion", "check", str(missing))
    assert done.returncode == 2
    assert done.stderr.splitlines() == [line for line in done.stderr.splitlines() if line]
    assert len(done.stderr.splitlines()) == 1
    assert done.stderr.startswith("error: ") and str(missing) in done.stderr


def test_help_of_a_subcommand_still_exits_0():
    done = run("companion", "mission", "pickup", "--help")
    assert done.returncode == 0
    assert "--payload-at" in done.stdout
