"""MavlinkLink against a scripted pymavlink peer on loopback UDP / TCP (free ports).

The peer is not a vehicle: it is pymavlink's own codec on a socket, driven step by step
by each test, so every byte the link sends is decoded by code that is not ours.
"""

import asyncio
import math
import os
import socket
import struct
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as m

from companion.control.setpoints import AttitudeThrustSetpoint, PositionSetpoint
from companion.frames import enu_from_ned, rotation_from_quaternion
from companion.link import (
    CommandDenied,
    CommandTimeout,
    LinkClosedError,
    LinkLost,
    LinkLostError,
    LinkRegained,
    MavlinkLink,
    ParamRefused,
    ParamTimeout,
    SetpointError,
    SigningConfig,
    VehicleDetected,
    VehicleId,
    VehicleNotFoundError,
    VehiclePose,
    VehicleStatus,
    px4_mode,
    quaternion_from_euler_zyx,
)
from companion.link.transport import open_transport
from companion.link.url import parse_link_url

WAIT_S = 5.0
"""Upper bound on any wait for an answer (a guard against hangs, not a measured time)."""
KEY = bytes(range(32))


class Peer:
    """A pymavlink endpoint on 127.0.0.1 that speaks as a PX4 autopilot (1, 1)."""

    def __init__(self, system_id=1, component_id=1, key=None):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.port = self.sock.getsockname()[1]
        self.addr = None
        self.mav = m.MAVLink(self, system_id, component_id)
        self.mav.robust_parsing = True
        if key is not None:
            self.mav.signing.secret_key = key
            self.mav.signing.sign_outgoing = True
            self.mav.signing.timestamp = int((__import__("time").time() - 1420070400) * 1e5)
            self.mav.signing.allow_unsigned_callback = lambda *_: False
        self.pending = []

    def write(self, buf):
        self.sock.sendto(bytes(buf), self.addr)

    def heartbeat(self, mode="POSCTL", armed=False, autopilot=m.MAV_AUTOPILOT_PX4):
        base = m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (m.MAV_MODE_FLAG_SAFETY_ARMED * armed)
        custom = px4_mode(mode).custom_mode
        self.mav.heartbeat_send(m.MAV_TYPE_HEXAROTOR, autopilot, base, custom, 4)

    def odometry(self, t_ms, x_ned=(1.0, 2.0, -3.0)):
        self.mav.odometry_send(
            t_ms * 1000, 1, 1, *x_ned, [1, 0, 0, 0], 0, 0, 0, 0, 0, 0, [0] * 21, [0] * 21, 0, 0, 0
        )

    async def expect(self, kind, where=lambda msg: True):
        """The next message of type ``kind`` the link sends (learns the link's address)."""
        loop = asyncio.get_running_loop()
        async with asyncio.timeout(WAIT_S):
            while True:
                while self.pending:
                    msg = self.pending.pop(0)
                    if msg.get_type() == kind and where(msg):
                        return msg
                data, self.addr = await loop.sock_recvfrom(self.sock, 65535)
                self.pending.extend(self.mav.parse_buffer(data) or ())

    def close(self):
        self.sock.close()


async def _events(sub, kind, count=1):
    out = []
    async with asyncio.timeout(WAIT_S):
        while len(out) < count:
            item = await sub.get()
            if isinstance(item, kind):
                out.append(item)
    return out


async def _connected(peer, **kwargs):
    """A link to ``peer`` (udpout to its port) that has detected it as the vehicle."""
    link = MavlinkLink(f"udpout://127.0.0.1:{peer.port}", heartbeat_period_s=0.05, **kwargs)
    await link.open()
    await peer.expect("HEARTBEAT")
    peer.heartbeat()
    await link.wait_vehicle(WAIT_S)
    return link


def run(coro):
    return asyncio.run(coro)


