"""The truth plant's compiled twin against its Python source: the vehicle's step
(``sitl.vehicle_step``: the attitude loop, the rotors, the integration step).

Each is one source built twice: the two builds agree bit for bit on random states and
inputs, failures included. The step is reached through its public caller,
``ArticulatedIntegrator`` (compiled or not), whose state lives in its work buffer (the
fields of ``vehicle_step.LAYOUT``), and its kinematics is checked against the frames
functions; ``Px4AttitudeLoop.update`` agrees with its parts called one by one.
"""

from __future__ import annotations

import math
from array import array
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from arm_driver.dynamixel import control_table as ct
from arm_driver.errors import HardwareErrorStatus
from arm_driver.joint import GripperConfig
from companion.compiled import twin, twin_reason
from sitl import vehicle_step
from sitl.physics import (
    AttitudeSetpoint,
    EulerSingularityError,
    PlantDivergedError,
    TruthPlant,
)
from sitl.physics.articulation import build_articulation
from sitl.physics.attitude_control import AttitudeLoopParams, Px4AttitudeLoop
from sitl.physics.battery import LipoPack
from sitl.physics.frames import (
    euler_from_rotation9,
    euler_rate_matrix_inverse9,
    quaternion_from_euler,
    rotation9_from_quaternion,
)
from sitl.physics.integration import ArticulatedIntegrator, BodyWrench, GeneralizedForce
from sitl.physics.rotors import (
    RotorBank,
    RotorGeometry,
    SequentialDesaturationMixer,
    inverse_thrust_curve,
)
from sitl.scenario import load_scenario
from sitl.servo import XM430Servo
from sitl.vehicle.world import GripperJaw

CONFIGS = Path(__file__).parent.parent / "configs"
_OVERLOADS = vehicle_step.LAYOUT["servo_overloads"][0]
PAPER = load_scenario(CONFIGS / "paper_sim.toml")
TOL = 1e-12


def _state(rng: np.random.Generator, phi: float, theta: float, u: list[float]):
    """(x, u) in Pinocchio's layout at attitude (phi, theta, random psi), with their
    rotation, Euler angles (psi unwrapped to another turn), our q_dot and W^-1 (of the pitch
    at most 90 deg - 2e-6 rad, where it exists), as the plant keeps them."""
    psi = rng.uniform(-3.1, 3.1)
    w, qx, qy, qz = quaternion_from_euler(phi, theta, psi).tolist()
    x = [*rng.normal(0, 2, 3), qx, qy, qz, w, *rng.normal(0, 2, 2)]
    r9 = rotation9_from_quaternion(w, qx, qy, qz)
    euler = (phi, theta, psi + 2.0 * math.pi)
    wi = euler_rate_matrix_inverse9(
        phi, math.copysign(min(abs(theta), 0.5 * math.pi - 2e-6), theta)
    )
    ox, oy, oz = u[3:6]
    qd = [*u[0:3], ox + wi[1] * oy + wi[2] * oz, wi[4] * oy + wi[5] * oz]
    qd += [wi[7] * oy + wi[8] * oz, u[6], u[7]]
    return x, u, r9, euler, qd, wi


def _case(rng: np.random.Generator, case: int):
    """A random state, or (case 1-4) one whose step fails: 1 the pitch 5e-7 rad short of
    +-90 deg (W(Phi) singular for a generalized force, the new state for a wrench), 2 pitch
    1.5e-6 rad short of it and pitching on (the new state singular), 3 a NaN body rate
    (diverged), 4 joint angles whose sum overflows (the new state non-finite)."""
    u = rng.normal(0.0, 2.0, 8).tolist()
    phi, theta = rng.uniform(-1.2, 1.2, 2)
    if case in (1, 2):
        sign = float(rng.choice([-1.0, 1.0]))
        phi, theta = 0.0, sign * (0.5 * math.pi - (5e-7 if case == 1 else 1.5e-6))
        u = [0.0, 0.0, 0.0, 0.0, sign * 1e-3, 0.0, 0.0, 0.0]
    state = _state(rng, phi, theta, u)
    if case == 3:
        state[1][3] = math.nan
    if case == 4:
        state[0][7:9] = [1.7e308, 1.7e308]
        state[1][6:8] = [0.0, 0.0]
    return state


