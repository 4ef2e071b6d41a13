"""The live view: the flight log's channels on a Foxglove WebSocket server started on the
MCAP writer's context, read by a WebSocket client speaking Foxglove's protocol as the
Foxglove app does (subscribe by channel id, binary message frames, Protobuf messages decoded
with the advertised schemas)."""

from __future__ import annotations

import asyncio
import base64
import json
import math
import queue
import re
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from test_mcap_log import decode
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

from companion.control.setpoints import AttitudeThrustSetpoint
from companion.logs.flightlog import CycleRecord
from companion.logs.live_view import LiveView, LiveViewError
from companion.logs.mcap_log import CHANNELS, SCHEMAS, ArmGeometry, FlightLogWithMcap, time_ns

ROOT = Path(__file__).parent.parent
GEOMETRY = ArmGeometry((0.05, 0.0, -0.08), 0.2, 0.15)
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01  # Foxglove WebSocket protocol: a binary frame carrying a message


def record(t: float) -> CycleRecord:
    q = np.array([1.0, 2.0, 3.0, 0.1, -0.2, 0.3, -math.pi / 2, 0.0])
    return CycleRecord(
        t_vehicle_s=t,
        q=q,
        q_dot=np.zeros(8),
        q_ddot=np.zeros(8),
        q_d=q,
        theta_hat=(0.2, 0.02, 0.004),
        setpoint=AttitudeThrustSetpoint(0.1, -0.05, 0.3, 20.0, 0.45, True, False),
        loop_period_ms=4.0,
        phase="lift",
        px4_mode="OFFBOARD",
    )


class Client:
    """A Foxglove WebSocket client: the advertised channels, then every message of the
    subscribed topics as (topic, log time [ns], decoded message)."""

    def __init__(self, url: str, topics: tuple[str, ...]) -> None:
        self.url, self.topics = url, topics
        self.channels: dict[str, dict] = {}
        self.messages: list[tuple[str, int, dict]] = []
        self.subscribed = threading.Event()

    async def run(self, seconds: float) -> None:
        """Read for ``seconds`` or until the server closes the connection."""
        async with connect(self.url, subprotocols=SUBPROTOCOLS) as ws:  # type: ignore[arg-type]
            by_subscription: dict[int, str] = {}
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                try:
                    frame = await asyncio.wait_for(ws.recv(), end - time.monotonic())
                except (TimeoutError, ConnectionClosed):
                    return
                if isinstance(frame, str):
                    self._control(json.loads(frame), by_subscription)
                    if by_subscription and not self.subscribed.is_set():
                        subscriptions = [
                            {"id": sub, "channelId": self.channels[topic]["id"]}
                            for sub, topic in by_subscription.items()
                        ]
                        await ws.send(
                            json.dumps({"op": "subscribe", "subscriptions": subscriptions})
                        )
                        self.subscribed.set()
                elif frame[0] == MESSAGE_DATA:
                    sub, log_ns = struct.unpack_from("<IQ", frame, 1)
                    topic = by_subscription[sub]
                    channel = self.channels[topic]
                    schema = base64.b64decode(channel["schema"])
                    message = decode(channel["schemaName"], "protobuf", schema, frame[13:])
                    self.messages.append((topic, log_ns, message))

    def _control(self, message: dict, by_subscription: dict[int, str]) -> None:
        if message["op"] == "advertise":
            for channel in message["channels"]:
                self.channels[channel["topic"]] = channel
            for n, topic in enumerate(self.topics, start=1):
                if topic in self.channels:
                    by_subscription[n] = topic

    def topic(self, name: str) -> list[tuple[int, dict]]:
        return [(ns, m) for topic, ns, m in self.messages if topic == name]


def read(url: str, topics: tuple[str, ...], seconds: float) -> tuple[Client, threading.Thread]:
    """A client reading in a thread (the server under test may run in this one)."""
    client = Client(url, topics)
    thread = threading.Thread(target=asyncio.run, args=(client.run(seconds),), daemon=True)
    thread.start()
    return client, thread


# -- the server on hand-made records -----------------------------------------------------


