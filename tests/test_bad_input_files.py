"""Every file a command line reads, fed the same hostile set: one ``error:`` line, exit 2.

The options are found, not listed: every parameter of the ``companion`` and ``sitl`` typer
apps annotated ``Path`` is an input file unless it is an output (:data:`OUTPUTS`) or a
directory (:data:`DIRECTORIES`), so an option added tomorrow is fed the hostile set
without anyone naming it (a command added tomorrow fails here until its other required
options are in :data:`REQUIRED`). Each input gets :data:`HOSTILE`: a missing path, a
directory, a FIFO, ``/dev/zero``, ``/dev/null``, an empty file, random bytes, a file over
the TOML size limit, arrays nested 600 deep and a loop of symbolic links; each case must
print one ``error:`` line naming the file, exit 2 without a traceback and create nothing.

The cases run in this process's typer runner, but inside one child process: a case that
hangs (a FIFO opened blocking) is caught by a 30 s timeout on that case, and one that reads
without end by an address-space limit, instead of taking the test run or the machine
down. Each case's rise of the child's peak memory must stay under 100 MB.
"""

from __future__ import annotations

import json
import os
import queue
import random
import resource
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]
PICKUP = ROOT / "configs" / "sitl_pickup.toml"
SMOKE = ROOT / "configs" / "campaigns" / "smoke.toml"

OUTPUTS = frozenset({"out", "truth_log", "keep_log"})
"""Parameter names of the options that name where results go (never read)."""
DIRECTORIES = frozenset({"px4_dir"})
"""Parameter names of the options that name a directory to read (the PX4 build)."""
STAND_INS = {"config": PICKUP, "scenario": PICKUP, "spec": SMOKE}
"""A good file for a required input beside the one under test, by parameter name; an
input without one gets an empty file (:data:`STAND_IN_FILE`)."""
STAND_IN_FILE = "stand-in"
REQUIRED: dict[str, list[str]] = {
    "companion check": [],
    "companion plot": ["--out", "figures"],
    "companion arm status": ["--bus", "dynamixel:///dev/null"],
    "companion arm move": ["--bus", "dynamixel:///dev/null", "--joint", "1", "--deg", "0"],
    "companion arm calibrate": ["--bus", "dynamixel:///dev/null"],
    "companion mission pickup": [
        *("--payload-at", "1.5,1.0,0.05", "--place-at", "-1.0,0.5,0.05"),
        *("--connect", "udpin://127.0.0.1:9"),
    ],
    "companion log info": [],
    "companion log add-ulog": [],
    "companion log export": [],
    "sitl authority": [],
    "sitl run": [],
    "sitl campaign": ["--out", "campaign"],
    "sitl sih": [],
    "sitl check": [],
    "sitl sim": ["--out", "run"],
    "sitl compare": ["--out", "run"],
    "sitl demo": [],
}
"""The other options each command needs, beside the file under test (outputs are
relative: inside the case's empty working directory)."""

HOSTILE = (
    "missing",
    "directory",
    "fifo",
    "dev-zero",
    "dev-null",
    "empty",
    "binary",
    "oversized",
    "nested",
    "symlink-loop",
)
CASE_TIMEOUT_S = 30.0
MEMORY_RISE_LIMIT_KB = 100 * 1024


@dataclass(frozen=True)
class FileOption:
    """One input-file parameter of a command."""

    tool: str
    command: tuple[str, ...]
    name: str
    flag: str | None
    """``--config``, or None for a positional argument."""
    inputs: tuple[tuple[str, str | None, bool], ...]
    """Every input-file parameter of the command: (name, flag, required)."""

    @property
    def label(self) -> str:
        return " ".join((self.tool, *self.command, self.flag or self.name.upper()))


def _commands(group: Any, path: tuple[str, ...]):
    from typer.core import TyperGroup

    if isinstance(group, TyperGroup):
        for name, sub in group.commands.items():
            yield from _commands(sub, (*path, name))
    else:
        yield path, group


def _is_path(param: Any) -> bool:
    descriptor = getattr(param, "type_descriptor", None)
    annotation = getattr(descriptor, "annotation", None)
    return annotation is Path or Path in getattr(annotation, "__args__", ())