def _force(rng: np.random.Generator, kind: str, held: bool) -> GeneralizedForce | BodyWrench:
    """A random force of ``kind``, or zero (only gravity: the vehicle ``held`` on course)."""
    if kind == "generalized":
        return GeneralizedForce([0.0] * 8 if held else rng.normal(0, 5, 8).tolist())
    if held:
        return BodyWrench(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0))
    b = rng.normal(0, 1, 12).tolist()
    return BodyWrench(
        20.0 + b[0], (b[1], b[2], b[3]), (0.3, 0.2, 0.1), (b[7], b[8]), (b[9], b[10], b[11])
    )


def _bits(values) -> list:
    """The float bits (and the integer statuses) of nested tuples and lists."""
    if isinstance(values, (list, tuple)):
        return [b for v in values for b in _bits(v)]
    return [values if isinstance(values, int) else float(values).hex()]


def _place(integ: ArticulatedIntegrator, state) -> None:
    """The state (x, u, R, Euler angles, q_dot, W^-1, and q) into the integrator's buffer,
    its other fields zero."""
    values = dict(zip(("x", "u", "rotation", "euler", "q_dot", "w_inv"), state, strict=True))
    x, euler = values["x"], values["euler"]
    values["q"] = [*x[0:3], *euler, x[7], x[8]]
    for name, (offset, size) in vehicle_step.LAYOUT.items():
        integ.work[offset : offset + size] = array("d", values.get(name, [0.0] * size))


def _fields(integ: ArticulatedIntegrator) -> dict[str, list[float]]:
    """The state's fields in the integrator's buffer."""
    return {
        name: integ.work[offset : offset + size].tolist()
        for name, (offset, size) in vehicle_step.LAYOUT.items()
    }


def _python_kinematics(x, u, euler_previous):
    """TruthPlant's kinematics by the frames functions, as the step returns them."""
    px, py, pz, qx, qy, qz, qw, e1, e2 = x
    n = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    n = -n if qw < 0.0 else n
    qx, qy, qz, qw = qx / n, qy / n, qz / n, qw / n
    r = rotation9_from_quaternion(qw, qx, qy, qz)
    phi, theta, psi = euler_from_rotation9(r, euler_previous)
    wi = euler_rate_matrix_inverse9(phi, theta)
    ox, oy, oz = u[3:6]
    q = [px, py, pz, phi, theta, psi, e1, e2]
    qd = [u[0], u[1], u[2], ox + wi[1] * oy + wi[2] * oz]
    qd += [wi[4] * oy + wi[5] * oz, wi[7] * oy + wi[8] * oz, u[6], u[7]]
    x_n = [px, py, pz, qx, qy, qz, qw, e1, e2]
    return [x_n, list(u), [qw, qx, qy, qz], r, (phi, theta, psi), wi, u[3:6], q, qd]


