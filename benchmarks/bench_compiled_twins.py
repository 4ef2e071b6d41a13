"""The compiled twins against their Python source: time per call of what runs every step.

Today's twin is the XM430 servo's per-step physics (``sitl.servo.xm430_loop``): one
servo's ``set_state``, ``step`` and ``torque_n_m``, as the plant calls them for every servo
at every 1 kHz step. Prints the best of ``--repeat`` runs of ``--calls`` calls, for the
compiled twin and for the Python source::

    python benchmarks/bench_compiled_twins.py
"""

from __future__ import annotations

import argparse
import timeit

from arm_driver.dynamixel import control_table as ct
from companion.compiled import twin_reason
from sitl.servo import xm430_loop
from sitl.servo.xm430 import XM430Servo


def servo_step_us(compiled: bool, calls: int, repeat: int) -> float:
    """Microseconds per set_state + step + torque_n_m of a servo holding its position."""
    servo = XM430Servo(1, angle_rad=0.1, compiled=compiled)
    servo.write(ct.TORQUE_ENABLE.address, bytes([1]))

    def once() -> None:
        servo.set_state(0.1, 0.01)
        servo.step(1e-3)
        servo.torque_n_m()

    return min(timeit.repeat(once, number=calls, repeat=repeat)) / calls * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=50_000)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    reason = twin_reason(xm430_loop)
    if reason is not None:
        raise SystemExit(f"bench_compiled_twins: {reason}")
    fast = servo_step_us(True, args.calls, args.repeat)
    slow = servo_step_us(False, args.calls // 10, args.repeat)
    print("XM430 servo, set_state + step + torque_n_m per servo and plant step [us]")
    print(f"  compiled twin {fast:8.2f}")
    print(f"  Python source {slow:8.2f}  ({slow / fast:.1f}x the twin)")


if __name__ == "__main__":
    main()
