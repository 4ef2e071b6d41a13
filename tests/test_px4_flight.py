"""The simulated PX4 flying the truth plant: takeoff, hold, offboard, failsafes, return, disarm.

The truth plant has no ground, so the flight starts in the air at the scenario's initial
position with a ground emulated 0.5 m below: once the vehicle descends to it, ``on_ground``
is reported and the plant is no longer stepped (the world's ground would hold it), while
the simulation clock runs on.
"""

import os

os.environ.setdefault("MAVLINK20", "1")

import math
import struct

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as M

from companion.frames import quaternion_ned_frd_from_enu_flu
from sitl.physics import AttitudeSetpoint, TruthPlant
from sitl.physics.frames import quaternion_from_euler
from sitl.px4 import Px4Mode, Px4Params, Px4Vehicle, VehicleMeasurement
from sitl.scenario import load_scenario

_client = M.MAVLink(None, 255, 190)
_MOTORS_OFF = AttitudeSetpoint(quaternion_from_euler(0.0, 0.0, 0.0), 0.0)


def received(msg):
    return M.MAVLink(None).parse_buffer(msg.pack(_client))[0]


def ack_of(replies):
    """The command's result: its last COMMAND_ACK (DO_SET_MODE gets two, as on PX4)."""
    return [m for _, m in replies if m.get_type() == "COMMAND_ACK"][-1]


def command(cmd, *params):
    p = list(params) + [0.0] * (7 - len(params))
    return received(M.MAVLink_command_long_message(1, 1, cmd, 0, *p))


class Flight:
    """Vehicle + plant stepped together at the plant rate, with an emulated ground."""

    def __init__(self, payload: bool) -> None:
        scenario = load_scenario("configs/paper_sim_flight.toml")
        self.plant = TruthPlant.from_scenario(scenario, "underactuated", payload_attached=payload)
        self.vehicle = Px4Vehicle(Px4Params.from_scenario(scenario), aiding="gps")
        self.dt = self.plant.dt_s
        self.t = 0.0
        self.ground_m = float(self.plant.state.q[2]) - 0.5
        self.on_ground = False
        self._estimate: VehicleMeasurement | None = None
        self.landed_states: list[int] = []
        self.step()

    def measurement(self) -> VehicleMeasurement:
        """The truth as an estimate on PX4's 8 ms estimator grid (held in between), with
        the accelerometer's specific force."""
        estimate_us = round(self.t * 1e6) // 8000 * 8000
        if self._estimate is None or self._estimate.estimate_time_us != estimate_us:
            s = self.plant.state
            force_world = np.asarray(s.q_ddot[:3]) + np.array([0.0, 0.0, self.plant.gravity_m_s2])
            self._estimate = VehicleMeasurement(
                self.t, s.q[:3], s.q_dot[:3], s.quaternion_wxyz, s.omega_body_rad_s,
                s.rotation_world_body.T @ force_world, self.on_ground,
                estimate_time_us=estimate_us,
            )  # fmt: skip
        return self._estimate

    def send(self, msg):
        return self.vehicle.handle(msg, "onboard", self.t)

    def step(self, stream=None) -> None:
        if stream is not None:
            self.send(stream)
        m = self.measurement()
        sp = self.vehicle.control(self.t, m)
        self.vehicle.telemetry(self.t, m)
        if self.vehicle.landed_state not in self.landed_states[-1:]:
            self.landed_states.append(self.vehicle.landed_state)
        if not self.on_ground:
            self.plant.step(sp or _MOTORS_OFF, [0.0, 0.0])
            self.on_ground = self.plant.state.q[2] <= self.ground_m
        self.t += self.dt

    def run(self, seconds: float, stream=None) -> None:
        for _ in range(round(seconds / self.dt)):
            self.step(stream)

    @property
    def position(self) -> np.ndarray:
        return np.array(self.plant.state.q[:3])


def param_set_int(name: str, value: int):
    wire = struct.unpack("<f", struct.pack("<i", value))[0]
    return received(M.MAVLink_param_set_message(1, 1, name.encode(), wire, M.MAV_PARAM_TYPE_INT32))


