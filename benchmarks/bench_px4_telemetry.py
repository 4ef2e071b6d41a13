"""Cost of the simulated PX4 per simulated second: state machine + telemetry + encoding.

Runs the pure vehicle at the 1 kHz plant rate on a fixed hovering measurement (armed,
AUTO.LOITER, in the air) with the default stream rates on both links, and packs every
outgoing message as the endpoint would (MAVLink 2, unsigned and signed). Prints the wall
time per simulated second and the messages per simulated second; the real-time factor
the PX4 side alone allows is 1 / (wall time per simulated second).

Run: ``python benchmarks/bench_px4_telemetry.py [--seconds N]``.
"""

from __future__ import annotations

import argparse
import time

from pymavlink.dialects.v20 import common as mavlink

from sitl.physics.frames import quaternion_from_euler
from sitl.px4 import Px4Params, Px4Vehicle, VehicleMeasurement


def run(seconds: float, signed: bool) -> tuple[float, int]:
    """Wall seconds and message count for ``seconds`` of simulated flight."""
    vehicle = Px4Vehicle(Px4Params())
    mav = mavlink.MAVLink(None, 1, 1)
    if signed:
        mav.signing.secret_key = bytes(32)
        mav.signing.sign_outgoing = True
    q = quaternion_from_euler(0.01, -0.02, 0.3)
    arm = mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
    arm._header.srcSystem, arm._header.srcComponent = 255, 190
    vehicle.handle(arm, "onboard", 0.0)
    steps = round(seconds * 1000)
    count = 0
    start = time.perf_counter()
    for k in range(steps):
        t = k * 1e-3
        m = VehicleMeasurement(t, [1, 2, 3], [0.1, 0, 0], q, [0, 0, 0.1], [0, 0, 9.81], False)
        vehicle.control(t, m)
        for _, msg in vehicle.telemetry(t, m):
            msg.pack(mav)
            count += 1
    return time.perf_counter() - start, count


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="simulated seconds")
    args = parser.parse_args()
    for signed in (False, True):
        wall, count = run(args.seconds, signed)
        per_s = wall / args.seconds
        print(
            f"{'signed' if signed else 'unsigned':>8}: {per_s * 1e3:7.1f} ms wall per simulated s"
            f" ({count / args.seconds:.0f} messages/s), PX4-side real-time limit {1 / per_s:.0f}x"
        )


if __name__ == "__main__":
    main()
