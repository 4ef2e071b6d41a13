"""``flight.html``: one page per flight that opens offline (no network, no other file): the
outcome, the summary (``summary.json``), the figures embedded as base64 PNGs, and the
event log (``flight.events.csv``). Written beside them by ``companion mission`` and
``sitl demo`` once the figures are drawn.
"""

from __future__ import annotations

import base64
import csv
import html
import json
from pathlib import Path
from typing import Any

from companion.cli.plot import FIGURES

__all__ = ["FLIGHT_PAGE", "write_flight_page"]

FLIGHT_PAGE = "flight.html"

_STYLE = """
body { font-family: sans-serif; margin: 2em; max-width: 1100px; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 3px 8px; text-align: left; vertical-align: top; }
th { background: #eee; }
td pre { margin: 0; white-space: pre-wrap; }
img { max-width: 100%; }
"""


def _cell(value: Any) -> str:
    if isinstance(value, dict | list):
        return f"<pre>{html.escape(json.dumps(value, indent=1))}</pre>"
    if isinstance(value, float):
        return f"{value:.6g}"
    return html.escape(str(value))


def write_flight_page(out_dir: Path) -> Path | None:
    """Write ``out_dir/flight.html`` from the flight's summary, figures and events found
    there; None (nothing written) without a ``summary.json``."""
    summary_path = out_dir / "summary.json"
    if not summary_path.exists():
        return None
    summary: dict[str, Any] = json.loads(summary_path.read_text())
    outcome = "completed" if summary.get("completed") else "did not complete"
    failure = summary.get("failure")
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>Flight {html.escape(out_dir.name)}</title><style>{_STYLE}</style></head><body>",
        f"<h1>Flight {html.escape(out_dir.name)}</h1>",
        f"<p><b>The mission {outcome}.</b>"
        + (f" {html.escape(str(failure))}" if failure else "")
        + "</p>",
    ]
    for name in FIGURES:
        png = out_dir / name
        if png.exists():
            data = base64.b64encode(png.read_bytes()).decode("ascii")
            parts.append(f"<h2>{html.escape(name)}</h2><img src='data:image/png;base64,{data}'>")
    parts += ["<h2>Summary</h2>", "<table>"]
    parts += [f"<tr><th>{html.escape(k)}</th><td>{_cell(v)}</td></tr>" for k, v in summary.items()]
    parts.append("</table>")
    events = out_dir / "flight.events.csv"
    if events.exists():
        with events.open(newline="") as f:
            rows = list(csv.reader(f))
        if rows:
            parts += ["<h2>Events</h2>", "<table>"]
            parts.append("<tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in rows[0]) + "</tr>")
            parts += [
                "<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>"
                for row in rows[1:]
            ]
            parts.append("</table>")
    parts.append("</body></html>")
    path = out_dir / FLIGHT_PAGE
    path.write_text("\n".join(parts), encoding="utf-8")
    return path
