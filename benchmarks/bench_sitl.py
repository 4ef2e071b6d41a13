"""The whole SITL vehicle (``SitlVehicle.run``): real-time factor, telemetry rates, step jitter.

Runs the vehicle of ``configs/sitl_pickup.toml`` in this process exactly as ``sitl run``
does (1 kHz underactuated plant, three XM430 servo models on a pty, gripper, payload,
ground, battery, noisy navigation, the PX4-like autopilot, both MAVLink links with their
default telemetry streams, no truth log). Before the measured run the vehicle is armed
and sent NAV_TAKEOFF through the autopilot's message handler, so it flies (take-off,
then hold at MIS_TAKEOFF_ALT) rather than idling on the ground. A separate client
process (pymavlink's parser on plain UDP sockets) listens on both links' remote ports
and counts what arrives.

1. Real-time factor: ``run`` flat out (``--speed 1000``, the pacing never sleeps) for
   ``--seconds`` simulated seconds, once with nobody listening (datagrams to closed
   loopback ports) and once with the client consuming both links; with the CPU time of
   this process per simulated second (less sensitive than wall time to other processes
   on a loaded machine).
   Also the time per step split by phase (links in, navigation, autopilot, world,
   telemetry out), from a separate instrumented loop with the same calls, airborne (from
   3.5 simulated seconds after the take-off command): the main thread's CPU time per phase
   (``time.thread_time``, what the step costs whatever else runs on the machine) and the
   wall time of the whole.
2. At speed 1 for ``--rate-seconds``: each stream's rate as the client measures it
   (messages after the first, over the wall time between first and last arrival)
   against the configured rate (and the count per simulated second: the streams keep
   their rates in simulation time even when the loaded machine cannot keep real time),
   and the step-start lateness (jitter) median / p99 / max that ``run`` reports. The
   window starts after 5 simulated seconds, hovering.

Numbers only, no pass/fail; the machine's load shows in them (``os.getloadavg`` is
printed). Each figure of part 1 is the best of ``--repeat`` runs (noise only ever adds
time). ``--before DIR`` also measures part 1 on the code in DIR (a checkout of an earlier
commit with its C extensions built in place, e.g. ``git worktree add /tmp/before a08a115
&& cd /tmp/before && python setup.py build_ext --inplace``) in a subprocess, alternating
with this code, and prints both. ``--rate-seconds 0`` skips part 2.
Run: ``python benchmarks/bench_sitl.py [--seconds 10] [--rate-seconds 20] [--repeat 3]
[--before DIR]``.
"""

from __future__ import annotations

import argparse
import json
import os
import select
import socket
import subprocess
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")

from checkout import now_and_before
from pymavlink.dialects.v20 import common as mavlink
from pymavlink.dialects.v20 import development

CONFIG = Path(__file__).resolve().parent.parent / "configs" / "sitl_pickup.toml"


# ------------------------------------------------------------------ client process


def client(onboard_port: int, gcs_port: int) -> None:
    """Count messages per link and type until stdin closes; print JSON arrival times."""
    socks = {}
    for name, port in (("onboard", onboard_port), ("gcs", gcs_port)):
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", port))
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        socks[sock] = (name, mavlink.MAVLink(None))
    arrivals: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    print("listening", flush=True)
    watched = [*socks, sys.stdin]
    while True:
        ready, _, _ = select.select(watched, [], [], 1.0)
        now = time.perf_counter()
        if sys.stdin in ready and not sys.stdin.readline():
            break
        for sock in ready:
            if sock is sys.stdin:
                continue
            name, mav = socks[sock]
            data = sock.recv(65535)
            try:
                messages = mav.parse_buffer(data) or []
            except Exception:  # count what decodes; a benchmark client never stops
                messages = []
            for msg in messages:
                arrivals[name][msg.get_type()].append(now)
    print(json.dumps(arrivals), flush=True)


