"""`sitl run --lockstep` over UDP: which messages answer a pose (SitlVehicle's lockstep)."""

from __future__ import annotations

import os
import time
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")

import pytest
from pymavlink import mavutil

from sitl.scenario import load_scenario
from sitl.vehicle.launch import free_udp_port
from sitl.vehicle.options import LinkPorts, RunOptions
from sitl.vehicle.runner import SitlVehicle

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def send(client, kind: str, time_boot_ms: int) -> None:
    if kind == "SET_ATTITUDE_TARGET":
        client.mav.set_attitude_target_send(
            time_boot_ms, 1, 1, 0b111, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0.5
        )
    elif kind == "SET_POSITION_TARGET_LOCAL_NED":
        client.mav.set_position_target_local_ned_send(
            time_boot_ms, 1, 1, 1, 2048, 0.0, 0.0, -1.0, 0, 0, 0, 0, 0, 0, 0.0, 0.0
        )
    else:
        client.mav.heartbeat_send(18, 8, 0, 0, 0)


def step_until_received(vehicle: SitlVehicle, before: int) -> None:
    """Step the vehicle until the onboard link has taken one more datagram (wall clock)."""
    deadline = time.monotonic() + 5.0
    while vehicle.links["onboard"].counters["received"] == before:
        assert time.monotonic() < deadline, "the vehicle received nothing"
        time.sleep(0.002)
        vehicle.step()


@pytest.mark.parametrize("setpoint", ["SET_ATTITUDE_TARGET", "SET_POSITION_TARGET_LOCAL_NED"])
def test_either_setpoint_stamped_with_a_poses_time_answers_it(setpoint: str) -> None:
    """A client's attitude or position target stamped with an ODOMETRY's time_boot_ms has
    answered that pose, and from then on the vehicle waits for the client's setpoints; any
    other message (a heartbeat, stamped with nothing) answers no pose."""
    client_port = free_udp_port()
    ports = LinkPorts(
        onboard_local=free_udp_port(),
        onboard_remote=client_port,
        gcs_local=free_udp_port(),
        gcs_remote=free_udp_port(),
    )
    scenario = load_scenario(CONFIGS / "sitl_pickup.toml")
    client = mavutil.mavlink_connection(f"udpin:127.0.0.1:{client_port}", source_system=255)
    try:
        with SitlVehicle(scenario, RunOptions(ports=ports, lockstep=True)) as vehicle:
            while vehicle._pose_sent_ms is None:
                vehicle.step()
            pose_ms = vehicle._pose_sent_ms
            assert client.recv_match(type="ODOMETRY", blocking=True, timeout=5) is not None
            received = vehicle.links["onboard"].counters["received"]
            send(client, "HEARTBEAT", pose_ms)
            step_until_received(vehicle, received)
            assert not vehicle._streaming() and vehicle._setpoint_ms < pose_ms
            send(client, setpoint, pose_ms)
            step_until_received(vehicle, received + 1)
            assert vehicle._setpoint_ms == pose_ms
            assert vehicle._streaming()
    finally:
        client.close()