def _flat(values) -> np.ndarray:
    return np.concatenate([np.ravel(np.asarray(v, dtype=float)) for v in values])


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
@pytest.mark.parametrize("kind", ["generalized", "wrench"])
def test_the_integration_step_twin_is_its_python_source_bit_for_bit(integrator, kind) -> None:
    """GIVEN random states and forces, and states whose step fails in each way WHEN the
    compiled twin and the Python source of sitl.vehicle_step each step, evaluate
    q_ddot without a step and load the state with its kinematics THEN every status and the
    states in their work buffers have the same bits; the step's q_ddot is the
    acceleration's, and the kinematics of a random state's step is the frames functions' to
    1e-12."""
    assert twin_reason(vehicle_step) is None, twin_reason(vehicle_step)
    model = build_articulation(PAPER).model
    compiled = ArticulatedIntegrator(model, 1e-3, integrator)
    source = ArticulatedIntegrator(model, 1e-3, integrator, compiled=False)
    assert compiled._step is twin(vehicle_step) is not vehicle_step
    assert source._step is vehicle_step
    rng = np.random.default_rng(7)
    statuses: Counter[int] = Counter()
    for i in range(200):
        case = i % 5 if i < 100 else 0
        state = _case(rng, case)
        x, u, _, euler, _, _ = state
        force = _force(rng, kind, held=case in (1, 2))
        results = []
        for integ in (compiled, source):
            _place(integ, state)
            out = integ.step(force)
            stepped = _fields(integ)
            _place(integ, state)
            a = integ.acceleration(force)
            accelerated = _fields(integ)
            _place(integ, state)
            k = integ.load(x, u, euler)
            loaded = _fields(integ)
            results.append(_bits((out, *stepped.values(), a, *accelerated.values(), k)))
            results[-1] += _bits(list(loaded.values()))
        assert results[0] == results[1]
        statuses[out] += 1
        if out == 0:
            assert _bits(accelerated["acceleration"]) == _bits(stepped["q_ddot"])
        if case == 0:
            expected = _python_kinematics(stepped["x"], stepped["u"], euler)
            names = ("x", "u", None, "rotation", "euler", "w_inv", None, "q", "q_dot")
            got = [stepped[n] for n in names if n is not None]
            want = [v for n, v in zip(names, expected, strict=True) if n is not None]
            np.testing.assert_allclose(_flat(got), _flat(want), rtol=0, atol=TOL)
    if kind == "wrench":
        failures = {1, 3, 4}  # a wrench is defined at any pitch
    elif integrator == "rk4":
        failures = {1, 2, 3}  # a later stage of case 2 reaches the singularity first
    else:
        failures = {1, 2, 3, 4}
    assert statuses[0] > 100 and failures <= set(statuses), statuses


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
@pytest.mark.parametrize("battery", [True, False])
def test_the_rotor_step_twin_is_its_parts_and_its_python_source_bit_for_bit(
    integrator, battery
) -> None:
    """GIVEN random states, rotor thrusts, commands and joint torques, and states whose step
    fails WHEN the compiled twin and the Python source of sitl.vehicle_step
    each take the rotor plant's step in one call (rotor_step), and the compiled twin takes
    it in parts (the pack's draw, the rotor wrench as a BodyWrench step, the rotors' lag)
    THEN statuses, the states in the work buffers, the rotors' and the pack's buffers have
    the same bits in all three; a failed step leaves the rotors' thrusts as they were."""
    model = build_articulation(PAPER).model
    compiled = ArticulatedIntegrator(model, 1e-3, integrator)
    source = ArticulatedIntegrator(model, 1e-3, integrator, compiled=False)
    parts = ArticulatedIntegrator(model, 1e-3, integrator)
    rotors = PAPER.vehicle.rotors
    geometry = RotorGeometry.hexa_x(rotors.arm_length_m, rotors.yaw_moment_per_thrust_m)
    rows = geometry.wrench_matrix()[:3].tolist()
    drag, wind, max_thrust = (0.3, 0.2, 0.1), (1.0, -0.5, 0.2), 6.3
    for integ in (compiled, source):
        integ.set_rotor_wrench(rows, drag, wind, max_thrust)
    rng = np.random.default_rng(11)
    statuses: Counter[int] = Counter()
    for i in range(120):
        case = i % 5 if i < 60 else 0
        state = _case(rng, case)
        thrusts = rng.uniform(0.0, 6.0, 6).tolist()
        commands = rng.uniform(0.0, 1.0, 6).tolist()
        joint = rng.normal(0.0, 1.0, 2).tolist()
        charge = float(rng.uniform(0.05, 1.0))
        results = []
        for integ in (compiled, source):
            bank = RotorBank(max_thrust, 0.3, 0.025, 1e-3)
            bank.reset(thrusts)
            pack = LipoPack(4, 2.0, 0.05, charge) if battery else None
            _place(integ, state)
            out = integ.rotor_step(
                commands, joint, bank.buffer, None if pack is None else pack.buffer
            )
            results.append(
                _bits(
                    (
                        out,
                        *_fields(integ).values(),
                        bank.buffer.tolist(),
                        [] if pack is None else pack.buffer.tolist(),
                    )
                )
            )
        bank = RotorBank(max_thrust, 0.3, 0.025, 1e-3)
        bank.reset(thrusts)
        pack = LipoPack(4, 2.0, 0.05, charge) if battery else None
        if pack is not None:
            pack.draw(bank.thrust_list_n, 1e-3)
            bank.max_thrust_n = max_thrust * pack.thrust_factor
        t = bank.thrust_list_n
        torque = tuple(
            row[0] * t[0]
            + row[1] * t[1]
            + row[2] * t[2]
            + row[3] * t[3]
            + row[4] * t[4]
            + row[5] * t[5]
            for row in rows
        )
        wrench = BodyWrench(sum(t), torque, drag, (joint[0], joint[1]), wind)  # type: ignore[arg-type]
        _place(parts, state)
        out = parts.step(wrench)
        if out == 0:
            bank.advance(commands)
        else:
            assert bank.thrust_list_n == thrusts
        fields = _fields(parts)
        fields.update(commands=commands, thrusts=t, joint_torques=joint)
        results.append(
            _bits(
                (
                    out,
                    *fields.values(),
                    bank.buffer.tolist(),
                    [] if pack is None else pack.buffer.tolist(),
                )
            )
        )
        assert results[0] == results[1] == results[2]
        statuses[out] += 1
    assert statuses[0] > 60 and {1, 3} <= set(statuses), statuses


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
def test_the_vehicle_step_twin_is_the_loop_then_the_rotor_step_bit_for_bit(integrator) -> None:
    """GIVEN random states, attitude setpoints (many saturating the mixer), joint torques
    and loops with random THR_MDL_FAC WHEN the compiled twin and the Python source each
    take the vehicle's step in one call (vehicle_step), and the compiled twin takes it in
    parts (Px4AttitudeLoop.commands at the state's attitude and body rate, then rotor_step)
    THEN statuses, the states and the actuator signals in the work buffers, the loops'
    buffers, the rotors' and the pack's buffers have the same bits in all three; the joint
    torques are clipped to the servos' limit, and a NaN one changes nothing."""
    model = build_articulation(PAPER).model
    integrators = [
        ArticulatedIntegrator(model, 1e-3, integrator),
        ArticulatedIntegrator(model, 1e-3, integrator, compiled=False),
        ArticulatedIntegrator(model, 1e-3, integrator),
    ]
    rotors = PAPER.vehicle.rotors
    geometry = RotorGeometry.hexa_x(rotors.arm_length_m, rotors.yaw_moment_per_thrust_m)
    limit = 0.8
    for integ in integrators:
        integ.set_rotor_wrench(
            geometry.wrench_matrix()[:3].tolist(), (0.3, 0.2, 0.1), (1.0, -0.5, 0.2), 6.3
        )
        integ.set_servo_limit(limit)
    rng = np.random.default_rng(13)
    statuses: Counter[int] = Counter()
    saturated = 0
    for i in range(150):
        case = i % 5 if i < 50 else 0
        state = _case(rng, case)
        thrusts = rng.uniform(0.0, 6.0, 6).tolist()
        joint = rng.normal(0.0, 1.0, 2).tolist()
        if i == 7:
            joint[1] = math.nan
        setpoint = AttitudeSetpoint.from_euler(*rng.uniform(-1.5, 1.5, 3), rng.uniform(0, 1))
        seed = int(rng.integers(1 << 30))
        charge = float(rng.uniform(0.05, 1.0))
        results = []
        for k, integ in enumerate(integrators):
            loop = _loop(np.random.default_rng(seed))
            bank = RotorBank(6.3, 0.3, 0.025, 1e-3)
            bank.reset(thrusts)
            pack = LipoPack(4, 2.0, 0.05, charge)
            _place(integ, state)
            if k < 2:
                out = integ.vehicle_step(setpoint, joint, loop, bank.buffer, pack.buffer)
                _, _, _, rate_sp, torque = integ.actuator_signals()
            elif i == 7:
                out, rate_sp, torque = 5, (0.0,) * 3, (0.0,) * 3  # nothing done
            else:
                commands, rate_sp, torque = loop.commands(*integ.attitude(), setpoint)
                clipped = [min(max(j, -limit), limit) for j in joint]
                out = integ.rotor_step(commands, clipped, bank.buffer, pack.buffer)
            fields = _fields(integ)
            fields["rate_setpoint"] = list(rate_sp)  # rotor_step leaves them as they were
            fields["torque"] = list(torque)
            buffers = [b.tolist() for b in loop.buffers]
            results.append(
                _bits((out, *fields.values(), *buffers, bank.buffer.tolist(), pack.buffer.tolist()))
            )
        assert results[0] == results[1] == results[2]
        statuses[out] += 1
        saturated += any(loop.buffers[4])
    assert statuses[0] > 100 and {1, 3} <= set(statuses), statuses
    assert saturated > 20, saturated


