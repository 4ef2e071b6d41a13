"""Latency of the MAVLink link: state message in -> SET_ATTITUDE_TARGET out, at 250 Hz.

A peer process (pymavlink's codec on a loopback UDP socket, acting as PX4) sends ODOMETRY
at 250 Hz, each stamped with its send time (``time_usec`` = CLOCK_MONOTONIC [us], the
clock ``time.monotonic_ns`` reads in every process). In this process a
:class:`companion.link.MavlinkLink` (``udpout`` to the peer) decodes it; a trivial
handler, subscribed to :class:`VehiclePose`, answers each pose with a SET_ATTITUDE_TARGET
carrying the pose's millisecond stamp. Printed, median and 99th percentile:

- ``in -> out``: from the peer's send to our SET_ATTITUDE_TARGET leaving
  ``send_attitude_target`` (the reader's receive -> setpoint sent, plus one loopback hop,
  so an upper bound of it; target p99 <= 2 ms);
- ``round trip``: measured by the peer, from its send to the setpoint's arrival;
- the CPU share of one core this process used while streaming (reader, decoding, fan-out,
  handler and heartbeat; no estimator or controller).

Run: ``python benchmarks/bench_link.py [--seconds S] [--rate HZ]``.
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing as mp
import select
import socket
import time

import numpy as np
from pymavlink.dialects.v20 import common as m

from companion.link import MavlinkLink, VehiclePose


def _peer(conn, seconds: float, rate_hz: float) -> None:
    """The PX4 side: ODOMETRY at ``rate_hz``, round trips of the setpoints."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    conn.send(sock.getsockname()[1])
    data, addr = sock.recvfrom(65535)  # the link's first heartbeat

    class Out:
        def write(self, buf):
            sock.sendto(bytes(buf), addr)

    mav = m.MAVLink(Out(), 1, 1)
    mav.heartbeat_send(m.MAV_TYPE_HEXAROTOR, m.MAV_AUTOPILOT_PX4, 0, 0, 4)
    time.sleep(0.5)
    sent: dict[int, int] = {}
    round_trips = []
    period_ns = int(1e9 / rate_hz)
    ticks = int(seconds * rate_hz)
    next_ns = time.monotonic_ns()
    sock.setblocking(False)
    for k in range(ticks):
        if k % int(rate_hz) == 0:
            mav.heartbeat_send(m.MAV_TYPE_HEXAROTOR, m.MAV_AUTOPILOT_PX4, 0, 0, 4)
        now = time.monotonic_ns()
        sent[now // 1_000_000 & 0xFFFFFFFF] = now
        mav.odometry_send(
            now // 1000, 1, 1, 1.0, 2.0, -3.0, [1, 0, 0, 0], 0, 0, 0, 0, 0, 0,
            [0] * 21, [0] * 21, 0, 0, 0,
        )  # fmt: skip
        next_ns += period_ns
        while (wait := next_ns - time.monotonic_ns()) > 0:
            if select.select([sock], [], [], wait / 1e9)[0]:
                data = sock.recv(65535)
                arrived = time.monotonic_ns()
                for msg in mav.parse_buffer(data) or ():
                    if msg.get_type() == "SET_ATTITUDE_TARGET" and msg.time_boot_ms in sent:
                        round_trips.append(arrived - sent.pop(msg.time_boot_ms))
    conn.send((ticks, round_trips))
    sock.close()


async def _app(port: int, seconds: float) -> tuple[list[int], float, object, int]:
    latencies: list[int] = []
    async with MavlinkLink(f"udpout://127.0.0.1:{port}") as link:
        poses = link.subscribe(VehiclePose, maxsize=16)
        await link.wait_vehicle(10.0)
        cpu0, wall0 = time.process_time(), time.monotonic()

        async def handler() -> None:
            async for _pose in poses:
                odometry = link.latest("ODOMETRY")  # the message this pose came from
                link.send_attitude_target((1.0, 0.0, 0.0, 0.0), 0.5, odometry.time_usec // 1000)
                latencies.append(time.monotonic_ns() - odometry.time_usec * 1000)

        task = asyncio.create_task(handler())
        await asyncio.sleep(seconds + 0.5)
        cpu_share = (time.process_time() - cpu0) / (time.monotonic() - wall0)
        task.cancel()
        stats = link.stats
    return latencies, cpu_share, stats, poses.dropped


def _summary(label: str, values_ns) -> str:
    us = np.asarray(values_ns, dtype=float) / 1000.0
    return (
        f"{label:>12}: median {np.median(us):7.1f} us, p99 {np.percentile(us, 99):7.1f} us, "
        f"max {us.max():7.1f} us  (n = {us.size})"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rate", type=float, default=250.0, help="ODOMETRY rate [Hz]")
    args = parser.parse_args()
    ours, theirs = mp.Pipe()
    peer = mp.Process(target=_peer, args=(theirs, args.seconds, args.rate))
    peer.start()
    port = ours.recv()
    latencies, cpu_share, stats, dropped = asyncio.run(_app(port, args.seconds))
    ticks, round_trips = ours.recv()
    peer.join()
    warm = latencies[int(args.rate) :]  # skip the first second (imports, caches)
    print(f"MAVLink link, ODOMETRY at {args.rate:g} Hz for {args.seconds:g} s, loopback UDP")
    print(_summary("in -> out", warm))
    print(_summary("round trip", round_trips[int(args.rate) :]))
    print(f"{'answered':>12}: {len(round_trips)} of {ticks} ODOMETRY; queue drops {dropped}")
    print(f"{'CPU':>12}: {100 * cpu_share:.1f} % of one core (link + trivial handler)")
    print(f"{'counters':>12}: {stats}")


if __name__ == "__main__":
    main()
