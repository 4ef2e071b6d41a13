"""``sitl run`` flown by MAVSDK-Python 4.x (``mavsdk.asyncio``), end to end.

The vehicle runs as its own process on free loopback ports; MAVSDK listens on the onboard
link's remote port (``udpin://127.0.0.1:PORT``, as it would on 14540 for PX4 SITL). One
flight: connect, read telemetry, arm, climb in OFFBOARD with an attitude setpoint above
hover thrust, stop offboard (the vehicle holds), land (it lands and disarms by itself).
The climb is checked twice: in MAVSDK's telemetry and in the truth log.

Timeouts are in wall time and generous (the machine running the tests may be loaded);
nothing here measures speed.
"""

from __future__ import annotations

import asyncio
import json
import math
from pathlib import Path

import pytest

pytest.importorskip("mavsdk.asyncio", reason="needs MAVSDK-Python >= 4 (mavsdk.asyncio)")

from mavsdk.asyncio import Autopilot, ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import Attitude, OffboardAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode, LandedState, TelemetryAsync

from sitl.scenario import load_scenario
from sitl.vehicle.launch import start_sitl

CONFIG = Path(__file__).parent.parent / "configs" / "sitl_pickup.toml"
SPEED = 1.0
"""Simulation speed of the vehicle process (MAVSDK's own timeouts are wall time)."""
pytestmark = pytest.mark.slow


async def _latest(subscription, condition, timeout_s: float):
    """The first update of ``subscription`` (an async generator) meeting ``condition``,
    or None after ``timeout_s`` of wall time."""

    async def first():
        async for value in subscription:
            if condition(value):
                return value
        return None

    try:
        return await asyncio.wait_for(first(), timeout_s)
    except TimeoutError:
        return None
    finally:
        await subscription.aclose()


async def _collect(subscription, count: int, timeout_s: float) -> list:
    """The next ``count`` updates of ``subscription`` (fewer after ``timeout_s`` wall)."""
    values: list = []

    async def take():
        async for value in subscription:
            values.append(value)
            if len(values) >= count:
                return

    try:
        await asyncio.wait_for(take(), timeout_s)
    except TimeoutError:
        pass
    finally:
        await subscription.aclose()
    return values


async def _fly(port: int, hover_thrust: float) -> dict:
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    seen: dict = {}
    async with Mavsdk(config) as sdk:
        await sdk.add_any_connection(f"udpin://127.0.0.1:{port}")
        system = await sdk.first_autopilot(timeout_s=30.0)
        assert system is not None, "MAVSDK found no autopilot"
        seen["autopilot_type"] = await system.autopilot_type()
        seen["vehicle_type"] = await system.vehicle_type()
        telemetry, action, offboard = (
            TelemetryAsync(system),
            ActionAsync(system),
            OffboardAsync(system),
        )

        # Telemetry before arming: standing on the ground, disarmed, a PX4 mode.
        seen["attitude"] = await _latest(telemetry.subscribe_attitude_euler(), lambda a: True, 20.0)
        seen["position"] = await _latest(telemetry.subscribe_position(), lambda p: True, 20.0)
        seen["armed_before"] = await _latest(telemetry.subscribe_armed(), lambda a: True, 20.0)
        seen["landed_before"] = await _latest(
            telemetry.subscribe_landed_state(), lambda s: True, 20.0
        )
        seen["mode_before"] = await _latest(telemetry.subscribe_flight_mode(), lambda m: True, 20.0)

        await action.arm()
        seen["armed"] = await _latest(telemetry.subscribe_armed(), lambda a: a, 20.0)

        # Offboard attitude: level, thrust well above hover -> climbs.
        await offboard.set_attitude(Attitude(0.0, 0.0, 0.0, min(1.0, hover_thrust + 0.05)))
        await offboard.start()
        seen["mode_offboard"] = await _latest(
            telemetry.subscribe_flight_mode(), lambda m: m == FlightMode.OFFBOARD, 20.0
        )
        start_alt = seen["position"].relative_altitude_m
        seen["climbed"] = await _latest(
            telemetry.subscribe_position(),
            lambda p: p.relative_altitude_m > start_alt + 1.5,
            30.0,
        )
        seen["in_air"] = await _latest(
            telemetry.subscribe_landed_state(), lambda s: s == LandedState.IN_AIR, 20.0
        )

        # Offboard stop: PX4 (and this vehicle) switches to HOLD.
        await offboard.stop()
        seen["mode_hold"] = await _latest(
            telemetry.subscribe_flight_mode(), lambda m: m == FlightMode.HOLD, 20.0
        )
        # Hold for 200 position updates (4 s of vehicle time at PX4's onboard 50 Hz).
        seen["hold_positions"] = await _collect(telemetry.subscribe_position(), 200, 30.0)

        await action.land()
        seen["mode_land"] = await _latest(
            telemetry.subscribe_flight_mode(), lambda m: m == FlightMode.LAND, 20.0
        )
        seen["on_ground"] = await _latest(
            telemetry.subscribe_landed_state(), lambda s: s == LandedState.ON_GROUND, 60.0
        )
        seen["disarmed"] = await _latest(telemetry.subscribe_armed(), lambda a: not a, 30.0)
        seen["landed_position"] = await _latest(
            telemetry.subscribe_position(), lambda p: True, 20.0
        )
        # Let the vehicle run on for 0.5 s of its time, so the truth log records the end.
        await _collect(telemetry.subscribe_attitude_euler(), 50, 20.0)
    return seen