def path_parameters() -> list[tuple[str, tuple[str, ...], Any]]:
    """(tool, command path, parameter) of every Path parameter of both apps."""
    from typer.main import get_command

    from companion.cli.main import app as companion_app
    from sitl.cli import app as sitl_app

    found = []
    for tool, app in (("companion", companion_app), ("sitl", sitl_app)):
        for path, command in _commands(get_command(app), ()):
            found += [(tool, path, p) for p in command.params if _is_path(p)]
    return found


def file_options() -> list[FileOption]:
    by_command: dict[tuple[str, tuple[str, ...]], list[Any]] = {}
    for tool, path, param in path_parameters():
        if param.name not in OUTPUTS | DIRECTORIES:
            by_command.setdefault((tool, path), []).append(param)
    options = []
    for (tool, path), params in by_command.items():
        inputs = tuple(
            (p.name, p.opts[0] if p.opts[0].startswith("-") else None, p.required) for p in params
        )
        for name, flag, _ in inputs:
            options.append(FileOption(tool, path, name, flag, inputs))
    return options


OPTIONS = file_options()


def argv(option: FileOption, path: str, stand_in: Path) -> list[str]:
    """The command line of one case: ``path`` for the option under test, good files (or
    ``stand_in``) for the other required inputs."""
    args = list(option.command)
    for name, flag, required in option.inputs:
        if name == option.name:
            value = path
        elif required:
            value = str(STAND_INS.get(name, stand_in))
        else:
            continue
        args += [flag, value] if flag else [value]
    return args + REQUIRED[" ".join((option.tool, *option.command))]


def make_hostile_files(where: Path) -> dict[str, str]:
    """The hostile set in ``where``: name -> path."""
    rng = random.Random(49)
    (where / "directory").mkdir()
    os.mkfifo(where / "fifo")
    (where / "empty").write_bytes(b"")
    (where / "binary").write_bytes(bytes(rng.randrange(256) for _ in range(4096)))
    # Valid TOML (comments) over the 1 MiB limit: only its size can refuse it.
    (where / "oversized").write_text("# a comment line of a file too large to be read\n" * 24_000)
    (where / "nested").write_text("x = " + "[" * 600 + "]" * 600 + "\n")
    os.symlink("loop-b", where / "loop-a")
    os.symlink("loop-a", where / "loop-b")
    (where / STAND_IN_FILE).write_bytes(b"")
    return {
        "missing": str(where / "missing"),
        "directory": str(where / "directory"),
        "fifo": str(where / "fifo"),
        "dev-zero": "/dev/zero",
        "dev-null": "/dev/null",
        "empty": str(where / "empty"),
        "binary": str(where / "binary"),
        "oversized": str(where / "oversized"),
        "nested": str(where / "nested"),
        "symlink-loop": str(where / "loop-a"),
    }


# --- the child: every case in one process, through typer's runner -----------------------


def _child(cases_file: str) -> None:
    """Run the cases of ``cases_file`` (JSON) one by one; a JSON line per case on stdout,
    written before (``start``) and after (the result)."""
    from typer.testing import CliRunner

    from companion.cli.main import app as companion_app
    from sitl.cli import app as sitl_app

    apps = {"companion": companion_app, "sitl": sitl_app}
    cases = json.loads(Path(cases_file).read_text())
    # A case that reads without end fails with MemoryError here, not by taking the machine.
    with open("/proc/self/statm") as f:
        virtual = int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    resource.setrlimit(resource.RLIMIT_AS, (virtual + (2 << 30), resource.RLIM_INFINITY))
    for case in cases:
        print(json.dumps({"start": case["id"]}), flush=True)
        os.chdir(case["cwd"])
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        result = CliRunner().invoke(apps[case["tool"]], case["argv"])
        after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        exception = result.exception
        print(
            json.dumps(
                {
                    "id": case["id"],
                    "exit_code": result.exit_code,
                    "stdout": result.stdout,
                    "stderr": result.stderr,
                    "exception": None
                    if isinstance(exception, SystemExit) or exception is None
                    else repr(exception),
                    "rise_kb": after - before,
                }
            ),
            flush=True,
        )


