"""The official ROBOTIS client (PyPI ``dynamixel-sdk``) drives our servo emulator.

If the SDK's own packet handler gets what it expects from ``sitl.servo``, the emulator
speaks real Protocol 2.0 (framing, CRC, Sync Read ordering, signed fields), not merely
the dialect of our own driver.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from arm_driver.dynamixel import control_table as ct
from arm_driver.dynamixel.units import rad_s_to_velocity_units, rad_to_ticks
from sitl.servo import PtyServoBus, XM430Servo

sdk = pytest.importorskip("dynamixel_sdk")

IDS = (1, 2)
BAUD = 1_000_000


@pytest.fixture
def sim() -> Iterator[PtyServoBus]:
    servos = {i: XM430Servo(i) for i in IDS}
    for servo in servos.values():
        servo.table[ct.RETURN_DELAY_TIME.address] = 0
    with PtyServoBus(servos) as bus:
        yield bus


@pytest.fixture
def port(sim: PtyServoBus, monkeypatch: pytest.MonkeyPatch) -> Iterator[object]:
    # The SDK waits 2 x LATENCY_TIMER (16 ms, the U2D2's USB latency) for a reply; the
    # emulator is a Python thread on a shared 2-core machine and was seen to need more.
    monkeypatch.setattr(sdk.port_handler, "LATENCY_TIMER", 100)
    handler = sdk.PortHandler(sim.device)
    assert handler.openPort()
    assert handler.setBaudRate(BAUD)
    yield handler
    handler.closePort()


@pytest.fixture
def packet() -> object:
    return sdk.PacketHandler(2.0)


def _ok(packet: object, result: int, error: int) -> None:
    assert result == sdk.COMM_SUCCESS, packet.getTxRxResult(result)
    assert error == 0, packet.getRxPacketError(error)


def test_ping_reports_the_xm430_model_number(port: object, packet: object) -> None:
    for servo_id in IDS:
        model, result, error = packet.ping(port, servo_id)
        _ok(packet, result, error)
        assert model == ct.XM430_W350_MODEL_NUMBER


def test_ping_of_a_missing_id_times_out(port: object, packet: object) -> None:
    _, result, _ = packet.ping(port, 9)
    assert result == sdk.COMM_RX_TIMEOUT


def test_broadcast_ping_finds_every_servo(port: object, packet: object) -> None:
    found, result = packet.broadcastPing(port)
    assert result == sdk.COMM_SUCCESS
    assert sorted(found) == list(IDS)
    assert all(found[i][0] == ct.XM430_W350_MODEL_NUMBER for i in IDS)


def test_operating_mode_and_torque_enable_writes(
    sim: PtyServoBus, port: object, packet: object
) -> None:
    address = ct.OPERATING_MODE.address
    _ok(packet, *packet.write1ByteTxRx(port, 1, address, ct.OperatingMode.CURRENT))
    _ok(packet, *packet.write1ByteTxRx(port, 1, ct.TORQUE_ENABLE.address, 1))
    mode, result, error = packet.read1ByteTxRx(port, 1, address)
    _ok(packet, result, error)
    assert mode == ct.OperatingMode.CURRENT
    result, error = packet.write1ByteTxRx(port, 1, address, ct.OperatingMode.POSITION)
    assert result == sdk.COMM_SUCCESS
    assert error == 7  # Access Error: EEPROM written while torque is on
    with sim.lock:
        assert sim.servos[1].get(ct.OPERATING_MODE) == ct.OperatingMode.CURRENT


def test_sync_write_goal_current_and_sync_read_present_values(
    sim: PtyServoBus, port: object, packet: object
) -> None:
    for servo_id in IDS:
        _ok(packet, *packet.write1ByteTxRx(port, servo_id, ct.OPERATING_MODE.address, 0))
        _ok(packet, *packet.write1ByteTxRx(port, servo_id, ct.TORQUE_ENABLE.address, 1))
    goals = {1: -200, 2: 350}
    writer = sdk.GroupSyncWrite(port, packet, ct.GOAL_CURRENT.address, 2)
    for servo_id, goal in goals.items():
        assert writer.addParam(servo_id, list(ct.GOAL_CURRENT.encode(goal)))
    assert writer.txPacket() == sdk.COMM_SUCCESS
    for servo_id in IDS:
        value, result, error = packet.read2ByteTxRx(port, servo_id, ct.GOAL_CURRENT.address)
        _ok(packet, result, error)
        assert ct.GOAL_CURRENT.decode(value.to_bytes(2, "little")) == goals[servo_id]

    with sim.lock:
        sim.servos[1].set_state(-0.5, -1.5)
        sim.servos[2].set_state(0.25, 2.0)
        for servo in sim.servos.values():
            servo.step(0.05)  # current loop settles on the goal

    reader = sdk.GroupSyncRead(port, packet, ct.PRESENT_CURRENT.address, 10)
    for servo_id in IDS:
        assert reader.addParam(servo_id)
    assert reader.txRxPacket() == sdk.COMM_SUCCESS
    for servo_id, (angle, rate) in {1: (-0.5, -1.5), 2: (0.25, 2.0)}.items():
        assert reader.isAvailable(servo_id, ct.PRESENT_CURRENT.address, 10)
        current = reader.getData(servo_id, ct.PRESENT_CURRENT.address, 2)
        velocity = reader.getData(servo_id, ct.PRESENT_VELOCITY.address, 4)
        position = reader.getData(servo_id, ct.PRESENT_POSITION.address, 4)
        assert ct.PRESENT_CURRENT.decode(current.to_bytes(2, "little")) == goals[servo_id]
        assert ct.PRESENT_VELOCITY.decode(velocity.to_bytes(4, "little")) == (
            rad_s_to_velocity_units(rate)
        )
        assert ct.PRESENT_POSITION.decode(position.to_bytes(4, "little")) == rad_to_ticks(angle)


def test_negative_present_position_in_extended_mode(
    sim: PtyServoBus, port: object, packet: object
) -> None:
    with sim.lock:
        sim.servos[2].set_state(-4.0, 0.0)  # beyond half a turn: below tick 0
    value, result, error = packet.read4ByteTxRx(port, 2, ct.PRESENT_POSITION.address)
    _ok(packet, result, error)
    assert ct.PRESENT_POSITION.decode(value.to_bytes(4, "little")) == rad_to_ticks(-4.0) < 0
