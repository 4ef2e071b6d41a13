"""``sitl run`` seen from a ground station (pymavlink on the GCS link), end to end.

The vehicle runs as its own process on free loopback ports; everything here goes through
real MAVLink 2 frames over UDP.
"""

from __future__ import annotations

import os
import random
import socket
import time
from pathlib import Path

import pytest

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from sitl.vehicle.launch import start_sitl

CONFIG = Path(__file__).parent.parent / "configs" / "sitl_pickup.toml"
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def vehicle():
    sitl = start_sitl(CONFIG, "--seed", "3", "--navigation", "gps", speed=2.0)
    yield sitl
    sitl.stop()


@pytest.fixture
def gcs(vehicle):
    conn = mavutil.mavlink_connection(
        f"udpin:127.0.0.1:{vehicle.gcs_port}", source_system=255, source_component=190
    )
    hb = conn.wait_heartbeat(timeout=20)
    assert hb is not None, "no heartbeat on the GCS link"
    yield conn
    conn.close()


def _wait(conn, kind, timeout_s=10.0, condition=lambda m: True):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = conn.recv_match(type=kind, blocking=True, timeout=0.5)
        if msg is not None and condition(msg):
            return msg
    return None


def _ack(conn, command, timeout_s=5.0):
    """The command's result. PX4 acknowledges DO_SET_MODE twice, at once: ACCEPTED, then the
    result; a refusal is in the second."""
    ack = _wait(conn, "COMMAND_ACK", timeout_s, lambda m: m.command == command)
    if ack is not None and command == mavlink2.MAV_CMD_DO_SET_MODE:
        ack = _wait(conn, "COMMAND_ACK", 2.0, lambda m: m.command == command)
    return ack


def test_heartbeat_identifies_a_px4_hexarotor(gcs):
    hb = _wait(gcs, "HEARTBEAT", condition=lambda m: m.get_srcSystem() == 1)
    assert hb.autopilot == mavlink2.MAV_AUTOPILOT_PX4
    assert hb.type == mavlink2.MAV_TYPE_HEXAROTOR
    assert hb.get_srcComponent() == 1
    assert hb.base_mode & mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert gcs.flightmode in mavutil.px4_map  # a PX4 mode name pymavlink knows
    assert hb.get_header().mlen > 0 and gcs.WIRE_PROTOCOL_VERSION == "2.0"


def test_param_list_is_complete_and_settable(gcs):
    gcs.mav.param_request_list_send(1, 1)
    seen: dict[str, float] = {}
    count = None
    deadline = time.monotonic() + 15.0
    while time.monotonic() < deadline and (count is None or len(seen) < count):
        msg = gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
        if msg is not None:
            count = msg.param_count
            seen[msg.param_id] = msg.param_value
    assert count is not None and len(seen) == count
    for name in ("MPC_THR_HOVER", "THR_MDL_FAC", "COM_OF_LOSS_T", "COM_OBL_RC_ACT", "MAV_SYS_ID"):
        assert name in seen
    assert 0.1 < seen["MPC_THR_HOVER"] < 0.9
    gcs.mav.param_set_send(1, 1, b"COM_OF_LOSS_T", 0.7, mavlink2.MAV_PARAM_TYPE_REAL32)
    echo = _wait(gcs, "PARAM_VALUE", condition=lambda m: m.param_id == "COM_OF_LOSS_T")
    assert echo is not None and echo.param_value == pytest.approx(0.7)