@pytest.mark.slow
@pytest.mark.parametrize("payload", [False, True])
def test_takeoff_hold_offboard_failsafes_return_and_disarm(payload):
    f = Flight(payload)
    start = f.position
    rotors = f.plant.scenario.vehicle.rotors
    weight = f.plant.total_mass_kg * f.plant.gravity_m_s2
    hover = weight / (6 * rotors.max_thrust_per_rotor_n)  # relative thrust (PX4 linearizes)
    assert ack_of(f.send(command(400, 1))).result == M.MAV_RESULT_ACCEPTED
    f.send(command(M.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 7))
    f.run(0.01)
    assert f.vehicle.mode is Px4Mode.AUTO_TAKEOFF
    f.run(6.0)  # 2.5 m at 1.5 m/s, then hold
    assert f.vehicle.mode is Px4Mode.AUTO_LOITER
    f.run(6.0)
    target = start + np.array([0.0, 0.0, 2.5])  # home is the arming position
    assert np.linalg.norm(f.position - target) < 0.15
    assert np.linalg.norm(f.plant.state.q_dot[:3]) < 0.1
    # PX4's hover thrust estimator has learned the vehicle's hover thrust from MPC_THR_HOVER 0.5
    assert f.vehicle.params["MPC_THR_HOVER"] == 0.5
    assert f.vehicle.hover_thrust == pytest.approx(hover, abs=0.02)

    # Offboard: level, relative thrust above hover -> climbs; the stream stops -> Hold
    # (COM_OBL_RC_ACT 5); it comes back -> OFFBOARD again.
    q_ned = quaternion_ned_frd_from_enu_flu(quaternion_from_euler(0.0, 0.0, 0.0))
    climb = received(
        M.MAVLink_set_attitude_target_message(0, 1, 1, 0b111, q_ned, 0, 0, 0, hover + 0.05)
    )
    f.send(param_set_int("COM_OBL_RC_ACT", 5))
    f.run(0.1, climb)
    assert ack_of(f.send(command(176, 1, 6, 0))).result == M.MAV_RESULT_ACCEPTED
    z0 = f.position[2]
    f.run(1.0, climb)
    assert f.vehicle.mode is Px4Mode.OFFBOARD
    assert f.position[2] > z0 + 0.2
    f.run(0.999)  # no setpoints: failsafe COM_OF_LOSS_T = 1 s after the last one
    assert f.vehicle.mode is Px4Mode.OFFBOARD
    f.run(0.002)
    assert f.vehicle.mode is Px4Mode.AUTO_LOITER and f.vehicle.failsafe
    failsafe_at = f.position
    f.run(6.0)  # Hold returns to where the failsafe struck (PX4 would brake and stop)
    assert np.linalg.norm(f.position - failsafe_at) < 0.3
    f.run(0.01, climb)
    assert f.vehicle.mode is Px4Mode.OFFBOARD and not f.vehicle.failsafe

    # Stream stops with the default action (0 Position: no RC, so Return): back home, land,
    # disarm after COM_DISARM_LAND.
    f.send(param_set_int("COM_OBL_RC_ACT", 0))
    f.run(1.1)
    assert f.vehicle.mode is Px4Mode.AUTO_RTL and f.vehicle.failsafe
    height = f.position[2] - f.ground_m
    f.run(height / f.vehicle.params["MPC_LAND_SPEED"] + 8.0)
    assert f.on_ground and f.vehicle.landed
    assert not f.vehicle.armed
    assert np.linalg.norm(f.position[:2] - start[:2]) < 0.5
    assert f.vehicle.mode is Px4Mode.OFFBOARD  # the intention after the disarm, as PX4
    assert f.landed_states == [
        M.MAV_LANDED_STATE_IN_AIR,
        M.MAV_LANDED_STATE_TAKEOFF,
        M.MAV_LANDED_STATE_IN_AIR,
        M.MAV_LANDED_STATE_LANDING,
        M.MAV_LANDED_STATE_ON_GROUND,
    ]


def test_a_takeoff_is_not_the_mode_after_the_disarm():
    """Take-off, land at once, auto-disarm: the intention returns to Hold, not Takeoff.
    Measured on the PX4 build (v1.17.0-alpha1, a servo silenced during the take-off of a
    PX4-in-the-loop pickup: AUTO_TAKEOFF, AUTO_LAND, disarmed, AUTO_LOITER); PX4 keeps
    the last intended mode that neither prevents arming nor is a take-off. (After
    OFFBOARD then Land it is OFFBOARD, as the pickups under PX4 end.)"""
    f = Flight(payload=False)
    assert ack_of(f.send(command(400, 1))).result == M.MAV_RESULT_ACCEPTED
    f.send(command(M.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 7))
    f.run(0.3)
    assert f.vehicle.mode is Px4Mode.AUTO_TAKEOFF
    assert ack_of(f.send(command(M.MAV_CMD_NAV_LAND))).result == M.MAV_RESULT_ACCEPTED
    f.run(0.01)
    assert f.vehicle.mode is Px4Mode.AUTO_LAND
    f.run(12.0)
    assert f.on_ground and not f.vehicle.armed
    assert f.vehicle.mode is Px4Mode.AUTO_LOITER