def test_heartbeat_is_mavlink2_onboard_controller():
    async def scenario():
        peer = Peer()
        async with MavlinkLink(f"udpout://127.0.0.1:{peer.port}", system_id=42) as link:
            hb = await peer.expect("HEARTBEAT")
            assert link.stats.messages_sent >= 1
        peer.close()
        return hb

    hb = run(scenario())
    assert (hb.type, hb.autopilot) == (m.MAV_TYPE_ONBOARD_CONTROLLER, m.MAV_AUTOPILOT_INVALID)
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (42, m.MAV_COMP_ID_ONBOARD_COMPUTER)
    assert hb.get_msgbuf()[0] == 0xFD  # a MAVLink 2 frame


def test_udpin_listens_and_answers_the_sender():
    async def scenario():
        probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
        probe.close()
        peer = Peer()
        peer.addr = ("127.0.0.1", port)
        async with MavlinkLink(f"udpin://127.0.0.1:{port}", heartbeat_period_s=0.05) as link:
            events = link.subscribe(VehicleDetected)
            peer.heartbeat()
            vehicle = await link.wait_vehicle(WAIT_S)
            detected = await events.get()
            hb = await peer.expect("HEARTBEAT")
        peer.close()
        return vehicle, detected, hb

    vehicle, detected, hb = run(scenario())
    assert vehicle == VehicleId(1, 1)
    assert detected.vehicle == vehicle
    assert hb.type == m.MAV_TYPE_ONBOARD_CONTROLLER


def test_only_a_px4_heartbeat_makes_the_vehicle():
    async def scenario():
        gcs, px4 = Peer(system_id=255, component_id=190), Peer(system_id=7, component_id=1)
        async with MavlinkLink(f"udpout://127.0.0.1:{gcs.port}") as link:
            await gcs.expect("HEARTBEAT")
            gcs.heartbeat(autopilot=m.MAV_AUTOPILOT_INVALID)
            with pytest.raises(VehicleNotFoundError):
                await link.wait_vehicle(0.2)
            assert link.latest("HEARTBEAT").get_srcSystem() == 255  # cached all the same
            with pytest.raises(VehicleNotFoundError):
                link.send_attitude_target((1, 0, 0, 0), 0.5, 0)
            # The PX4 peer sends to the link's port, which it learns from the GCS peer.
            px4.addr = gcs.addr
            statuses = link.subscribe(VehicleStatus)
            px4.heartbeat(mode="OFFBOARD", armed=True)
            vehicle = await link.wait_vehicle(WAIT_S)
            status = await _next(statuses)
        gcs.close()
        px4.close()
        return vehicle, status

    vehicle, status = run(scenario())
    assert vehicle == VehicleId(7, 1)
    assert (status.armed, status.mode_name) == (True, "OFFBOARD")


