"""The product speaks of the product: no stop, issue or session numbers and no dates of its
development in code, comments, configs, tests or docs (they belong in commit messages)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).parent.parent
PROCESS_WORDS = re.compile(
    r"\b(stops?|issues?|sessions?)(?: #?|-|#)?[0-9]+"
    r"|\b[0-9]{1,2} (Jan|Feb|Mar|Apr|May|Jun|Jul|Aug|Sep|Oct|Nov|Dec)[a-z]*\.? 20[0-9]{2}\b"
    r"|\([0-9]{1,2} (Jan|Feb|Mar|Apr|May|Jun|Jul|Aug|Sep|Oct|Nov|Dec)[a-z]*\)"
    r"|\bmeasured 20[0-9]{2}-[0-9]{2}-[0-9]{2}\b"
    r"|\b(later|second|third|first) session\b",
    re.IGNORECASE,
)
"""Stop, issue and session numbers; dates of development (a day and month with a year, a day
and month in brackets, an ISO date after "measured"); sessions counted. Dates that are data
(a signing epoch, a boot time, a config stamp written by the product) are none of these
forms."""


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
    assert PROCESS_WORDS.search(f"issues {number} and 16's comparison")
    assert PROCESS_WORDS.search(f"(Issue {number})")
    assert not PROCESS_WORDS.search("stops at 20 s; the issue is the wind")
    assert PROCESS_WORDS.search(f"the issue-{number} acceptance")
    assert PROCESS_WORDS.search(f"fixed at stop #{number}")
    year = "20" + "26"
    assert PROCESS_WORDS.search(f"on the 2-core VM of 2 Dec {year} the step")
    assert PROCESS_WORDS.search("stalls injected into the companion (" + "3 Dec):")
    assert PROCESS_WORDS.search(f"(measured {year}-12-02, before the change)")
    assert PROCESS_WORDS.search("as measured in a later " + "session")
    assert not PROCESS_WORDS.search("10 us units since 2015-01-01 00:00:00 UTC")
    assert not PROCESS_WORDS.search(f"boots at {year}-01-01 00:00 UTC")