def _stream_attitude(conn, seconds, thrust=0.0, until=lambda m: False):
    """Stream level setpoints for ``seconds`` of wall time, reading what comes in (the GCS
    link's 50 Hz streams fill a socket that is not read); returns the first message meeting
    ``until`` (then stops), or None."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        conn.mav.set_attitude_target_send(
            0, 1, 1, 0b00000111, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, thrust
        )
        stop = time.monotonic() + 0.02
        while time.monotonic() < stop:
            msg = conn.recv_match(blocking=True, timeout=0.005)
            if msg is not None and until(msg):
                return msg
    return None


def test_offboard_needs_a_live_setpoint_stream_and_fails_safe_when_it_stops(gcs):
    # Disarmed, PX4 accepts any mode; armed, OFFBOARD needs the setpoint stream.
    gcs.mav.command_long_send(1, 1, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    ack = _ack(gcs, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM)
    assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED
    gcs.set_mode("OFFBOARD")
    ack = _ack(gcs, mavlink2.MAV_CMD_DO_SET_MODE)
    assert ack is not None
    assert ack.result == mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
    assert (ack.target_system, ack.target_component) == (255, 190)
    _stream_attitude(gcs, 0.5)
    gcs.set_mode("OFFBOARD")
    # Keep streaming while the command is answered (at once) and until the next 1 Hz
    # heartbeat shows the mode.
    for _ in range(2):  # ACCEPTED twice
        ack = _stream_attitude(
            gcs,
            2.0,
            until=lambda m: (
                m.get_type() == "COMMAND_ACK" and m.command == mavlink2.MAV_CMD_DO_SET_MODE
            ),
        )
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED
    hb = _stream_attitude(
        gcs, 3.0, until=lambda m: m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1
    )
    assert hb is not None and mavutil.mode_string_v10(hb) == "OFFBOARD"
    # Stop streaming: after COM_OF_LOSS_T of vehicle time it leaves OFFBOARD by itself.
    left = _wait(
        gcs,
        "HEARTBEAT",
        timeout_s=15.0,
        condition=lambda m: m.get_srcSystem() == 1 and mavutil.mode_string_v10(m) != "OFFBOARD",
    )
    assert left is not None, "still in OFFBOARD after the setpoint stream stopped"
    # COM_OBL_RC_ACT 0 (Position) needs RC: PX4 falls back to Return
    assert mavutil.mode_string_v10(left) == "RTL"
    gcs.mav.command_long_send(1, 1, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 0, 0, 0, 0, 0, 0)
    ack = _ack(gcs, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM)
    assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED  # on the ground


def test_unhandled_command_is_unsupported(gcs):
    gcs.mav.command_long_send(1, 1, mavlink2.MAV_CMD_DO_SET_SERVO, 0, 5, 1500, 0, 0, 0, 0, 0)
    ack = _ack(gcs, mavlink2.MAV_CMD_DO_SET_SERVO)
    assert ack is not None and ack.result == mavlink2.MAV_RESULT_UNSUPPORTED


def test_garbage_and_mutated_frames_do_not_kill_the_vehicle(vehicle, gcs):
    rng = random.Random(5)
    mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    valid = [
        mav.heartbeat_encode(6, 8, 0, 0, 0).pack(mav),
        mav.set_attitude_target_encode(0, 1, 1, 7, [float("nan"), 0, 0, 0], 0, 0, 0, 2.0).pack(mav),
        # Not an arm command: a mutation that leaves the frame intact is a valid message.
        mav.command_long_encode(1, 1, 512, 0, 148, 0, 0, 0, 0, 0, 0).pack(mav),
        mav.param_request_read_encode(1, 1, b"NOPE", -1).pack(mav),
    ]
    targets = [("127.0.0.1", vehicle.onboard_local_port), ("127.0.0.1", vehicle.gcs_local_port)]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for i in range(10_000):
            kind = i % 4
            if kind == 0:
                data = rng.randbytes(rng.randrange(1, 300))
            elif kind == 1:
                frame = bytearray(rng.choice(valid))
                frame[rng.randrange(len(frame))] ^= 1 << rng.randrange(8)
                data = bytes(frame)
            elif kind == 2:
                frame = rng.choice(valid)
                data = frame[: rng.randrange(1, len(frame))]
            else:
                frame = bytearray(rng.choice(valid))
                frame[5] = rng.randrange(256)  # another sender id: CRC mismatch
                data = bytes(frame)
            sock.sendto(data, targets[i % 2])
            if i % 500 == 0:
                time.sleep(0.01)
    assert vehicle.alive()
    # A frame that survived the mutation makes the fuzzer the link's latest peer (the
    # endpoint answers whoever spoke last); the ground station's heartbeat takes it back.
    # Like a real GCS it sends one every second: the first may be dropped by the kernel
    # while the vehicle's socket buffer is still full of the burst.
    hb = None
    deadline = time.monotonic() + 20.0
    while hb is None and time.monotonic() < deadline:
        gcs.mav.heartbeat_send(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        hb = _wait(gcs, "HEARTBEAT", timeout_s=1.0, condition=lambda m: m.get_srcSystem() == 1)
    assert hb is not None
    assert not hb.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED  # no corrupted frame armed it
    assert vehicle.alive()
