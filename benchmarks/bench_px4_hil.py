"""PX4 in the loop (``sitl run --autopilot px4``): real-time factor in lockstep, and what bounds it.

Runs :class:`sitl.hil.Px4InTheLoop` in this process exactly as ``sitl run --autopilot px4``
does (``configs/sitl_pickup.toml``: 1 kHz Pinocchio plant, the arm's XM430s on a pty,
gripper, object, ground; PX4 SITL from ``PX4_SITL_DIR`` with airframe 3011, motion capture,
HIL_SENSOR at 250 Hz), flat out (speed 1000: the loop never sleeps, so the lockstep pair
runs as fast as it can). A pymavlink client on PX4's onboard link sets the global origin
(motion capture), arms and sends NAV_TAKEOFF; the window is measured hovering in Hold,
``--settle`` simulated seconds after take-off, for ``--seconds`` simulated seconds:

- the real-time factor (simulated seconds per wall-clock second);
- where the wall time of one IMU period (4 ms simulated) goes: our physics (4 plant steps
  with the servos, gripper, ground), making and sending the sensor messages, waiting for
  PX4's answer (PX4's modules run: sensors, EKF2, commander, controllers, allocation,
  logger; plus the loopback round trip);
- the CPU seconds per simulated second of this process and of PX4 (``/proc``);
- with ``--profile``, the 15 most expensive functions of the loop (cProfile, cumulative).

Numbers only; the machine's load shows in them (``os.getloadavg`` is printed).
Run: ``PX4_SITL_DIR=../shared/px4-sitl python benchmarks/bench_px4_hil.py [--seconds 20]``.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import math
import os
import pstats
import threading
import time
from pathlib import Path

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from sitl.hil import HilOptions, Px4InTheLoop
from sitl.px4_sitl.launcher import Px4Build
from sitl.scenario import load_scenario
from sitl.vehicle.launch import free_udp_port
from sitl.vehicle.options import LinkPorts, RunOptions

CONFIG = Path(__file__).resolve().parent.parent / "configs" / "sitl_pickup.toml"
ORIGIN = (47.397742, 8.545594, 488.0)


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process and its threads."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _command(conn, command: int, *params: float) -> int | None:
    """COMMAND_LONG to PX4; its COMMAND_ACK result (None without one in 2 s)."""
    values = list(params) + [0.0] * (7 - len(params))
    conn.mav.command_long_send(conn.target_system, 1, command, 0, *values)
    ack = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=2.0)
    while ack is not None and ack.command != command:
        ack = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=2.0)
    return None if ack is None else ack.result


def fly(conn) -> None:
    """Global origin, arm (retried while PX4 refuses), take off."""
    conn.wait_heartbeat(timeout=30)
    lat, lon, alt = ORIGIN
    conn.mav.set_gps_global_origin_send(
        conn.target_system, round(lat * 1e7), round(lon * 1e7), round(alt * 1e3)
    )
    deadline = time.monotonic() + 60.0
    while _command(conn, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0) != 0:
        if time.monotonic() > deadline:
            raise SystemExit("PX4 did not arm")
        time.sleep(0.5)
    nan = math.nan
    if _command(conn, mavlink.MAV_CMD_NAV_TAKEOFF, nan, 0, 0, nan, nan, nan, nan) != 0:
        raise SystemExit("PX4 refused NAV_TAKEOFF")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="simulated window [s]")
    parser.add_argument("--settle", type=float, default=10.0, help="after take-off [s]")
    parser.add_argument("--profile", action="store_true", help="cProfile the loop")
    args = parser.parse_args()
    build = Px4Build.from_env()
    if build is None:
        raise SystemExit("set PX4_SITL_DIR to a PX4 SITL build")
    ports = LinkPorts(
        onboard_local=free_udp_port(),
        onboard_remote=free_udp_port(),
        gcs_local=free_udp_port(),
        gcs_remote=free_udp_port(),
    )
    options = RunOptions(speed=1000.0, ports=ports)
    vehicle = Px4InTheLoop(load_scenario(CONFIG), options, HilOptions(build, nice=0))
    stop = threading.Event()
    ready = threading.Event()
    result: dict = {}
    profiler = cProfile.Profile() if args.profile else None

    def loop() -> None:
        run = lambda: vehicle.run(stop, on_ready=lambda _: ready.set())  # noqa: E731
        result["stats"] = profiler.runcall(run) if profiler else run()

    with vehicle:
        thread = threading.Thread(target=loop, name="hil-loop")
        thread.start()
        try:
            if not ready.wait(120.0):
                raise SystemExit("PX4 did not get ready")
            conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{ports.onboard_remote}")
            fly(conn)
            takeoff_s = vehicle.world.time_s
            while vehicle.world.time_s < takeoff_s + args.settle:
                time.sleep(0.05)
            assert vehicle.px4 is not None and vehicle.px4.process is not None
            px4_pid = vehicle.px4.process.pid
            start = _snapshot(vehicle, px4_pid)
            while vehicle.world.time_s < start["sim"] + args.seconds:
                time.sleep(0.05)
            end = _snapshot(vehicle, px4_pid)
            height = float(vehicle.world.state.q[2])
        finally:
            stop.set()
            thread.join()
    vehicle_stats = result.get("stats")
    if vehicle_stats is None:
        raise SystemExit("the simulator loop ended without its statistics")
    stats = {k: end[k] - start[k] for k in start}
    sim = stats["sim"]
    print(f"load average {os.getloadavg()[0]:.2f}; PX4 {build.root}")
    print(
        f"boot: PX4 ready after {vehicle_stats.boot_sim_s:.1f} s simulated, "
        f"{vehicle_stats.boot_wall_s:.1f} s wall"
    )
    print(
        f"hover at {height:.2f} m, window {sim:.1f} s simulated in {stats['wall']:.1f} s wall: "
        f"real-time factor {sim / stats['wall']:.2f}"
    )
    frames = stats["frames"]
    print(f"per IMU period ({1e3 * vehicle.frame_s:.0f} ms simulated, {frames:.0f} periods):")
    for key, label in (
        ("physics", f"physics ({vehicle.steps_per_frame} plant steps, servos, ground)"),
        ("sensors", "sensor messages (make, encode, send)"),
        ("px4", "waiting for PX4's answer"),
    ):
        print(
            f"  {label:<48} {1e6 * stats[key] / frames:7.0f} us "
            f"({100 * stats[key] / stats['wall']:4.1f} % of wall)"
        )
    print(
        f"CPU per simulated second: this process {stats['cpu_self'] / sim:.3f} s, "
        f"PX4 {stats['cpu_px4'] / sim:.3f} s"
    )
    if profiler is not None:
        out = io.StringIO()
        pstats.Stats(profiler, stream=out).sort_stats("cumulative").print_stats(15)
        print(out.getvalue())


def _snapshot(vehicle: Px4InTheLoop, px4_pid: int) -> dict[str, float]:
    s = vehicle.stats
    assert s is not None
    return {
        "sim": vehicle.world.time_s,
        "wall": time.perf_counter(),
        "frames": s.frames,
        "physics": s.physics_s,
        "sensors": s.sensors_s,
        "px4": s.px4_wait_s,
        "cpu_self": time.process_time(),
        "cpu_px4": _cpu_s(px4_pid),
    }


if __name__ == "__main__":
    main()