def test_two_subscribers_both_get_every_message():
    async def scenario():
        peer = Peer()
        link = await _connected(peer)
        first = link.subscribe("ODOMETRY")
        second = link.subscribe(VehiclePose, "ODOMETRY")
        for t in range(1, 6):
            peer.odometry(t)
        got_first = [await _next(first) for _ in range(5)]
        got_second = [await _next(second) for _ in range(10)]
        first.close()
        peer.odometry(6)
        last = {type(await _next(second)).__name__ for _ in range(2)}
        await link.close()
        await link.close()  # idempotent
        with pytest.raises(LinkClosedError):
            await second.get()
        peer.close()
        return got_first, got_second, last, link

    got_first, got_second, last, link = run(scenario())
    assert [msg.time_usec // 1000 for msg in got_first] == [1, 2, 3, 4, 5]
    poses = [x for x in got_second if isinstance(x, VehiclePose)]
    assert [p.time_boot_ms for p in poses] == [1, 2, 3, 4, 5]
    assert poses[0].position_enu_m == pytest.approx((2.0, 1.0, 3.0))
    assert len(got_second) == 10
    assert last == {"VehiclePose", "MAVLink_odometry_message"}
    assert link.closed


async def _next(sub):
    async with asyncio.timeout(WAIT_S):
        return await sub.get()


async def _answer_commands(peer, results):
    """Answer successive COMMAND_LONGs with ``results`` (None: stay silent); returns them."""
    seen = []
    for result in results:
        cmd = await peer.expect("COMMAND_LONG")
        seen.append(cmd)
        if result is not None:
            peer.mav.command_ack_send(cmd.command, result, 0, 0, cmd.get_srcSystem(), 191)
    return seen


def test_command_is_retried_until_acknowledged():
    async def scenario():
        peer = Peer()
        link = await _connected(peer)
        answer = asyncio.create_task(_answer_commands(peer, [None, m.MAV_RESULT_ACCEPTED]))
        ack = await link.arm(timeout_s=0.2, attempts=3)
        seen = await answer
        await link.close()
        peer.close()
        return ack, seen

    ack, seen = run(scenario())
    assert ack.result == m.MAV_RESULT_ACCEPTED
    assert [c.confirmation for c in seen] == [0, 1]
    assert all(c.command == m.MAV_CMD_COMPONENT_ARM_DISARM and c.param1 == 1 for c in seen)
    assert (seen[0].target_system, seen[0].target_component) == (1, 1)


def test_in_progress_then_accepted():
    async def scenario():
        peer = Peer()
        link = await _connected(peer)

        async def answer():
            cmd = await peer.expect("COMMAND_LONG")
            peer.mav.command_ack_send(cmd.command, m.MAV_RESULT_IN_PROGRESS, 0, 0, 1, 191)
            peer.mav.command_ack_send(cmd.command, m.MAV_RESULT_ACCEPTED, 0, 0, 1, 191)

        task = asyncio.create_task(answer())
        ack = await link.set_message_interval(m.MAVLINK_MSG_ID_ODOMETRY, 250.0, timeout_s=1.0)
        await task
        await link.close()
        peer.close()
        return ack

    assert run(scenario()).result == m.MAV_RESULT_ACCEPTED


def test_denied_command_raises_with_the_result():
    async def scenario():
        peer = Peer()
        link = await _connected(peer)
        answer = asyncio.create_task(_answer_commands(peer, [m.MAV_RESULT_DENIED]))
        with pytest.raises(CommandDenied) as info:
            await link.disarm()
        await answer
        await link.close()
        peer.close()
        return info.value

    err = run(scenario())
    assert err.result == m.MAV_RESULT_DENIED
    assert "MAV_CMD_COMPONENT_ARM_DISARM" in str(err) and "MAV_RESULT_DENIED" in str(err)


def test_unanswered_command_times_out_after_every_attempt():
    async def scenario():
        peer = Peer()
        link = await _connected(peer)
        answer = asyncio.create_task(_answer_commands(peer, [None, None, None]))
        with pytest.raises(CommandTimeout) as info:
            await link.set_message_interval(31, 0.0, timeout_s=0.05, attempts=3)
        seen = await answer
        await link.close()
        peer.close()
        return info.value, seen

    err, seen = run(scenario())
    assert err.attempts == 3
    assert isinstance(err, TimeoutError)
    assert [c.confirmation for c in seen] == [0, 1, 2]
    assert (seen[0].param1, seen[0].param2) == (31, -1)  # rate 0: stop the stream


class ParamTable:
    """The peer's parameters, answered as PX4 answers them (INT32 bytewise)."""

    def __init__(self, peer, values, refuse=()):
        self.peer, self.values, self.refuse = peer, dict(values), set(refuse)
        self.sets = []

    def _send(self, name):
        value, kind = self.values[name]
        wire = struct.unpack("<f", struct.pack("<i", int(value)))[0] if kind == 6 else value
        self.peer.mav.param_value_send(name.encode(), wire, kind, len(self.values), 0)

    async def serve(self, count):
        for _ in range(count):
            msg = await self.peer.expect("PARAM_REQUEST_READ", lambda _: True)
            if msg.param_id in self.values:
                self._send(msg.param_id)

    async def serve_set(self):
        await self.serve(1)
        msg = await self.peer.expect("PARAM_SET")
        self.sets.append(msg)
        if msg.param_id not in self.refuse:
            kind = self.values[msg.param_id][1]
            wire = msg.param_value
            new = struct.unpack("<i", struct.pack("<f", wire))[0] if kind == 6 else wire
            self.values[msg.param_id] = (new, kind)
        self._send(msg.param_id)


def test_parameters_are_read_and_set_as_px4_encodes_them():
    async def scenario():
        peer = Peer()
        link = await _connected(peer)
        table = ParamTable(peer, {"THR_MDL_FAC": (0.3, 9), "COM_OBL_RC_ACT": (4, 6)})
        serve = asyncio.create_task(table.serve(2))
        fac = await link.param_read("THR_MDL_FAC")
        action = await link.param_read("COM_OBL_RC_ACT")
        await serve
        serve = asyncio.create_task(table.serve_set())
        kept = await link.param_set("COM_OBL_RC_ACT", 5)
        await serve
        await link.close()
        peer.close()
        return fac, action, kept, table

    fac, action, kept, table = run(scenario())
    assert fac == (pytest.approx(0.3), m.MAV_PARAM_TYPE_REAL32)
    assert action == (4.0, m.MAV_PARAM_TYPE_INT32)  # bytewise, not the float 5.6e-45
    assert kept == 5.0 and table.values["COM_OBL_RC_ACT"] == (5, 6)
    assert table.sets[0].param_type == m.MAV_PARAM_TYPE_INT32


def test_a_missing_or_refused_parameter_raises():
    async def scenario():
        peer = Peer()
        link = await _connected(peer)
        table = ParamTable(peer, {"MPC_THR_MIN": (0.12, 9)}, refuse={"MPC_THR_MIN"})
        serve = asyncio.create_task(table.serve(2))
        with pytest.raises(ParamTimeout) as missing:
            await link.param_read("NO_SUCH_PARAM", timeout_s=0.05, attempts=2)
        await serve
        serve = asyncio.create_task(table.serve_set())
        with pytest.raises(ParamRefused) as refused:
            await link.param_set("MPC_THR_MIN", 0.2)
        await serve
        await link.close()
        peer.close()
        return missing.value, refused.value

    missing, refused = run(scenario())
    assert missing.name == "NO_SUCH_PARAM" and isinstance(missing, TimeoutError)
    assert (refused.wanted, refused.kept) == (0.2, pytest.approx(0.12))


@pytest.mark.parametrize("name", ["OFFBOARD", "LAND", "TAKEOFF", "POSCTL", "LOITER", "MISSION"])
def test_set_mode_sends_px4_custom_mode(name):
    from pymavlink import mavutil

    async def scenario():
        peer = Peer()
        link = await _connected(peer)
        answer = asyncio.create_task(_answer_commands(peer, [m.MAV_RESULT_ACCEPTED]))
        await link.set_mode_px4(*px4_mode(name))
        (cmd,) = await answer
        await link.close()
        peer.close()
        return cmd

    cmd = run(scenario())
    _, main, sub = mavutil.px4_map[name]
    assert cmd.command == m.MAV_CMD_DO_SET_MODE
    assert int(cmd.param1) & m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert (cmd.param2, cmd.param3) == (main, sub)


def test_set_attitude_target_is_ned_frd():
    phi, theta, psi = 0.1, -0.2, 0.3  # ENU/FLU ZYX Euler [rad]
    sp = AttitudeThrustSetpoint(phi, theta, psi, 12.0, 0.55, False, False)

    async def scenario():
        peer = Peer()
        link = await _connected(peer)
        link.send_setpoint(sp, time_boot_ms=2**32 + 1234)
        msg = await peer.expect("SET_ATTITUDE_TARGET")
        with pytest.raises(SetpointError):
            link.send_attitude_target((1, 0, 0, 0), 1.5, 0)
        with pytest.raises(SetpointError):
            link.send_attitude_target((0, 0, 0, 0), 0.5, 0)
        await link.close()
        peer.close()
        return msg

    msg = run(scenario())
    assert msg.type_mask == 7
    assert (msg.target_system, msg.target_component) == (1, 1)
    assert msg.time_boot_ms == 1234
    assert msg.thrust == pytest.approx(0.55)
    r_ned_frd = rotation_from_quaternion(msg.q)
    r_enu_flu = rotation_from_quaternion(quaternion_from_euler_zyx(phi, theta, psi))
    # The same physical axes: body forward, right (= -left) and down (= -up), seen in NED.
    np.testing.assert_allclose(r_ned_frd[:, 0], [*_ned(r_enu_flu[:, 0])], atol=1e-6)
    np.testing.assert_allclose(r_ned_frd[:, 1], [*_ned(-r_enu_flu[:, 1])], atol=1e-6)
    np.testing.assert_allclose(r_ned_frd[:, 2], [*_ned(-r_enu_flu[:, 2])], atol=1e-6)
    # PX4's Euler angles: same roll, opposite pitch, yaw from north.
    q = msg.q
    yaw = math.atan2(2 * (q[0] * q[3] + q[1] * q[2]), 1 - 2 * (q[2] ** 2 + q[3] ** 2))
    assert yaw == pytest.approx(math.pi / 2 - psi, abs=1e-6)


def test_set_position_target_is_local_ned_with_only_the_yaw_rate_ignored():
    """What PX4's receiver takes into its trajectory setpoint (every field not ignored):
    position, velocity and acceleration in NED, yaw from north."""
    sp = PositionSetpoint((1.0, 2.0, 3.0), (0.1, 0.2, 0.3), (-0.5, 0.25, 1.5), 0.3)

    async def scenario():
        peer = Peer()
        link = await _connected(peer)
        link.send_position_target(sp, time_boot_ms=4321)
        msg = await peer.expect("SET_POSITION_TARGET_LOCAL_NED")
        bad = PositionSetpoint((1.0, math.nan, 3.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0)
        with pytest.raises(SetpointError):
            link.send_position_target(bad, 0)
        await link.close()
        peer.close()
        return msg

    msg = run(scenario())
    assert msg.coordinate_frame == m.MAV_FRAME_LOCAL_NED
    assert msg.type_mask == m.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
    assert (msg.target_system, msg.target_component, msg.time_boot_ms) == (1, 1, 4321)
    np.testing.assert_allclose([msg.x, msg.y, msg.z], _ned((1.0, 2.0, 3.0)), rtol=1e-6)
    np.testing.assert_allclose([msg.vx, msg.vy, msg.vz], _ned((0.1, 0.2, 0.3)), rtol=1e-6)
    np.testing.assert_allclose([msg.afx, msg.afy, msg.afz], _ned((-0.5, 0.25, 1.5)), rtol=1e-6)
    assert msg.yaw == pytest.approx(math.pi / 2 - 0.3, abs=1e-6)


def _ned(v_enu):
    e, n, u = v_enu
    ned = np.array([n, e, -u])
    assert np.allclose(enu_from_ned(ned), v_enu)
    return ned


def test_garbage_and_corrupt_frames_are_counted_not_fatal():
    async def scenario():
        peer = Peer()
        link = await _connected(peer)
        poses = link.subscribe(VehiclePose)
        garbage = bytes(b for b in range(256) if b not in (0xFD, 0xFE)) * 2
        peer.write(garbage)
        frame = bytearray(peer.mav.heartbeat_encode(2, 12, 0, 0, 4).pack(peer.mav))
        frame[-1] ^= 0xFF  # break the CRC
        peer.write(frame)
        peer.odometry(1, x_ned=(float("nan"), 0.0, 0.0))
        peer.odometry(2)
        pose = await _next(poses)
        stats = link.stats
        await link.close()
        peer.close()
        return stats, pose

    stats, pose = run(scenario())
    assert stats.garbage_bytes == 2 * 254
    assert stats.bad_frames == 1
    assert stats.telemetry_rejected == {"bad_position": 1}
    assert pose.time_boot_ms == 2


def test_telemetry_loss_is_reported_and_regained():
    async def scenario():
        peer = Peer()
        link = await _connected(peer, telemetry_timeout_s=0.2)
        events = link.subscribe(LinkLost, LinkRegained)
        peer.odometry(1)
        (lost,) = await _events(events, LinkLost)
        with pytest.raises(LinkLostError) as info:
            link.raise_if_lost()
        peer.heartbeat()
        peer.odometry(2)
        (regained,) = await _events(events, LinkRegained)
        link.raise_if_lost()
        await link.close()
        peer.close()
        return lost, info.value, regained

    lost, err, regained = run(scenario())
    assert lost.reason == "telemetry" and lost.silent_s >= 0.2
    assert err.reason == "telemetry"
    assert regained.reason == "telemetry"


def test_heartbeat_silence_counts_on_the_vehicles_clock_while_its_telemetry_comes():
    """A vehicle whose clock runs slower than the companion's (a simulator held in lockstep)
    sends its 1 Hz heartbeat less often in wall time: no loss while its own time has not
    moved on by the timeout; a loss once it has, or when it sends no timed telemetry."""

    async def scenario():
        peer = Peer()
        link = await _connected(peer, heartbeat_timeout_s=0.3, telemetry_timeout_s=5.0)
        events = link.subscribe(LinkLost)
        peer.odometry(1000)
        peer.heartbeat()
        for k in range(1, 13):  # 0.6 s of wall time, 0.12 s of the vehicle's
            await asyncio.sleep(0.05)
            peer.odometry(1000 + 10 * k)
        quiet = link.lost is None
        peer.odometry(1000 + 400)  # the vehicle's clock 0.4 s past its heartbeat
        (lost,) = await _events(events, LinkLost)
        await link.close()
        peer.close()
        return quiet, lost

    quiet, lost = run(scenario())
    assert quiet
    assert lost.reason == "heartbeat" and lost.silent_s >= 0.3

    async def without_telemetry():
        peer = Peer()
        link = await _connected(peer, heartbeat_timeout_s=0.3, telemetry_timeout_s=5.0)
        events = link.subscribe(LinkLost)
        (lost,) = await _events(events, LinkLost)
        await link.close()
        peer.close()
        return lost

    lost = run(without_telemetry())
    assert lost.reason == "heartbeat" and 0.3 <= lost.silent_s < 1.0


def test_signed_frames_accepted_unsigned_rejected():
    async def scenario():
        peer = Peer(key=KEY)
        intruder = Peer(system_id=9)
        signing = SigningConfig(KEY, link_id=3)
        link = MavlinkLink(f"udpout://127.0.0.1:{peer.port}", signing=signing)
        await link.open()
        await peer.expect("HEARTBEAT")  # verified by the peer's codec
        intruder.addr = peer.addr
        intruder.heartbeat()  # unsigned
        with pytest.raises(VehicleNotFoundError):
            await link.wait_vehicle(0.2)
        peer.heartbeat()  # signed
        vehicle = await link.wait_vehicle(WAIT_S)
        stats = link.stats
        await link.close()
        peer.close()
        intruder.close()
        return vehicle, stats, peer.mav.signing

    vehicle, stats, peer_signing = run(scenario())
    assert vehicle == VehicleId(1, 1)
    assert stats.signature_rejected == 1
    assert peer_signing.goodsig_count >= 1 and peer_signing.badsig_count == 0


def test_wrong_key_is_rejected():
    async def scenario():
        peer = Peer(key=bytes(32))
        link = MavlinkLink(f"udpout://127.0.0.1:{peer.port}", signing=SigningConfig(KEY))
        await link.open()
        await asyncio.sleep(0)
        data, peer.addr = await asyncio.get_running_loop().sock_recvfrom(peer.sock, 65535)
        peer.heartbeat()
        with pytest.raises(VehicleNotFoundError):
            await link.wait_vehicle(0.3)
        stats = link.stats
        await link.close()
        peer.close()
        return stats, peer.mav.parse_buffer(data)

    stats, parsed = run(scenario())
    assert stats.signature_rejected == 1
    assert parsed[0].get_type() == "BAD_DATA"  # and the peer refuses ours


def test_tcp_peer_closing_ends_the_subscriptions():
    async def scenario():
        server = socket.socket()
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        server.setblocking(False)
        port = server.getsockname()[1]
        link = MavlinkLink(f"tcpout://127.0.0.1:{port}", heartbeat_period_s=60.0)
        await link.open()
        loop = asyncio.get_running_loop()
        conn, _ = await loop.sock_accept(server)
        reader = m.MAVLink(None, 2, 1)
        ours = reader.parse_buffer(await loop.sock_recv(conn, 65535))  # read all: a clean EOF
        sub = link.subscribe("HEARTBEAT")
        peer = m.MAVLink(None, 1, 1)
        await loop.sock_sendall(conn, peer.heartbeat_encode(2, 12, 0, 0, 4).pack(peer))
        vehicle = await link.wait_vehicle(WAIT_S)
        await _next(sub)
        conn.close()
        server.close()
        with pytest.raises(LinkClosedError) as info:
            await _next(sub)
        await link.close()
        return vehicle, info.value, ours

    vehicle, err, ours = run(scenario())
    assert ours[0].get_type() == "HEARTBEAT"
    assert vehicle == VehicleId(1, 1)
    assert "closed the connection" in str(err.__cause__)


def test_constructor_opens_nothing_and_open_errors_are_typed():
    link = MavlinkLink("udpout://no-such-host.invalid:14550")  # no loop, no socket: fine
    with pytest.raises(LinkClosedError, match="cannot open"):
        run(link.open())
    with pytest.raises(ValueError):
        MavlinkLink("udpin://0.0.0.0:14540", system_id=0)
    with pytest.raises(ValueError):
        MavlinkLink("udpin://0.0.0.0:14540", telemetry_timeout_s=0)


def test_a_second_ack_that_refuses_the_mode_wins():
    """PX4 answers DO_SET_MODE twice; measured: a Hold it could not enter came as ACCEPTED
    then TEMPORARILY_REJECTED."""

    async def scenario(second):
        peer = Peer()
        link = await _connected(peer)

        async def answer():
            cmd = await peer.expect("COMMAND_LONG")
            peer.mav.command_ack_send(cmd.command, m.MAV_RESULT_ACCEPTED, 0, 0, 1, 191)
            peer.mav.command_ack_send(cmd.command, second, 0, 0, 1, 191)

        task = asyncio.create_task(answer())
        try:
            return await link.set_mode_px4(*px4_mode("LOITER"))
        finally:
            await task
            await link.close()
            peer.close()

    assert run(scenario(m.MAV_RESULT_ACCEPTED)).result == m.MAV_RESULT_ACCEPTED
    with pytest.raises(CommandDenied) as info:
        run(scenario(m.MAV_RESULT_TEMPORARILY_REJECTED))
    assert info.value.result == m.MAV_RESULT_TEMPORARILY_REJECTED


def test_datagrams_waiting_in_the_socket_are_timed_from_their_arrival():
    """The kernel stamps each datagram's arrival: while the event loop is held up (a
    blocking sleep), the vehicle's poses wait in the socket, and the link says how long."""

    async def scenario():
        peer = Peer()
        link = await _connected(peer)
        try:
            with link.subscribe(VehiclePose) as poses:
                link.take_longest_socket_wait_s()
                peer.odometry(1)
                time.sleep(0.06)  # noqa: ASYNC251 - holds the loop: the datagram waits
                await poses.get()
                held = link.take_longest_socket_wait_s()
                after = link.take_longest_socket_wait_s()
        finally:
            await link.close()
            peer.close()
        return held, after

    held, after = run(scenario())
    assert held >= 0.055
    assert after == 0.0


def test_a_serial_link_cannot_time_its_datagrams():
    parent, child = os.openpty()
    try:
        transport = open_transport(parse_link_url(f"serial://{os.ttyname(child)}:57600"), 1, 191)
        assert transport.take_longest_socket_wait_s() is None
        transport.close()
    finally:
        os.close(parent)
        os.close(child)