@pytest.mark.parametrize("direction", [1, -1])
def test_the_vehicle_step_couples_the_servos_as_they_couple_themselves(direction) -> None:
    """GIVEN random states, two joint XM430s and a gripper XM430 with its jaw, holding
    positions WHEN the compiled twin and the Python source take the vehicle's step coupled
    to the servos (shaft = zero offset + direction * eta; the gripper's on the jaw), and
    the compiled twin takes it under the torques of the servos' own couple, the jaw moved
    by its own advance, and the servos' own steps after it THEN statuses, the work buffers,
    the servos' control tables and loops and the jaws have the same bits in all three; the
    buffer keeps the joints' angles and rates at the start of the step, the servos' torques
    and overloads (some servos pushing at their overload current for longer than their
    overload time)."""
    model = build_articulation(PAPER).model
    integrators = [
        ArticulatedIntegrator(model, 1e-3, "semi_implicit_euler"),
        ArticulatedIntegrator(model, 1e-3, "semi_implicit_euler", compiled=False),
        ArticulatedIntegrator(model, 1e-3, "semi_implicit_euler"),
    ]
    zeros = (0.3, -0.2)
    for integ in integrators:
        integ.set_servo_limit(0.8)
        integ.set_joint_servos([(zeros[0], direction), (zeros[1], direction)])
    rng = np.random.default_rng(17)
    overloads_seen = 0
    for _ in range(60):
        state = _case(rng, 0)
        setpoint = AttitudeSetpoint.from_euler(*rng.uniform(-0.5, 0.5, 3), rng.uniform(0, 1))
        goals = rng.uniform(-1.0, 1.0, 3)
        overload_s = rng.choice([0.0, 5.0])
        results = []
        for k, integ in enumerate(integrators):
            servos = [XM430Servo(i + 1, angle_rad=float(goals[i])) for i in range(3)]
            jaw = GripperJaw(GripperConfig(3, open_position_rad=0.8, closed_position_rad=-0.25))
            for servo in servos:
                servo.write(ct.TORQUE_ENABLE.address, b"\x01")
                servo._overload_s = float(overload_s)  # as if it had pushed that long
            loop = _loop(np.random.default_rng(5))
            bank = RotorBank(6.3, 0.3, 0.025, 1e-3)
            _place(integ, state)
            eta, eta_dot = state[0][7:9], state[1][6:8]
            if k < 2:
                buffers = [b for servo in servos for b in servo.physics_buffers]
                buffers.append(jaw.buffer)
                out = integ.vehicle_step(setpoint, None, loop, bank.buffer, None, tuple(buffers))
                overloads = integ.work[_OVERLOADS : _OVERLOADS + 3].tolist()
                for servo, flag in zip(servos, overloads, strict=True):
                    if flag:
                        servo.overloaded()
            else:
                torques = [
                    direction * s.couple(z + direction * e, direction * r)
                    for s, z, e, r in zip(servos, zeros, eta, eta_dot, strict=False)
                ]
                jaw.advance(servos[2].couple(jaw.angle_rad, jaw.rate_rad_s), 1e-3)
                out = integ.vehicle_step(setpoint, torques, loop, bank.buffer, None)
                for servo in servos:
                    servo.step(1e-3)
            fields = _fields(integ)
            if k == 2:
                overloaded = [
                    float(bool(s.hardware_error & HardwareErrorStatus.OVERLOAD)) for s in servos
                ]
                fields.update(arm_start=[*eta, *eta_dot], servo_torques=torques)
                fields.update(servo_overloads=overloaded, stepped=[1.0])
            else:
                assert fields["arm_start"] == [*eta, *eta_dot]
            tables = [bytes(s.table) for s in servos]
            tables += _bits([s.physics_buffers[1].tolist() for s in servos] + [jaw.buffer.tolist()])
            results.append(_bits((out, *fields.values(), bank.buffer.tolist())) + tables)
        assert results[0] == results[1] == results[2]
        assert out == 0
        overloads_seen += any(s.hardware_error for s in servos)
    assert overloads_seen > 5