def test_mavsdk_arms_climbs_in_offboard_holds_lands_and_disarms(tmp_path):
    scenario = load_scenario(CONFIG)
    mass = scenario.vehicle.mass_kg + scenario.arm.link1.mass_kg + scenario.arm.link2.mass_kg
    rotors = scenario.vehicle.rotors
    # PX4's thrust is relative thrust: weight over the six rotors' full thrust hovers
    hover = mass * scenario.environment.gravity_m_s2 / (6 * rotors.max_thrust_per_rotor_n)
    truth = tmp_path / "truth.jsonl"
    # GPS aiding: MAVSDK arms in Hold, which needs a global position
    sitl = start_sitl(CONFIG, "--seed", "7", "--navigation", "gps", speed=SPEED, truth_log=truth)
    try:
        seen = asyncio.run(asyncio.wait_for(_fly(sitl.onboard_port, hover), 120.0))
        assert sitl.alive(), "the vehicle process died during the flight"
    finally:
        summary = sitl.stop()

    # What MAVSDK saw.
    assert seen["autopilot_type"] == Autopilot.PX4
    attitude, position = seen["attitude"], seen["position"]
    assert attitude is not None and abs(attitude.roll_deg) < 5 and abs(attitude.pitch_deg) < 5
    assert position is not None and math.isfinite(position.latitude_deg)
    assert abs(position.relative_altitude_m) < 0.5
    assert seen["armed_before"] is False
    assert seen["landed_before"] == LandedState.ON_GROUND
    assert seen["mode_before"] is not None and seen["mode_before"] != FlightMode.OFFBOARD
    assert seen["armed"] is True
    assert seen["mode_offboard"] == FlightMode.OFFBOARD
    assert seen["climbed"] is not None, "no climb seen in telemetry with thrust above hover"
    assert seen["in_air"] == LandedState.IN_AIR
    assert seen["mode_hold"] == FlightMode.HOLD
    hold = [p.relative_altitude_m for p in seen["hold_positions"]]
    assert len(hold) == 200
    assert min(hold) > 1.0, "the vehicle fell in HOLD"
    # It brakes the climb, then stays: the last second within half a metre.
    assert max(hold[-50:]) - min(hold[-50:]) < 0.5, "the vehicle did not hold its altitude"
    assert seen["mode_land"] == FlightMode.LAND
    assert seen["on_ground"] == LandedState.ON_GROUND
    assert seen["disarmed"] is False
    # GPS and baro: the estimated height wanders (PX4 SIH: 0.3-1.2 m in flight)
    assert abs(seen["landed_position"].relative_altitude_m) < 1.0

    # What really happened (the truth log, never sent over MAVLink).
    records = [json.loads(line) for line in truth.read_text().splitlines() if line]
    heights = [r["q"][2] for r in records]
    start_height = heights[0]
    offboard = [r for r in records if r["mode"] == "OFFBOARD"]
    assert offboard and all(r["armed"] for r in offboard)
    assert max(r["q"][2] for r in offboard) > start_height + 1.5
    assert max(heights) > start_height + 1.5
    after = records[records.index(offboard[-1]) + 1 :]
    assert [r["mode"] for r in after][:1] == ["AUTO_LOITER"]
    landing = next(i for i, r in enumerate(after) if r["mode"] == "AUTO_LAND")
    held = [r for r in after[:landing] if r["mode"] == "AUTO_LOITER"]  # (Hold again disarmed)
    assert abs(held[-1]["q_dot"][2]) < 0.3 and held[-1]["q"][2] > start_height + 1.0
    assert any(r["mode"] == "AUTO_LAND" and not r["on_ground"] for r in after)
    last = records[-1]
    assert last["on_ground"] and not last["armed"]
    assert abs(last["q"][2] - start_height) < 0.1
    assert "real-time factor" in summary
