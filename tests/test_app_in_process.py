"""Parts of the flight app checked in-process (the end-to-end tests fly it against the SITL).

- Preflight: the ODOMETRY stream that clocks the control loop must come fast enough
  (a scripted pose stream; the link and bus stand-ins provide only what ``PickupApp``
  reads before take-off).
- Joints stopped by the servos' Bus Watchdog after a silent bus, or by a servo rebooting by
  itself, are enabled again (the real Dynamixel driver against the XM430 emulator on a pty).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from arm_driver.bus import JointConfig, OperatingMode, open_bus
from companion.config import load_config
from companion.link.px4_modes import px4_mode
from companion.link.telemetry import VehiclePose, VehicleStatus
from companion.mission.app import MissionError, PickupApp
from companion.mission.offboard import Stream
from companion.mission.pickup import PickupPlan
from companion.mission.preflight import PreflightError, check_pose_rate
from companion.mission.servo_check import torque_constant_sources
from sitl.servo import Faults, PtyServoBus, XM430Servo

SCENARIO = load_config("configs/sitl_pickup.toml")
PLAN = PickupPlan(home_m=(0.0, 0.0), payload_at_m=(1.0, 0.0, 0.0), place_at_m=(2.0, 0.0, 0.0))


class ScriptedPoses:
    """A pose subscription that yields one pose per ``period_us`` of vehicle time."""

    def __init__(self, period_us: int, repeat_each: int = 1, start_us: int = 0) -> None:
        self.period_us = period_us
        self.repeat_each = repeat_each
        self.start_us = start_us
        self.count = 0

    async def get(self) -> VehiclePose:
        await asyncio.sleep(0)
        t_us = self.start_us + (self.count // self.repeat_each) * self.period_us
        self.count += 1
        return VehiclePose(t_us, (0.0, 0.0, 0.0), None, (1.0, 0.0, 0.0, 0.0))


class PoseLink:
    lost = None
    """The link's watchdog: never lost."""

    def __init__(self, poses: ScriptedPoses) -> None:
        self.poses = poses
        self.mav = mavlink2.MAVLink(None, 1, mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER)
        self.sent: list = []
        """The messages the app sent (its STATUSTEXTs)."""

    def send_message(self, msg) -> None:
        self.sent.append(msg)

    @contextlib.contextmanager
    def subscribe(self, *keys, maxsize: int = 64):
        assert keys == (VehiclePose,)
        yield self.poses

    def latest(self, key):
        return None


JOINTS = (JointConfig("eta1", 1, 1.78, 1.5), JointConfig("eta2", 2, 1.78, 1.5))


class TwoJoints:
    joints = JOINTS
    watchdog_s = 0.0

    def torque_limit_n_m(self, name: str) -> float:
        return 1.5


def check(period_us: int, repeat_each: int = 1, start_us: int = 0):
    notes: list[tuple[str, str]] = []
    app = PickupApp(
        SCENARIO,
        PoseLink(ScriptedPoses(period_us, repeat_each, start_us)),
        TwoJoints(),
        PLAN,
        event=lambda kind, detail, t_s: notes.append((kind, detail)),
    )
    app.cycle.loop_period = asyncio.run(
        check_pose_rate(
            app.link,
            app.control,
            app.report,
            app._note,
            rate_hz=app.control_rate_hz,
            q_stow=app.cycle.q_stow,
            loop_period=app.loop_period,
        )
    )
    return notes, app


def test_full_rate_passes_quietly():
    notes, app = check(4000)
    assert notes == [] and app.loop_period.period_s == pytest.approx(0.004)
    assert app.report.control_rate_hz == pytest.approx(250.0)


def test_repeated_timestamps_are_one_pose():
    assert check(4000, repeat_each=3)[0] == []


def test_px4s_125_hz_becomes_the_loop_period_in_microseconds():
    """PX4 sends ODOMETRY at its estimator's rate (125 Hz) whatever is asked, stamped with
    the IMU sample time in microseconds: the loop's period is measured from those."""
    notes, app = check(8000, start_us=123_457)
    assert notes and notes[0][0] == "loop" and "arrives at 125 Hz" in notes[0][1]
    assert app.loop_period.period_s == pytest.approx(0.008, abs=1e-9)
    assert not app.loop_period.update(0.0) and not app.loop_period.update(0.012).late


def test_too_slow_for_the_gains_refuses_to_fly():
    """configs/sitl_pickup.toml's joint gains (0.15 N m s/rad) need 14.3 Hz at the stow
    pose."""
    with pytest.raises(PreflightError, match=r"arrives at 10 Hz .* raise the control rate"):
        check(100_000)


