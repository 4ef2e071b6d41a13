"""Backends for the arm bus conformance suite (``tests/test_arm_conformance.py``).

Modelled on python-can's back2back tests: one set of tests, several backends. Each
:class:`Harness` starts what its bus talks to and offers the same view of the device
side, so a test can check what a servo was told (goal torque, goal angle, torque on)
and inject faults:

- ``dynamixel``: XM430 models on a pty (:class:`sitl.servo.PtyServoBus`);
- ``dronecan``: actuator models behind a DroneCAN node on a python-can virtual bus
  (:class:`sitl.servo.DroneCanActuatorNode`);
- ``hardware``: the bus at ``$ARM_BUS_URL`` (joints from the ``arm_bus`` section of
  ``$ARM_BUS_CONFIG`` if set, else :data:`JOINTS`). Nothing on the device side can be
  inspected or injected, so tests that need it skip; the silent-host test runs when
  the URL sets ``watchdog_ms``.

In both emulators each shaft sits on an inertia (:class:`sitl.servo.JointRig`), so
position goals converge and torques move the joints.
"""

from __future__ import annotations

import os
import uuid
from contextlib import ExitStack
from typing import Any

import pytest

from arm_driver.bus import GripperConfig, JointConfig
from arm_driver.dynamixel import control_table as ct
from arm_driver.dynamixel import units
from arm_driver.errors import HardwareError, HardwareErrorStatus
from arm_driver.url import parse_bus_url
from sitl.servo import (
    CanActuator,
    CanActuatorParameters,
    CommandType,
    DroneCanActuatorNode,
    Faults,
    JointRig,
    PtyServoBus,
    XM430Servo,
)

KT = 4.1 / 2.3
JOINTS = (
    JointConfig("shoulder", 1, KT, torque_max_n_m=2.0),
    JointConfig("elbow", 2, KT, torque_max_n_m=1.5, direction=-1, zero_offset_rad=0.5),
)
GRIPPER = GripperConfig(3, open_position_rad=0.8, closed_position_rad=-0.2)
ANGLE_TOLERANCE_RAD = 4e-3
"""Worst read-back resolution: DroneCAN's float16 near 2 rad (2e-3), XM430 ticks (1.5e-3)."""


class Harness:
    """What a conformance test needs from a backend; device-side views skip on hardware."""

    name = "abstract"
    url = ""
    joints: tuple[JointConfig, ...] = JOINTS
    gripper: GripperConfig | None = GRIPPER
    timeout_bound_s = 0.0
    """Largest ``BusTimeoutError.timeout_s`` the configured options allow [s]."""
    command_timeout_s: float | None = None
    """How long a device keeps a torque command once the host goes quiet [s] (Dynamixel:
    the Bus Watchdog of ``watchdog_ms``; DroneCAN: the actuator's command timeout);
    None: for ever (the test of it skips)."""

    def close(self) -> None:
        """Stop what the harness started."""

    def _device(self) -> Any:
        pytest.skip(f"{self.name}: the device side cannot be inspected or faulted")

    def torque_on(self, servo_id: int) -> bool:
        """The device drives its output."""
        return self._device()

    def goal_torque_n_m(self, servo_id: int) -> float:
        """The device's goal torque, in the servo's frame [N m]."""
        return self._device()

    def goal_angle_rad(self, servo_id: int) -> float:
        """The device's goal shaft angle [rad]."""
        return self._device()

    def set_shaft(self, servo_id: int, angle_rad: float, rate_rad_s: float = 0.0) -> None:
        """Move a shaft (the physics joint) to an angle [rad] and rate [rad/s]."""
        self._device()

    def set_faults(self, faults: Faults) -> None:
        """Inject faults on the device side."""
        self._device()

    def corrupted_replies(self) -> int:
        """Replies the device side damaged on purpose so far."""
        return self._device()

    def inject_overload(self, servo_id: int) -> None:
        """Put a servo in Overload, with its shutdown."""
        self._device()

    @staticmethod
    def decoded_bits(error: HardwareError) -> HardwareErrorStatus:
        """The hardware error bits a backend's error carries."""
        if error.status is not None:
            return error.status
        return HardwareErrorStatus(error.vendor_status_code)  # type: ignore[attr-defined]


class _SimulatedHarness(Harness):
    """Emulated devices (``sim``, with its lock and fault injection) whose shafts sit on a
    rig (``rig``); the subclass builds them in ``_stack`` and names a device by id."""

    sim: Any
    rig: JointRig
    _stack: ExitStack

    def close(self) -> None:
        self._stack.close()

    def _servo(self, servo_id: int) -> Any:
        raise NotImplementedError

    def set_shaft(self, servo_id: int, angle_rad: float, rate_rad_s: float = 0.0) -> None:
        self.rig.set_state(servo_id, angle_rad, rate_rad_s)

    def set_faults(self, faults: Faults) -> None:
        self.sim.set_faults(faults)

    def corrupted_replies(self) -> int:
        return self.sim.corrupted_replies

    def inject_overload(self, servo_id: int) -> None:
        with self.sim.lock:
            self._servo(servo_id).inject_hardware_error(HardwareErrorStatus.OVERLOAD)


