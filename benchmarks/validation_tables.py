"""Write the tables of docs/validation.md: each is the table ``sitl compare`` writes for the
command its marker names.

    python benchmarks/validation_tables.py          # rerun every table, rewrite the page
    python benchmarks/validation_tables.py --check  # rerun, exit 1 if the page differs

A table sits between ``<!-- sitl compare ARGS -->`` and ``<!-- end -->``; everything
outside the markers (the prose) is left as it is, and the line that starts with
"Tables written by" gets this checkout's commit. The offline runs are deterministic, so the
same code writes the same numbers on any machine; the last column of ``compare.md`` (each
law's step time, which depends on the machine) is dropped.
"""

from __future__ import annotations

import argparse
import re
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

from checkout import this_commit

ROOT = Path(__file__).resolve().parent.parent
PAGE = ROOT / "docs" / "validation.md"
BLOCK = re.compile(r"(<!-- sitl compare (?P<args>[^>]*?) -->\n)(?P<body>.*?)(<!-- end -->)", re.S)
STAMP = re.compile(r"^Tables written by .*$", re.M)


def compare_table(args: str) -> str:
    """``sitl compare ARGS``'s table and notes, without its title and its step-time column."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out"
        command = [sys.executable, "-c", "from sitl.entry import main; main()", "compare"]
        subprocess.run(
            [*command, *shlex.split(args), "--out", str(out)],
            check=True,
            cwd=ROOT,
            stdout=subprocess.DEVNULL,  # the console table; the file is what is kept
        )
        text = (out / "compare.md").read_text()
    lines = [line for line in text.splitlines() if not line.startswith("# ")]
    while lines and not lines[0].strip():
        lines.pop(0)
    table = [line.rsplit("|", 2)[0] + "|" if line.startswith("|") else line for line in lines]
    return "\n".join(table).strip() + "\n"


def rewrite(page: str, commit: str) -> str:
    def block(match: re.Match[str]) -> str:
        args = match.group("args")
        print(f"sitl compare {args}", file=sys.stderr, flush=True)
        return f"{match.group(1)}{compare_table(args)}{match.group(4)}"

    page = BLOCK.sub(block, page)
    stamp = f"Tables written by `python benchmarks/validation_tables.py` at commit {commit}."
    return STAMP.sub(stamp, page)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="Exit 1 if the page differs.")
    args = parser.parse_args()
    old = PAGE.read_text()
    if not BLOCK.search(old):
        sys.exit(f"{PAGE}: no '<!-- sitl compare ARGS -->' markers")
    new = rewrite(old, this_commit())
    if args.check:
        unstamped = (STAMP.sub("", old), STAMP.sub("", new))
        sys.exit(0 if unstamped[0] == unstamped[1] else f"{PAGE} differs from what the code writes")
    PAGE.write_text(new)
    print(f"wrote {PAGE}")


if __name__ == "__main__":
    main()
