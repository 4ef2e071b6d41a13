"""The compiled twins against their Python source: time per call of what runs every step.

The XM430 servo's per-step physics (in ``sitl.vehicle_step``: one servo's ``set_state``,
``step`` and ``torque_n_m``, as the plant calls them for every servo at every 1 kHz step),
the PX4-like attitude loop (in ``sitl.vehicle_step``: one
``Px4AttitudeLoop.update`` of the default scenario's loop at a tilted attitude) and the
truth plant's integration step (``sitl.vehicle_step``: one
``ArticulatedIntegrator.step`` of the default scenario's model under a rotor wrench,
semi-implicit Euler and RK4, the state in its buffer) and the companion's control step
(``companion.control.control_step``: one ``CompiledStep.step`` of the default scenario's
controller, RLS estimator with the attitude feed-forward). Prints the best of
``--repeat`` runs of ``--calls`` calls, for the compiled twin and for the Python source::

    python benchmarks/bench_compiled_twins.py
"""

from __future__ import annotations

import argparse
import functools
import timeit
from pathlib import Path

import numpy as np

from arm_driver.dynamixel import control_table as ct
from companion.compiled import twin, twin_reason
from companion.control import control_step
from companion.control.compiled_step import CompiledStep
from companion.control.flight import FlightControl
from companion.control.laws import DesiredState, PassivityController
from sitl import vehicle_step
from sitl.physics import attitude_control, rotors
from sitl.physics.articulation import build_articulation
from sitl.physics.attitude_control import AttitudeLoopParams, AttitudeSetpoint, Px4AttitudeLoop
from sitl.physics.frames import (
    quaternion_from_euler,
)
from sitl.physics.integration import ArticulatedIntegrator, BodyWrench, IntegratorMethod
from sitl.physics.rotors import RotorGeometry, SequentialDesaturationMixer
from sitl.scenario import load_scenario
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
    module = vehicle_step if not compiled else attitude_control._LOOP
    saved = attitude_control._LOOP, rotors._STEP
    attitude_control._LOOP = rotors._STEP = module
    try:
        seconds = timeit.repeat(
            lambda: loop.update(q, (0.1, -0.2, 0.05), setpoint), number=calls, repeat=repeat
        )
    finally:
        attitude_control._LOOP, rotors._STEP = saved
    return min(seconds) / calls * 1e6


def integration_step_us(method: IntegratorMethod, compiled: bool, calls: int, repeat: int) -> float:
    """Microseconds per ArticulatedIntegrator.step (the sitl_pickup.toml model, 1 kHz) on
    from a tilted, moving state under a hover wrench without torque."""
    scenario = load_scenario(ROOT / "configs" / "sitl_pickup.toml")
    integrator = ArticulatedIntegrator(
        build_articulation(scenario).model, 1e-3, method, compiled=compiled
    )
    phi, theta, psi = 0.05, -0.03, 0.4
    w, qx, qy, qz = quaternion_from_euler(phi, theta, psi).tolist()
    x = [0.1, 0.2, 1.0, qx, qy, qz, w, 0.3, -0.4]
    u = [0.1, -0.05, 0.02, 0.01, 0.02, -0.03, 0.2, -0.1]
    assert integrator.load(x, u, (phi, theta, psi)) == 0
    force = BodyWrench(20.0, (0.0, 0.0, 0.0), (0.3, 0.3, 0.5), (0.1, -0.05))
    seconds = timeit.repeat(
        lambda: integrator.step(force),
        number=calls,
        repeat=repeat,
    )
    return min(seconds) / calls * 1e6


def control_step_us(compiled: bool, calls: int, repeat: int) -> float:
    """Microseconds per CompiledStep.step (the sitl_pickup.toml controller and estimator,
    the estimator on this cycle's inputs) near hover."""
    config = load_scenario(ROOT / "configs" / "sitl_pickup.toml").beliefs
    control = FlightControl(config, compiled=False)
    law = control.controller
    assert isinstance(law, PassivityController)
    step = CompiledStep(
        twin(control_step) if compiled else control_step,
        control.model.params.vector(),
        control.estimator,
        law,
        np.asarray(config.controller.lambda_, dtype=float),
        control.tilt,
        control.trim,
        control.thrust,
        control.tilt_max_rad,
        attitude_inverse=control.attitude_inverse,
    )
    q = np.array([0.1, -0.2, 1.5, 0.02, -0.03, 0.3, -1.2, 0.4])
    q_dot = np.full(8, 0.05)
    desired = DesiredState(q + 0.01, np.zeros(8), np.zeros(8))
    applied = control.applied_force(q, 20.0, np.array([0.1, -0.05]))
    seconds = timeit.repeat(
        lambda: step.step(0.008, q, q_dot, q_dot, desired, applied), number=calls, repeat=repeat
    )
    return min(seconds) / calls * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=50_000)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    for module in (vehicle_step, control_step):
        reason = twin_reason(module)
        if reason is not None:
            raise SystemExit(f"bench_compiled_twins: {reason}")
    for title, measure in (
        ("XM430 servo, set_state + step + torque_n_m per servo and plant step", servo_step_us),
        ("PX4-like attitude loop, Px4AttitudeLoop.update per plant step", attitude_loop_us),
        (
            "Integration step, semi-implicit Euler, ArticulatedIntegrator.step per plant step",
            functools.partial(integration_step_us, "semi_implicit_euler"),
        ),
        (
            "Integration step, RK4, ArticulatedIntegrator.step per plant step",
            functools.partial(integration_step_us, "rk4"),
        ),
        ("Companion control step, CompiledStep.step per control cycle", control_step_us),
    ):
        fast = measure(True, args.calls, args.repeat)
        slow = measure(False, args.calls // 10, args.repeat)
        print(f"{title} [us]")
        print(f"  compiled twin {fast:8.2f}")
        print(f"  Python source {slow:8.2f}  ({slow / fast:.1f}x the twin)")


if __name__ == "__main__":
    main()