@contextlib.asynccontextmanager
async def app_on_servos(sim: PtyServoBus, margin_ms: int, notes: list[tuple[str, str]]):
    """The app on the real Dynamixel driver against the emulator ``sim``: joints in current
    mode, torque on, the watchdog at 100 ms; its events go to ``notes``."""
    url = f"dynamixel://{sim.device}?timeout_margin_ms={margin_ms}&watchdog_ms=100"
    async with open_bus(url, JOINTS) as bus:
        await bus.set_operating_mode(OperatingMode.CURRENT)
        await bus.enable_torque()
        yield (
            bus,
            PickupApp(
                SCENARIO,
                PoseLink(ScriptedPoses(4000)),
                bus,
                PLAN,
                event=lambda kind, detail, t_s: notes.append((kind, detail)),
            ),
        )


def test_joints_stopped_by_the_servo_watchdog_are_enabled_again():
    notes: list[tuple[str, str]] = []

    async def body(sim: PtyServoBus) -> None:
        async with app_on_servos(sim, 50, notes) as (bus, app):
            await app.arm.rearm_after_silence()
            assert notes == []  # a bus in use is left alone
            deadline = time.monotonic() + 2.0
            while not sim.servos[1].watchdog_tripped:  # the host is silent
                assert time.monotonic() < deadline, "the servo watchdog did not trip"
                await asyncio.sleep(0.01)
            await app.arm.write_torques(np.array([0.89, 0.0]))
            assert abs((await bus.read_joint_states())["eta1"].torque_n_m) < 0.01  # refused
            await asyncio.sleep(0.1)
            await app.arm.rearm_after_silence()
            assert [kind for kind, _ in notes] == ["servo"] and "watchdog 100 ms" in notes[0][1]
            assert not sim.servos[1].watchdog_tripped
            await app.arm.write_torques(np.array([0.89, 0.0]))
            await asyncio.sleep(0.02)
            assert (await bus.read_joint_states())["eta1"].torque_n_m > 0.8

    with PtyServoBus({i: XM430Servo(i) for i in (1, 2)}) as sim:
        asyncio.run(asyncio.wait_for(body(sim), 10.0))


def test_a_servo_that_rebooted_by_itself_gets_its_torque_back_after_its_silence():
    notes: list[tuple[str, str]] = []

    async def body(sim: PtyServoBus) -> None:
        async with app_on_servos(sim, 20, notes) as (bus, app):
            sim.set_faults(Faults(silent_ids=frozenset({2})))  # a timeout, no reboot
            assert await app.arm.read_joints() is None
            sim.set_faults(Faults())
            assert await app.arm.read_joints() is not None
            assert notes == [] and app.arm.rearmed == 0
            with sim.lock:
                sim.servos[1].reboot()  # a brown-out: RAM at the defaults, torque off
            sim.set_faults(Faults(silent_ids=frozenset({1})))  # booting
            assert await app.arm.read_joints() is None
            assert await app.arm.read_joints() is None
            sim.set_faults(Faults())
            assert await app.arm.read_joints() is not None
            assert app.arm.rearmed == 1 and sim.servos[1].torque_enabled
            assert notes == [
                ("servo", "eta1: torque off after 2 failed transactions (the servo rebooted): "
                 "torque enabled again")
            ]  # fmt: skip
            await app.arm.write_torques(np.array([0.89, 0.0]))
            await asyncio.sleep(0.02)
            assert (await bus.read_joint_states())["eta1"].torque_n_m > 0.8

    with PtyServoBus({i: XM430Servo(i) for i in (1, 2)}) as sim:
        asyncio.run(asyncio.wait_for(body(sim), 10.0))