def _run_child(cases: list[dict[str, Any]], cases_file: Path, found: dict[str, Any]) -> None:
    """Run ``cases`` in a child process until they are done or one hangs or crashes it;
    their results into ``found`` (a hung or crashed case too)."""
    cases_file.write_text(json.dumps(cases))
    child = subprocess.Popen(
        [sys.executable, __file__, str(cases_file)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    lines: queue.Queue[str | None] = queue.Queue()

    def read() -> None:
        assert child.stdout is not None
        for line in child.stdout:
            lines.put(line)
        lines.put(None)

    threading.Thread(target=read, daemon=True).start()
    running = None
    try:
        while True:
            try:
                line = lines.get(timeout=CASE_TIMEOUT_S)
            except queue.Empty:
                found[running or cases[0]["id"]] = {"hung": True}
                return
            if line is None:
                break
            record = json.loads(line)
            if "start" in record:
                running = record["start"]
            else:
                found[record["id"]] = record
                running = None
    finally:
        child.kill()
        stderr = child.communicate()[1]
    crashed = running or next((c["id"] for c in cases if c["id"] not in found), None)
    if crashed is not None:
        found[crashed] = {"crashed": stderr[-2000:]}


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> dict[str, dict[str, Any]]:
    """Every case's result (by case id), from one child process (and one more after each
    case that hangs or crashes one)."""
    base = tmp_path_factory.mktemp("hostile")
    files = base / "files"
    files.mkdir()
    paths = make_hostile_files(files)
    cases = []
    found_paths: dict[str, str] = {}
    for option in OPTIONS:
        for hostile in HOSTILE:
            case_id = f"{option.label} {hostile}"
            cwd = base / "cwd" / str(len(cases))
            cwd.mkdir(parents=True)
            args = argv(option, paths[hostile], files / STAND_IN_FILE)
            cases.append({"id": case_id, "tool": option.tool, "argv": args, "cwd": str(cwd)})
            found_paths[case_id] = paths[hostile]
    found: dict[str, dict[str, Any]] = {}
    while len(found) < len(cases):  # a child per hang: the cases after it run in the next
        _run_child([c for c in cases if c["id"] not in found], base / "cases.json", found)
    for case in cases:
        found[case["id"]]["created"] = sorted(os.listdir(case["cwd"]))
        found[case["id"]]["path"] = found_paths[case["id"]]
    found["files"] = {"listing": sorted(os.listdir(files))}
    return found


@pytest.mark.parametrize("hostile", HOSTILE)
@pytest.mark.parametrize("option", OPTIONS, ids=lambda o: o.label.replace(" ", "-"))
def test_a_hostile_file_is_one_error_line(results, option: FileOption, hostile: str):
    result = results[f"{option.label} {hostile}"]
    assert not result.get("hung"), f"hung for over {CASE_TIMEOUT_S:g} s"
    assert "crashed" not in result and "not_run" not in result, result
    assert result["exception"] is None, result["exception"]
    assert result["exit_code"] == 2, result
    lines = [line for line in result["stderr"].splitlines() if line.strip()]
    lines = [line for line in lines if not line.startswith(("note: ", "warning: "))]
    assert len(lines) == 1 and lines[0].startswith("error: "), result["stderr"]
    assert "Traceback" not in result["stderr"] + result["stdout"]
    alone = all(n == option.name or not req or n in STAND_INS for n, _, req in option.inputs)
    if alone:  # beside good files only, the error is this file's
        assert result["path"] in lines[0], lines[0]
    assert result["created"] == [], f"left behind: {result['created']}"
    assert result["rise_kb"] < MEMORY_RISE_LIMIT_KB, f"peak memory rose {result['rise_kb']} kB"


def test_the_hostile_files_are_left_as_they_were(results):
    assert results["files"]["listing"] == sorted(
        ["directory", "fifo", "empty", "binary", "oversized", "nested", "loop-a", "loop-b",
         STAND_IN_FILE]
    )  # fmt: skip


def test_every_file_option_is_found_and_every_exception_is_still_there():
    names = {param.name for _, _, param in path_parameters()}
    assert OUTPUTS | DIRECTORIES <= names, (OUTPUTS | DIRECTORIES) - names
    labels = {o.label for o in OPTIONS}
    for expected in ("companion check CONFIG", "sitl run --config", "sitl campaign SPEC",
                     "companion plot LOG", "companion mission pickup --signing-key"):  # fmt: skip
        assert expected in labels, sorted(labels)
    commands = {" ".join((o.tool, *o.command)) for o in OPTIONS}
    assert commands <= set(REQUIRED), commands - set(REQUIRED)


if __name__ == "__main__":
    _child(sys.argv[1])