class Client:
    """The client process: start, wait until it listens, stop and collect its counts."""

    def __init__(self, onboard_port: int, gcs_port: int) -> None:
        self._proc = subprocess.Popen(
            [sys.executable, __file__, "--client", str(onboard_port), str(gcs_port)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self._proc.stdout is not None
        if self._proc.stdout.readline().strip() != "listening":
            raise RuntimeError("benchmark client did not start")

    def stop(self) -> dict[str, dict[str, list[float]]]:
        assert self._proc.stdin is not None and self._proc.stdout is not None
        self._proc.stdin.close()
        out = self._proc.stdout.read()
        self._proc.wait(timeout=30)
        return json.loads(out)


# ------------------------------------------------------------------ vehicle side


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _vehicle(speed: float):
    from sitl.scenario import load_scenario
    from sitl.vehicle.options import LinkPorts, RunOptions
    from sitl.vehicle.runner import SitlVehicle

    ports = LinkPorts(
        onboard_local=_free_port(),
        onboard_remote=_free_port(),
        gcs_local=_free_port(),
        gcs_remote=_free_port(),
    )
    # GPS aiding: the vehicle arms in Hold without a global origin being set first
    options = RunOptions(speed=speed, seed=1, navigation="gps", ports=ports)
    return SitlVehicle(load_scenario(CONFIG), options)


def _take_off(vehicle) -> None:
    """Arm and NAV_TAKEOFF through the autopilot's handler, as if from the onboard link."""
    client_mav = mavlink.MAVLink(None, 255, 190)
    for command in (
        mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0),
        mavlink.MAVLink_command_long_message(1, 1, 22, 0, 0, 0, 0, 0, *[float("nan")] * 3),
    ):
        msg = mavlink.MAVLink(None).parse_buffer(command.pack(client_mav))[0]
        for link, reply in vehicle.autopilot.handle(msg, "onboard", vehicle.world.time_s):
            vehicle.links[link].send(reply)


def real_time_factor(seconds: float, with_client: bool) -> tuple[float, float, str]:
    """Simulated / wall seconds of ``run`` flat out for ``seconds``, this process's CPU
    seconds per simulated second, and the flight state at the end."""
    vehicle = _vehicle(speed=1000.0)
    ports = vehicle.options.ports
    listener = Client(ports.onboard_remote, ports.gcs_remote) if with_client else None
    try:
        with vehicle:
            vehicle.run(threading.Event(), until_s=0.5)  # settle on the ground
            _take_off(vehicle)
            cpu0 = time.process_time()
            stats = vehicle.run(threading.Event(), until_s=0.5 + seconds)
            cpu = (time.process_time() - cpu0) / stats.sim_time_s
            state = f"{vehicle.autopilot.mode.display_name}, z = {vehicle.world.state.q[2]:.2f} m"
    finally:
        counts = listener.stop() if listener else {}
    received = sum(len(v) for link in counts.values() for v in link.values())
    if with_client:
        state += f", client got {received / seconds:.0f} msg per sim s"
    return stats.real_time_factor, cpu, state


PHASES = ("links in", "navigation", "autopilot", "world", "telemetry")


def phase_split(seconds: float) -> dict[str, float]:
    """Main-thread CPU time per step [us] by phase, the same calls as ``SitlVehicle.run``,
    airborne; and the wall time per step of the whole (key ``wall``)."""
    vehicle = _vehicle(speed=1000.0)
    tt = time.thread_time_ns
    totals = dict.fromkeys(PHASES, 0)
    with vehicle:
        vehicle.run(threading.Event(), until_s=0.5)
        _take_off(vehicle)
        vehicle.run(threading.Event(), until_s=4.0)  # climbing, then holding
        world, autopilot, links = vehicle.world, vehicle.autopilot, vehicle.links
        steps = round(seconds / world.dt_s)
        wall0 = time.perf_counter()
        for _ in range(steps):
            t0 = tt()
            now_s = world.time_s
            for name, link in links.items():
                for message in link.receive():
                    for reply_link, reply in autopilot.handle(message, name, now_s):
                        links[reply_link].send(reply)
            t1 = tt()
            measurement = vehicle.navigation.measure(world)
            t2 = tt()
            setpoint = autopilot.control(now_s, measurement)
            t3 = tt()
            with vehicle.servo_bus.lock:
                world.step(setpoint)
            t4 = tt()
            for link_name, message in autopilot.telemetry(now_s, measurement):
                links[link_name].send(message)
            t5 = tt()
            for key, a, b in zip(PHASES, (t0, t1, t2, t3, t4), (t1, t2, t3, t4, t5), strict=True):
                totals[key] += b - a
        wall = time.perf_counter() - wall0
    out = {key: value / steps / 1e3 for key, value in totals.items()}
    out["wall"] = wall / steps * 1e6
    return out


def measure(seconds: float, repeat: int) -> dict:
    """Part 1, each figure the best of ``repeat`` runs."""
    out: dict = {}
    for with_client in (False, True):
        runs = [real_time_factor(seconds, with_client) for _ in range(repeat)]
        rtf = max(r[0] for r in runs)
        cpu = min(r[1] for r in runs)
        out["client" if with_client else "nobody"] = (rtf, cpu, runs[-1][2])
    splits = [phase_split(min(seconds, 5.0)) for _ in range(repeat)]
    out["split"] = {key: min(s[key] for s in splits) for key in splits[0]}
    return out


def _best(a: dict, b: dict) -> dict:
    out = {}
    for key in ("nobody", "client"):
        out[key] = (max(a[key][0], b[key][0]), min(a[key][1], b[key][1]), b[key][2])
    out["split"] = {k: min(a["split"][k], b["split"][k]) for k in a["split"]}
    return out


_WARM_UP_S = 5.0
"""Simulated seconds at speed 1 before the measured window: arming, take-off and its
completion (each sends an extra HEARTBEAT at once) are over by then."""


def rates_and_jitter(seconds: float):
    """At speed 1, hovering: measured stream rates per link and the run's statistics,
    over ``seconds`` after the warm-up."""
    from sitl.px4 import GCS_RATES_HZ, ONBOARD_RATES_HZ

    vehicle = _vehicle(speed=1.0)
    ports = vehicle.options.ports
    listener = Client(ports.onboard_remote, ports.gcs_remote)
    try:
        with vehicle:
            _take_off(vehicle)
            vehicle.run(threading.Event(), until_s=_WARM_UP_S)
            # perf_counter is the system's monotonic clock: the client's stamps compare
            window_start = time.perf_counter()
            stats = vehicle.run(threading.Event(), until_s=_WARM_UP_S + seconds)
    finally:
        arrivals = listener.stop()
    rows = []
    for link, configured in (("onboard", ONBOARD_RATES_HZ), ("gcs", GCS_RATES_HZ)):
        for msg_id, rate in configured.items():
            name = development.mavlink_map[msg_id].msgname  # CURRENT_MODE is not in common
            times = [t for t in arrivals.get(link, {}).get(name, []) if t >= window_start]
            measured = (len(times) - 1) / (times[-1] - times[0]) if len(times) > 2 else 0.0
            rows.append((link, name, rate, measured, len(times)))
    return rows, stats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="sim s per flat-out run")
    parser.add_argument("--rate-seconds", type=float, default=20.0, help="sim s at speed 1")
    parser.add_argument("--repeat", type=int, default=3, help="runs per figure of part 1")
    parser.add_argument("--before", type=Path, help="checkout of the code to compare with")
    parser.add_argument("--client", nargs=2, type=int, help=argparse.SUPPRESS)
    parser.add_argument("--json", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.client:
        client(*args.client)
        return
    if args.json:
        print(json.dumps(measure(args.seconds, args.repeat)))
        return
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs\n")
    now, before = now_and_before(
        lambda: measure(args.seconds, args.repeat), args.before, __file__,
        ["--seconds", str(args.seconds), "--repeat", str(args.repeat)], _best,
    )  # fmt: skip

    print(
        f"Real-time factor, 1 kHz plant, full telemetry, flat out, {args.seconds:g} sim s, "
        f"best of {args.repeat}"
    )
    print(f"{'':<8} {'telemetry':<28} {'real-time factor':>16} {'CPU s / sim s':>14}  state")
    for label, figures in (("before", before), ("now", now)):
        if figures is None:
            continue
        for key, name in (("nobody", "nobody listening"), ("client", "client on both links")):
            rtf, cpu, state = figures[key]
            print(f"{label:<8} {name:<28} {rtf:>15.2f}x {cpu:>14.3f}  {state}")

    print("\nTime per step by phase, airborne, no client: main-thread CPU [us]")
    print(f"{'':<8}" + "".join(f"{key:>12}" for key in (*PHASES, "total", "wall")))
    for label, figures in (("before", before), ("now", now)):
        if figures is None:
            continue
        split = figures["split"]
        total = sum(split[key] for key in PHASES)
        cells = [split[key] for key in PHASES] + [total, split["wall"]]
        print(f"{label:<8}" + "".join(f"{value:12.1f}" for value in cells))
    if args.rate_seconds <= 0.0:
        return

    print(
        f"\nAt speed 1 for {args.rate_seconds:g} s after a {_WARM_UP_S:g} s take-off, "
        "hovering; pymavlink client on loopback"
    )
    rows, stats = rates_and_jitter(args.rate_seconds)
    print(
        f"{'link':<8} {'message':<22} {'configured':>10} {'measured':>9} {'error':>7}"
        f" {'per sim s':>9}  n"
    )
    for link, name, rate, measured, count in rows:
        error = (measured - rate) / rate * 100.0
        flag = "" if abs(error) <= 10.0 else "  (outside 10 %)"
        per_sim_s = count / stats.sim_time_s
        print(
            f"{link:<8} {name:<22} {rate:>8.1f}Hz {measured:>7.2f}Hz {error:>+6.1f}%"
            f" {per_sim_s:>7.2f}Hz  {count}{flag}"
        )
    median, p99 = stats.jitter_us()
    worst = max(stats.lateness_us) if stats.lateness_us else 0.0
    print(
        f"\nstep jitter (lateness of each 1 ms step's start): median {median:.0f} us, "
        f"p99 {p99:.0f} us, max {worst:.0f} us; {stats.overruns} overruns; "
        f"real-time factor {stats.real_time_factor:.3f}"
    )


if __name__ == "__main__":
    main()