def test_touching_the_ground_in_offboard_is_a_fault_flown_level_at_the_thrust_floor():
    """EKF2's height drifted up to 1 m near the ground on PX4 SIH with GPS, and the app kept
    commanding a 32 deg tilt standing on the ground: now the height at the take-off height
    is ground_contact, whose way out is level at the thrust floor until PX4 lands."""
    from companion.control.laws import DesiredState
    from companion.control.setpoints import ThrustModel
    from companion.estimation.filters import FilteredState
    from companion.mission.failsafe import Fault, Reaction

    link = PoseLink(ScriptedPoses(8000))
    app = PickupApp(SCENARIO, link, TwoJoints(), PLAN)
    app.control.thrust = ThrustModel(app.control.thrust.max_thrust_n, 0.12)
    app.sequence.ground_z_m = 0.25
    app.offboard.to(Stream.HOLD)
    app.offboard.accept(0.5)
    q = np.array([0.5, 0.0, 0.27, 0.0, 0.0, 0.3, 0.0, -1.5])  # 2 cm above the take-off height
    zero = np.zeros(8)
    desired = DesiredState(q + np.array([0.4, 0, 0.5, 0, 0, 0, 0, 0]), zero, zero)
    out = app.control.step(0.008, FilteredState(q, zero, zero), desired, np.full(8, np.nan))
    app.cycle.watch_flight(1.0, q, out, None, None)
    (event,) = app.failsafe.raised
    assert event.fault == Fault.GROUND_CONTACT and "take-off height" in event.detail
    assert Reaction.LEVEL_ON_GROUND in event.reactions and event.aborts
    (told,) = link.sent  # the fault told on the link, for PX4's log and the ground station
    assert told.get_type() == "STATUSTEXT" and told.severity == mavlink2.MAV_SEVERITY_WARNING
    assert told.text.startswith("pickup: fault ground_contact: ")
    app.offboard.to(Stream.GROUND)
    sp = app.offboard.setpoint(out.setpoint, q, app.control.weight_n(), app.control.thrust)
    assert (sp.roll_rad, sp.pitch_rad, sp.yaw_rad) == (0.0, 0.0, 0.3)
    assert sp.thrust_relative == pytest.approx(0.12)


def _with_servos(check: str, calibrated: bool):
    """SCENARIO with ``flight.servo_check`` = ``check`` and every joint ``torque_calibrated``
    as given."""
    assert SCENARIO.arm_bus is not None
    joints = tuple(
        j.model_copy(update={"torque_calibrated": calibrated}) for j in SCENARIO.arm_bus.joints
    )
    return SCENARIO.model_copy(
        update={
            "flight": SCENARIO.flight.model_copy(update={"servo_check": check}),
            "arm_bus": SCENARIO.arm_bus.model_copy(update={"joints": joints}),
        }
    )


@pytest.mark.parametrize(
    ("check", "calibrated", "measures"),
    [
        ("auto", False, True),
        ("auto", True, False),
        ("always", True, True),
        ("off", False, False),
        ("off", True, False),
    ],
)
def test_the_servo_check_runs_where_the_torque_constants_are_not_known(check, calibrated, measures):
    """``auto`` measures uncalibrated joints, ``always`` any; a mission that flies on the
    datasheet's constants unmeasured says so at preflight."""
    sources = torque_constant_sources(_with_servos(check, calibrated))
    assert sources.check is measures
    source = "calibrated" if calibrated else "datasheet"
    assert {j["source"] for j in sources.per_joint.values()} == {source}
    assert set(sources.per_joint) == {"eta1", "eta2"}
    datasheet_note = sources.note is not None and "datasheet's torque constants" in sources.note
    assert datasheet_note is (not measures and not calibrated)


class StatusLink(PoseLink):
    """A link whose HEARTBEAT the test sets; every command is acknowledged."""

    def __init__(self, status: VehicleStatus) -> None:
        super().__init__(ScriptedPoses(8000))
        self.status = status

    def latest(self, key):
        return self.status if key is VehicleStatus else None

    async def command_long(self, *args, **kwargs) -> None:
        await asyncio.sleep(0)

    async def arm(self) -> None:
        await asyncio.sleep(0)


def _heartbeat(armed: bool, mode: str) -> VehicleStatus:
    return VehicleStatus(1000, armed, px4_mode(mode), 4 if armed else 3)


def test_a_land_right_after_arming_waits_for_a_newer_heartbeat_that_says_disarmed():
    """PX4's HEARTBEAT comes at 1 Hz. Under PX4 a servo fell silent 0.5 s after the app
    armed: the land found the HEARTBEAT from before the arming (disarmed), and the app
    reported landed and disarmed while PX4 was still armed and landing. Now the app
    counts as armed from PX4's acknowledgement, and the land ends on a newer HEARTBEAT."""
    link = StatusLink(_heartbeat(False, "LOITER"))
    app = PickupApp(SCENARIO, link, TwoJoints(), PLAN, land_timeout_s=5.0)

    async def fly() -> tuple[float, float]:
        await link.arm()
        app.cycle.status_at_arm = link.latest(VehicleStatus)
        assert app.cycle.armed()  # the stale heartbeat says disarmed
        landing = asyncio.create_task(app._land(Stream.LEVEL))
        newer_s = math.nan
        for cycle in range(1, 1000):
            await asyncio.sleep(0)
            app.t_s = 0.004 * cycle
            if cycle == 100:
                link.status = _heartbeat(True, "LAND")
            if cycle == 350:
                link.status, newer_s = _heartbeat(False, "LAND"), app.t_s
            app._tick.set()
            if landing.done():
                break
        await landing
        return newer_s, app.t_s

    newer_s, landed_s = asyncio.run(fly())
    assert newer_s <= landed_s <= newer_s + 0.0041  # the next control cycle
    assert app.report.landed and app.report.disarmed
    assert not app.cycle.armed()