def test_the_acceleration_is_the_steps_q_ddot() -> None:
    """GIVEN a plant in motion WHEN q_ddot is evaluated under tau, then a step taken under
    it THEN the step's q_ddot is that q_ddot, bit for bit."""
    plant = TruthPlant.from_scenario(PAPER, "ideal")
    rng = np.random.default_rng(3)
    q = np.array(PAPER.simulation.initial_q) + rng.normal(0.0, 0.2, 8)
    plant.reset(q, rng.normal(0.0, 0.5, 8))
    tau = rng.normal(0.0, 3.0, 8)
    q_ddot = plant.acceleration(tau)
    assert _bits(q_ddot.tolist()) == _bits(plant.step_ideal(tau).q_ddot.tolist())


def _loop(rng: np.random.Generator) -> Px4AttitudeLoop:
    cfg = PAPER.plant.attitude_control
    params = AttitudeLoopParams.from_config(cfg, float(rng.uniform(0.0, 0.9)))
    rotors = PAPER.vehicle.rotors
    geometry = RotorGeometry.hexa_x(rotors.arm_length_m, rotors.yaw_moment_per_thrust_m)
    mixer = SequentialDesaturationMixer(geometry, rotors.max_thrust_per_rotor_n)
    return Px4AttitudeLoop.from_params(params, mixer, 1e-3)