def test_every_channel_is_advertised_with_its_schema_and_messages_arrive_stamped(tmp_path):
    """The file's writer serves the live view: what a block of cycles writes to the file
    reaches the client too, with the file's schemas."""
    with FlightLogWithMcap(tmp_path / "flight.csv", GEOMETRY, block_rows=2) as log:
        context = log.mcap.context
        assert context is not None
        with LiveView(0, context) as live:
            assert live.port > 0 and live.url == f"ws://127.0.0.1:{live.port}"
            client, thread = read(live.url, ("/tf", "/estimate", "/events"), 5.0)
            assert client.subscribed.wait(5.0)
            deadline = time.monotonic() + 5.0
            while not client.topic("/events") and time.monotonic() < deadline:
                log.event("probe", "until the server has taken the subscription", 0.5)
                time.sleep(0.05)
            log.write(record(1.0))  # with its events (mode, phase): written at once
            log.write(record(1.004))
            log.write(record(1.008))  # a full block of two
            log.event("fault", "payload_lost: the payload slipped", 1.010)
            deadline = time.monotonic() + 5.0
            while client.topic("/events")[-1][1]["name"] != "fault" and (
                time.monotonic() < deadline
            ):
                time.sleep(0.05)
            thread.join(timeout=0.1)
        thread.join(timeout=5.0)
    assert set(client.channels) == set(CHANNELS)
    for topic, channel in client.channels.items():
        assert channel["schemaName"] == CHANNELS[topic]
        assert channel["encoding"] == "protobuf" and channel["schemaEncoding"] == "protobuf"
        assert base64.b64decode(channel["schema"]) == SCHEMAS[CHANNELS[topic]]
    tf = client.topic("/tf")
    assert [ns for ns, _ in tf] == [time_ns(1.0), time_ns(1.004), time_ns(1.008)]
    base = tf[0][1]["transforms"][0]
    assert (base["parent_frame_id"], base["child_frame_id"]) == ("world", "base_link")
    assert base["translation"] == {"x": 1.0, "y": 2.0, "z": 3.0}
    assert client.topic("/estimate")[0][1]["lc_m"] == pytest.approx(0.1)
    events = client.topic("/events")
    assert [e["name"] for _, e in events if e["name"] != "probe"] == ["mode", "phase", "fault"]
    ns, event = events[-1]
    assert ns == time_ns(1.010) and event["level"] == 4  # ERROR: a fault
    assert event["message"] == "payload_lost: the payload slipped"


def test_a_taken_port_and_a_bad_port_are_clear_errors(tmp_path):
    with FlightLogWithMcap(tmp_path / "flight.csv", GEOMETRY) as log:
        context = log.mcap.context
        assert context is not None
        with LiveView(0, context) as live:
            with pytest.raises(LiveViewError, match=f"127.0.0.1:{live.port}"):
                LiveView(live.port, context).open()
        with pytest.raises(LiveViewError, match="0-65535"):
            LiveView(70000, context)


def test_the_live_option_is_checked_before_anything_flies(run_sitl, tmp_path):
    done = run_sitl("demo", "--clock", "virtual", "--live", "70000", "--out", str(tmp_path / "o"))
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "error: --live must be a TCP port, 0-65535 (0: any free port), got 70000"
    ]
    assert not (tmp_path / "o").exists()
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = run_sitl(
            "demo", "--clock", "virtual", "--live", str(port), "--out", str(tmp_path / "p")
        )
    assert done.returncode == 2
    assert done.stderr.strip().startswith(f"error: --live: live view on 127.0.0.1:{port}")
    assert "Traceback" not in done.stderr


# -- a demo watched while it flies -------------------------------------------------------


@pytest.mark.slow
def test_a_client_watches_the_demo_while_it_flies(tmp_path):
    demo = subprocess.Popen(
        [sys.executable, "-c", "from sitl.cli import main; main()", "demo", "--clock", "virtual",
         "--live", "0", "--out", str(tmp_path / "demo")],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )  # fmt: skip
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in demo.stdout], daemon=True).start()
    try:
        url = None
        while url is None:
            line = lines.get(timeout=60)
            found = re.search(r"live view: (ws://127\.0\.0\.1:\d+)", line)
            url = found.group(1) if found else None
        started = time.monotonic()
        client, thread = read(url, ("/tf", "/vehicle/pose", "/events"), 300.0)
        thread.join(timeout=300.0)  # the server closes when the flight ends
        watched_s = time.monotonic() - started
        assert demo.wait(timeout=120) == 0
    finally:
        demo.kill()
    output = "".join(lines.queue)
    assert "mission completed" in output
    poses = client.topic("/vehicle/pose")
    assert len(poses) >= 10  # the flight, seen while it flew
    assert watched_s > 0.0
    times = [ns for ns, _ in poses]
    assert times == sorted(times) and times[-1] - times[0] > 30e9  # vehicle time, most of it
    heights = [m["pose"]["position"]["z"] for _, m in poses]
    assert max(heights) > 1.0  # it took off (cruise at 1.5 m)
    kinds = {m["name"] for _, m in client.topic("/events")}
    assert kinds  # the mission's events too
    assert len(client.topic("/tf")) == len(poses)