def test_a_land_without_a_newer_heartbeat_is_a_mission_error_not_a_disarm():
    link = StatusLink(_heartbeat(False, "LOITER"))
    app = PickupApp(SCENARIO, link, TwoJoints(), PLAN, land_timeout_s=1.0)

    async def fly() -> None:
        landing = asyncio.create_task(app._land(Stream.LEVEL))
        for cycle in range(1, 400):
            await asyncio.sleep(0)
            app.t_s = 0.004 * cycle
            app._tick.set()
        await landing

    with pytest.raises(MissionError, match="did not land and disarm"):
        asyncio.run(fly())
    assert not app.report.disarmed


class Done(Exception):
    """Ends a scripted pose stream."""


class DroppingPoses(ScriptedPoses):
    """Scripted poses whose queue reports ``dropped[i]`` after the i-th pose."""

    def __init__(self, dropped: list[int]) -> None:
        super().__init__(4000)
        self.script = dropped
        self.dropped = 0

    async def get(self) -> VehiclePose:
        if self.count == len(self.script):
            raise Done
        self.dropped = self.script[self.count]
        return await super().get()


class ScriptedThreadTimes:
    """The control thread's (run, CPU wait) [s], one per cycle."""

    def __init__(self, script: list[tuple[float, float]]) -> None:
        self.script = script

    def read(self) -> tuple[float, float]:
        return self.script.pop(0)

    def close(self) -> None:
        pass


def test_the_loop_blames_dropped_poses_on_who_held_them_up(monkeypatch):
    """The control loop counts each drop under its cause from its thread's last two cycles:
    47 ms waiting for a CPU is the host; a 58 ms cycle of its own, more than that wait still
    in its window, is the companion."""
    link = PoseLink(DroppingPoses([0, 0, 2, 3]))
    link.lost = "telemetry"  # the cycles themselves are skipped: only the accounting runs
    waits = [0.0005, 0.0005, 0.047, 0.0005]
    link.take_longest_socket_wait_s = lambda: waits.pop(0)
    times = [(1.0, 5.0), (1.001, 5.0), (1.002, 5.047), (1.060, 5.047)]
    monkeypatch.setattr("companion.mission.app.ThreadTimes", lambda: ScriptedThreadTimes(times))
    notes: list[tuple[str, str]] = []
    app = PickupApp(
        SCENARIO, link, TwoJoints(), PLAN, event=lambda kind, text, t_s: notes.append((kind, text))
    )
    with pytest.raises(Done):
        asyncio.run(app._control_loop())
    assert app.report.poses_dropped == 3
    assert app.report.poses_dropped_by_cause == {"host": 2, "companion": 1}
    assert app.report.late_cycles_by_cause == {}
    assert [text.split(" (")[0] for kind, text in notes if kind == "loop"] == [
        "2 dropped poses: host",
        "1 dropped pose: companion",
    ]
    assert "waited 47.0 ms for a CPU; datagrams waited up to 47.0 ms" in notes[0][1]


def test_the_streams_are_given_back_when_the_mission_is_cancelled():
    """Ctrl-C cancels the app's task mid-flight: the streams changed at preflight are set
    back to PX4's defaults on the way out (``OnboardStreams.restore``)."""
    restored: list[str] = []

    class Streams:
        async def restore(self) -> None:
            await asyncio.sleep(0)  # awaiting still works in the cancelled task
            restored.append("restored")

    async def body() -> None:
        app = PickupApp(SCENARIO, PoseLink(ScriptedPoses(4000)), TwoJoints(), PLAN)
        app.streams = Streams()  # type: ignore[assignment]
        flying = asyncio.Event()

        async def fly():
            flying.set()
            await asyncio.Event().wait()

        app._fly = fly  # type: ignore[method-assign]
        task = asyncio.create_task(app.run())
        await flying.wait()
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task

    asyncio.run(body())
    assert restored == ["restored"]