def test_the_attitude_loop_twin_is_its_python_source_bit_for_bit() -> None:
    """GIVEN the same loop's constants and state twice WHEN the compiled twin and the Python
    source of the attitude loop in sitl.vehicle_step each run 2000 steps of
    random attitudes, rates and setpoints (many saturating) THEN commands, relative
    thrusts, rate setpoints, torques, the rate controller's state and the saturation flags
    have the same bits."""
    assert twin_reason(vehicle_step) is None, twin_reason(vehicle_step)
    compiled = twin(vehicle_step)
    rng = np.random.default_rng(5)
    saturated = 0
    for _ in range(10):
        seed = int(rng.integers(1 << 30))
        loops = [_loop(np.random.default_rng(seed)) for _ in range(2)]
        for _ in range(200):
            q = tuple(quaternion_from_euler(*rng.uniform(-1.5, 1.5, 3)).tolist())
            rate = tuple(rng.normal(0.0, 2.0, 3).tolist())
            setpoint = AttitudeSetpoint.from_euler(*rng.uniform(-1.5, 1.5, 3), rng.uniform(0, 1))
            bits = []
            for module, loop in zip((compiled, vehicle_step), loops, strict=True):
                relative = array("d", [0.0] * 6)
                commands, rate_sp, torque = module.attitude_loop(
                    q,
                    rate,
                    setpoint.quaternion_wxyz,
                    setpoint.thrust,
                    loop.attitude._constants,
                    loop.rate._constants,
                    loop.rate._state,
                    loop.mixer._constants,
                    loop._saturation,
                    loop.thr_mdl_fac,
                    relative,
                )
                values = [*commands, *relative, *rate_sp, *torque, *loop.rate._state]
                bits.append([float(v).hex() for v in (*values, *loop._saturation)])
            assert bits[0] == bits[1]
            saturated += any(loops[0]._saturation)
    assert saturated > 100  # the desaturation and anti-windup paths ran


