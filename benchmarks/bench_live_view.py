"""What the live view costs the control loop: ``sitl demo`` (wall clock, speed 1) flown
without ``--live`` and with ``--live 0`` and a Foxglove client subscribed to every channel,
alternately, ``--pairs`` times.

Prints, and with ``--write`` puts in ``docs/live_view.md`` (machine and commit stated), per
flight: completed (or why not), faults, late cycles, the pose -> setpoint latency (median,
p99 [us]), the pose -> joint torques latency (median, p99 [us]), and for the watched
flights the messages the client received and their rate. The two sets of flights differ by
the live view only; the spread between flights of the same kind is the noise to judge the
difference against::

    python benchmarks/bench_live_view.py --pairs 2 --write
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from checkout import this_commit
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

ROOT = Path(__file__).resolve().parent.parent


async def watch(url: str, counts: dict[str, int]) -> None:
    """Subscribe to every advertised channel and count what arrives until the server
    closes (Foxglove's WebSocket protocol, as the Foxglove app speaks it)."""
    async with connect(url, subprotocols=["foxglove.sdk.v1"]) as ws:  # type: ignore[list-item]
        topics: dict[int, str] = {}
        try:
            async for frame in ws:
                if isinstance(frame, str):
                    message = json.loads(frame)
                    if message["op"] == "advertise":
                        subs = [{"id": c["id"], "channelId": c["id"]} for c in message["channels"]]
                        topics.update({c["id"]: c["topic"] for c in message["channels"]})
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                elif frame[0] == 0x01:
                    topic = topics[int.from_bytes(frame[1:5], "little")]
                    counts[topic] = counts.get(topic, 0) + 1
        except ConnectionClosed:
            return


def fly(live: bool, tmp: Path) -> dict:
    """One demo; its summary with the client's counts and watched seconds added."""
    out = Path(tempfile.mkdtemp(dir=tmp)) / "demo"
    command = [sys.executable, "-c", "from sitl.cli import main; main()", "demo", "--out", str(out)]
    demo = subprocess.Popen(
        [*command, *(["--live", "0"] if live else [])],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    counts: dict[str, int] = {}
    watcher: threading.Thread | None = None
    started = time.monotonic()
    assert demo.stdout is not None
    for line in demo.stdout:
        found = re.search(r"live view: (ws://\S+)", line)
        if found:
            started = time.monotonic()
            watcher = threading.Thread(target=asyncio.run, args=(watch(found.group(1), counts),))
            watcher.start()
    demo.wait()
    watched_s = time.monotonic() - started
    if watcher is not None:
        watcher.join(timeout=10)
    summary = json.loads((out / "summary.json").read_text())
    summary["client_messages"] = sum(counts.values()) if live else None
    summary["client_pose_hz"] = counts.get("/vehicle/pose", 0) / watched_s if live else None
    return summary


def row(live: bool, s: dict) -> list[str]:
    def pct(key: str, which: str) -> str:
        return f"{(s.get(key) or {}).get(which, float('nan')):.0f}"

    received = "-" if not live else f"{s['client_messages']} ({s['client_pose_hz']:.1f} Hz)"
    faults = ", ".join(f["fault"] for f in s["faults"]) or "-"
    return [
        "with" if live else "without",
        "yes" if s["completed"] else f"NO ({s.get('failure') or faults})",
        faults,
        str(s["late_cycles"]),
        pct("setpoint_latency_us", "median"),
        pct("setpoint_latency_us", "p99"),
        pct("cycle_latency_us", "median"),
        pct("cycle_latency_us", "p99"),
        received,
    ]


HEADER = [
    "live view",
    "completed",
    "faults",
    "late cycles",
    "pose -> setpoint p50 [us]",
    "p99 [us]",
    "pose -> torques p50 [us]",
    "p99 [us]",
    "client received (poses)",
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=2, help="flights without and with")
    parser.add_argument("--write", action="store_true", help="write docs/live_view.md")
    args = parser.parse_args()
    rows, p99 = [], {False: [], True: []}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.pairs):
            for live in (False, True):
                summary = fly(live, Path(tmp))
                rows.append(row(live, summary))
                p99[live].append(summary["setpoint_latency_us"]["p99"])
                print(" | ".join(rows[-1]), flush=True)
    spread = {k: (min(v), max(v)) for k, v in p99.items()}
    verdict = (
        f"Pose -> setpoint p99: without the live view {spread[False][0]:.0f}-"
        f"{spread[False][1]:.0f} us, with it {spread[True][0]:.0f}-{spread[True][1]:.0f} us "
        f"(medians of the flights {statistics.median(p99[False]):.0f} and "
        f"{statistics.median(p99[True]):.0f} us)."
    )
    print(verdict)
    if args.write:
        lines = [
            "# The live view's cost to the control loop",
            "",
            f"Written by `benchmarks/bench_live_view.py` on {platform.node()} "
            f"({os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at the end, "
            f"Python {platform.python_version()}), commit {this_commit()}. `sitl demo` on the "
            "wall clock at speed 1 (the vehicle in its own process), flown alternately "
            "without `--live` and with `--live 0` and a client subscribed to every channel; "
            "latencies from each flight's `summary.json`.",
            "",
            "| " + " | ".join(HEADER) + " |",
            "|" + "---|" * len(HEADER),
            *("| " + " | ".join(r) + " |" for r in rows),
            "",
            verdict,
            "",
        ]
        (ROOT / "docs" / "live_view.md").write_text("\n".join(lines))


if __name__ == "__main__":
    main()
