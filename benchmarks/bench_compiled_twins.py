"""The compiled twins against their Python source: time per call of what runs every step.

The XM430 servo's per-step physics (``sitl.servo.xm430_loop``: one servo's ``set_state``,
``step`` and ``torque_n_m``, as the plant calls them for every servo at every 1 kHz step)
and the PX4-like attitude loop (``sitl.physics.attitude_loop``: one
``Px4AttitudeLoop.update`` of the default scenario's loop at a tilted attitude). Prints the
best of ``--repeat`` runs of ``--calls`` calls, for the compiled twin and for the Python
source::

    python benchmarks/bench_compiled_twins.py
"""

from __future__ import annotations

import argparse
import timeit
from pathlib import Path

from arm_driver.dynamixel import control_table as ct
from companion.compiled import twin_reason
from sitl.physics import attitude_control, attitude_loop, rotors
from sitl.physics.attitude_control import AttitudeLoopParams, AttitudeSetpoint, Px4AttitudeLoop
from sitl.physics.rotors import RotorGeometry, SequentialDesaturationMixer
from sitl.scenario import load_scenario
from sitl.servo import xm430_loop
from sitl.servo.xm430 import XM430Servo

ROOT = Path(__file__).resolve().parent.parent


def servo_step_us(compiled: bool, calls: int, repeat: int) -> float:
    """Microseconds per set_state + step + torque_n_m of a servo holding its position."""
    servo = XM430Servo(1, angle_rad=0.1, compiled=compiled)
    servo.write(ct.TORQUE_ENABLE.address, bytes([1]))

    def once() -> None:
        servo.set_state(0.1, 0.01)
        servo.step(1e-3)
        servo.torque_n_m()

    return min(timeit.repeat(once, number=calls, repeat=repeat)) / calls * 1e6


def attitude_loop_us(compiled: bool, calls: int, repeat: int) -> float:
    """Microseconds per Px4AttitudeLoop.update (the sitl_pickup.toml loop, 1 kHz)."""
    scenario = load_scenario(ROOT / "configs" / "sitl_pickup.toml")
    vehicle = scenario.vehicle
    rotor_config = vehicle.rotors
    geometry = RotorGeometry.hexa_x(rotor_config.arm_length_m, rotor_config.yaw_moment_per_thrust_m)
    mixer = SequentialDesaturationMixer(geometry, rotor_config.max_thrust_per_rotor_n)
    params = AttitudeLoopParams.from_config(
        scenario.plant.attitude_control, rotor_config.thr_mdl_fac
    )
    loop = Px4AttitudeLoop.from_params(params, mixer, 1e-3)
    q = AttitudeSetpoint.from_euler(0.1, -0.05, 0.2, 0.5).quaternion_wxyz.tolist()
    setpoint = AttitudeSetpoint.from_euler(0.05, 0.02, 0.1, 0.45)
    module = attitude_loop if not compiled else attitude_control._LOOP
    saved = attitude_control._LOOP, rotors._LOOP
    attitude_control._LOOP = rotors._LOOP = module
    try:
        seconds = timeit.repeat(
            lambda: loop.update(q, (0.1, -0.2, 0.05), setpoint), number=calls, repeat=repeat
        )
    finally:
        attitude_control._LOOP, rotors._LOOP = saved
    return min(seconds) / calls * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=50_000)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    for module in (xm430_loop, attitude_loop):
        reason = twin_reason(module)
        if reason is not None:
            raise SystemExit(f"bench_compiled_twins: {reason}")
    for title, measure in (
        ("XM430 servo, set_state + step + torque_n_m per servo and plant step", servo_step_us),
        ("PX4-like attitude loop, Px4AttitudeLoop.update per plant step", attitude_loop_us),
    ):
        fast = measure(True, args.calls, args.repeat)
        slow = measure(False, args.calls // 10, args.repeat)
        print(f"{title} [us]")
        print(f"  compiled twin {fast:8.2f}")
        print(f"  Python source {slow:8.2f}  ({slow / fast:.1f}x the twin)")


if __name__ == "__main__":
    main()