class DynamixelHarness(_SimulatedHarness):
    """XM430 emulators on a pty, shafts on a rig."""

    name = "dynamixel"
    timeout_margin_s = 0.02
    timeout_bound_s = timeout_margin_s + 0.005  # plus line time and return delays
    command_timeout_s = 0.2  # every test runs with the watchdog armed

    def __init__(self) -> None:
        self._stack = ExitStack()
        ids = [j.servo_id for j in self.joints] + [GRIPPER.servo_id]
        self.sim = PtyServoBus({i: XM430Servo(i) for i in ids}, step_servos=False)
        self._stack.enter_context(self.sim)
        self.rig = JointRig(self.sim.servos, self.sim.lock)
        self._stack.enter_context(self.rig)
        self.url = (
            f"dynamixel://{self.sim.device}?timeout_margin_ms={self.timeout_margin_s * 1e3:g}"
            f"&watchdog_ms={self.command_timeout_s * 1e3:g}"
        )

    def _servo(self, servo_id: int) -> XM430Servo:
        return self.sim.servos[servo_id]

    def torque_on(self, servo_id: int) -> bool:
        with self.sim.lock:
            return self._servo(servo_id).torque_enabled

    def goal_torque_n_m(self, servo_id: int) -> float:
        with self.sim.lock:
            raw = self._servo(servo_id).get(ct.GOAL_CURRENT)
        return units.current_units_to_a(raw) * KT

    def goal_angle_rad(self, servo_id: int) -> float:
        with self.sim.lock:
            return units.ticks_to_rad(self._servo(servo_id).get(ct.GOAL_POSITION))


class DroneCanHarness(_SimulatedHarness):
    """A DroneCAN actuator node on a python-can virtual bus, shafts on a rig."""

    name = "dronecan"
    timeout_s = 0.02
    timeout_bound_s = timeout_s
    command_timeout_s = CanActuatorParameters().command_timeout_s

    def __init__(self) -> None:
        self._stack = ExitStack()
        ids = [j.servo_id for j in self.joints] + [GRIPPER.servo_id]
        actuators = {i: CanActuator(i) for i in ids}
        self.sim = DroneCanActuatorNode(
            actuators, channel=f"arm-{uuid.uuid4().hex}", step_actuators=False
        )
        self._stack.enter_context(self.sim)
        self.rig = JointRig(actuators, self.sim.lock)
        self._stack.enter_context(self.rig)
        self.url = f"{self.sim.url}&timeout_ms={self.timeout_s * 1e3:g}"

    def _servo(self, servo_id: int) -> CanActuator:
        return self.sim.actuators[servo_id]

    def torque_on(self, servo_id: int) -> bool:
        with self.sim.lock:
            return self._servo(servo_id).output_enabled

    def goal_torque_n_m(self, servo_id: int) -> float:
        with self.sim.lock:
            actuator = self._servo(servo_id)
            return actuator.goal_torque_n_m if actuator.mode == CommandType.FORCE else 0.0

    def goal_angle_rad(self, servo_id: int) -> float:
        with self.sim.lock:
            return self._servo(servo_id).goal_position_rad


class HardwareHarness(Harness):
    """The real bus at ``$ARM_BUS_URL``; only driver-side checks run."""

    name = "hardware"
    timeout_bound_s = 0.05

    def __init__(self) -> None:
        url = os.environ.get("ARM_BUS_URL")
        if not url:
            pytest.skip("set ARM_BUS_URL (e.g. dynamixel:///dev/ttyUSB0?baud=1000000) to run")
        self.url = url
        watchdog_ms = parse_bus_url(url).options.get("watchdog_ms", "0")
        self.command_timeout_s = float(watchdog_ms) / 1e3 or None
        config = os.environ.get("ARM_BUS_CONFIG")
        if config:
            from companion.config import arm_bus_configs
            from sitl.scenario import load_scenario

            section = load_scenario(config).arm_bus
            if section is None:
                pytest.fail(f"{config} has no [arm_bus] section")
            self.joints, self.gripper = arm_bus_configs(section)
        else:
            self.gripper = None


HARNESSES = {
    "dynamixel": DynamixelHarness,
    "dronecan": DroneCanHarness,
    "hardware": HardwareHarness,
}