def test_the_attitude_loop_is_its_parts_in_a_row() -> None:
    """GIVEN the same loop twice WHEN one runs update and the other its parts one by one
    (rate_setpoint, rate.update with the previous saturation, mixer.mix, the THR_MDL_FAC
    inverse) over random attitudes, rates and setpoints, many saturating THEN every output
    and the rate controller's state agree."""
    rng = np.random.default_rng(9)
    saturated = 0
    for _ in range(20):
        seed = int(rng.integers(1 << 30))
        compiled, reference = _loop(np.random.default_rng(seed)), _loop(np.random.default_rng(seed))
        flags = ((False,) * 3, (False,) * 3)
        for _ in range(100):
            q = tuple(quaternion_from_euler(*rng.uniform(-1.5, 1.5, 3)).tolist())
            rate = tuple(rng.normal(0.0, 2.0, 3).tolist())
            setpoint = AttitudeSetpoint.from_euler(*rng.uniform(-1.5, 1.5, 3), rng.uniform(0, 1))
            out = compiled.update(q, rate, setpoint)  # type: ignore[arg-type]
            rate_sp = reference.attitude.rate_setpoint(q, setpoint.quaternion_wxyz)
            torque = reference.rate.update(rate, rate_sp, *flags)  # type: ignore[arg-type]
            mixed = reference.mixer.mix(torque, setpoint.thrust)
            flags = (mixed.saturation_positive, mixed.saturation_negative)
            saturated += any(flags[0] + flags[1])
            rel = np.array(mixed.relative_thrusts)
            commands = inverse_thrust_curve(rel, reference.thr_mdl_fac)
            np.testing.assert_allclose(out.rate_setpoint_rad_s, rate_sp, rtol=0, atol=TOL)
            np.testing.assert_allclose(out.torque_normalized, torque, rtol=0, atol=TOL)
            np.testing.assert_allclose(out.relative_thrusts, rel, rtol=0, atol=TOL)
            np.testing.assert_allclose(out.motor_commands, commands, rtol=0, atol=1e-9)
            np.testing.assert_allclose(
                compiled.rate.integral, reference.rate.integral, rtol=0, atol=TOL
            )
            np.testing.assert_allclose(
                compiled.rate.angular_acceleration_estimate,
                reference.rate.angular_acceleration_estimate,
                rtol=0,
                atol=TOL,
            )
    assert saturated > 100  # the desaturation and anti-windup paths ran


def test_compiled_step_raises_the_plants_errors() -> None:
    """GIVEN pitch 1.5 urad short of 90 deg, pitching up at 1 mrad/s WHEN one step ends
    within 1 urad of it THEN the new state cannot be reported (EulerSingularityError) and
    time has moved on; a non-finite acceleration is a PlantDivergedError at the time of
    the failed step."""
    plant = TruthPlant.from_scenario(PAPER, "ideal")
    q = np.array(PAPER.simulation.initial_q)
    q[4] = 0.5 * math.pi - 1.5e-6
    plant.reset(q, [0.0, 0.0, 0.0, 0.0, 1e-3, 0.0, 0.0, 0.0])
    with pytest.raises(EulerSingularityError):
        plant.step_ideal(np.zeros(8))
    assert plant.time_s == pytest.approx(plant.dt_s)
    plant = TruthPlant.from_scenario(PAPER, "ideal")
    with pytest.raises(PlantDivergedError) as failure:
        plant.step_ideal([0.0] * 6 + [1.7e308, 0.0])  # overflows through the small inertia
    assert failure.value.time_s == 0.0
