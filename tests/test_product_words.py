"""The product speaks of the product: no stop, issue or session numbers of its development
in code, comments, configs, tests or docs (they belong in commit messages)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).parent.parent
PROCESS_WORDS = re.compile(r"\b(stop|issue|session) [0-9]+", re.IGNORECASE)


def tracked_files() -> list[Path]:
    try:
        done = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: the tracked files are unknown")
    return [ROOT / name for name in done.stdout.decode().split("\0") if name]


def test_no_development_process_words_in_the_product():
    found = []
    for path in tracked_files():
        try:
            text = path.read_text(encoding="utf-8")
        except (UnicodeDecodeError, FileNotFoundError, IsADirectoryError):
            continue  # binary files; a symbolic link's directory
        for number, line in enumerate(text.splitlines(), start=1):
            if PROCESS_WORDS.search(line):
                found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()[:100]}")
    assert not found, "\n".join(found)


def test_the_check_finds_what_it_looks_for():
    number = "2" + "0"  # not written whole here: this file is scanned too
    assert PROCESS_WORDS.search(f"as seen in CI at stop {number}")
    assert PROCESS_WORDS.search(f"(Issue {number})")
    assert not PROCESS_WORDS.search("stops at 20 s; the issue is the wind")
