"""Servo supervision: the arm's own task, its commands, its failures and its safe state.

The flight app's control cycle never waits for the servo bus. It takes the joint state the
arm task read after the previous cycle (:meth:`ArmSupervisor.take`, with its age), and
hands over the joint torques and a gripper action (:meth:`ArmSupervisor.command`,
:meth:`ArmSupervisor.grip`); after each cycle (:meth:`ArmSupervisor.due`) the arm task
writes them and reads the joints again (one Sync Read). A Sync Read over the pty beside
the SITL took 1-25 ms, and a timed-out one with its retries longer: it used to delay the
vehicle's setpoint.

Failures: every joint transaction that fails counts; when they have lasted
:data:`SERVO_FAILURE_S` of vehicle time (at least three), or the bus reports itself failed,
the supervisor declares the bus lost once (``on_failure``, the app's ``servo_bus`` fault)
and applies the bus's safe state itself (:meth:`arm_driver.bus.ArmBus.enter_safe_state`:
current-mode joints limp, the gripper holding): a torque command held after the controller
lost the bus drives the joints on and on (measured in the SITL: a silenced servo kept its
last goal current and the arm spun up until the vehicle could not land).

While the app watches the gripper (:meth:`ArmSupervisor.watch_gripper`: from the grasp to
the release), the task also reads the gripper servo's position and current every
:data:`GRIPPER_READ_PERIOD_S` (:meth:`ArmSupervisor.take_gripper`), after the joints; a
bus that cannot read it is noted once and not asked again.

With the servos' Bus Watchdog armed (``watchdog_ms``), a bus silent for most of its
timeout (a lost MAVLink link pauses the loop) has stopped the current-mode joints, which
then refuse torque without a word: the task enables them again first. A servo that stopped
answering for a few transactions and answers again may have rebooted by itself (a
brown-out): its RAM is back at the defaults and its torque off, and it says nothing of it.
After every run of failed joint transactions the task asks the joints' torque state
(:meth:`~arm_driver.bus.ArmBus.joints_without_torque`) and enables torque again where it
is off (noted, counted in :attr:`ArmSupervisor.rearmed`).

After the landing (:meth:`ArmSupervisor.hold_after_landing`) the joints hold their pose
on the servos' position loop: the mission's end leaves the arm holding, not falling.

Time: ages, read periods and the bus's silence are measured on the running event loop's
clock (``loop.time()``): the monotonic clock in flight, the simulation's in a flight on
simulated time (:mod:`sitl.vehicle.lockstep`).
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from arm_driver.bus import (
    ArmBus,
    BusFailedError,
    BusStateError,
    GripperState,
    JointState,
    OperatingMode,
)
from arm_driver.errors import ArmDriverError, BusTimeoutError, CommunicationError
from companion.mission.pickup import GripperAction

__all__ = [
    "BUS_FAILURES",
    "GRIPPER_ATTEMPTS",
    "GRIPPER_READ_PERIOD_S",
    "SERVO_FAILURE_S",
    "ArmSupervisor",
]

FloatArray = NDArray[np.float64]
SERVO_FAILURE_S = 0.3
"""Vehicle time over which every joint transaction failed that loses the bus [s] (at least
three failures): a transient stall is ridden through with the servos holding their last
goal current; a servo that stopped answering is not. Open the bus with a
``max_consecutive_failures`` that covers this time (see :data:`BUS_FAILURES`)."""
BUS_FAILURES = 30
"""``max_consecutive_failures`` for the arm bus: more than the transactions in
:data:`SERVO_FAILURE_S`, so the supervisor, not the bus, decides."""
GRIPPER_READ_PERIOD_S = 0.1
"""Wall-clock period of the gripper reads while it is watched [s]: an object that slipped
out shows within two reads (:data:`companion.mission.carry_check.EMPTY_READINGS`), one extra
transaction every 25 cycles at 250 Hz."""
GRIPPER_ATTEMPTS = 2
"""Tries of an open or close that timed out or came back damaged (a position goal: writing
it again is harmless) before the bus counts as lost."""
PREFLIGHT_ATTEMPTS = 3
"""Tries of the preflight set-up; a reply that came late once is not a broken bus."""
PREFLIGHT_PAUSE_S = 0.5
"""Wall-clock pause before the n-th retry is n times this [s]: tries back to back all
fell inside the same busy moment of the servo adapter's host (a SITL's servo thread
starved at start-up answered none of three reads within 21 ms)."""


def _now() -> float:
    """The running event loop's clock [s]."""
    return asyncio.get_running_loop().time()


class ArmSupervisor:
    """The arm's task and state; see the module docstring.

    Parameters
    ----------
    bus
        An open arm bus; its joints' torque limits and watchdog timeout are read once.
    vehicle_time
        The vehicle time now [s] (the failure clock).
    note
        Where events go: ``note(kind, text)``.
    on_failure
        Called once, with the reason, when the bus is lost.
    """

    def __init__(
        self,
        bus: ArmBus,
        *,
        vehicle_time: Callable[[], float],
        note: Callable[[str, str], None],
        on_failure: Callable[[str], None],
    ) -> None:
        self.bus = bus
        self.names = [j.name for j in bus.joints]
        self.torque_limits = np.array([bus.torque_limit_n_m(n) for n in self.names])
        self.watchdog_s = bus.watchdog_s
        self._vehicle_time = vehicle_time
        self._note = note
        self._on_failure = on_failure
        self.failed = False
        """The bus is lost: nothing is written any more (its safe state applies)."""
        self._safe_applied = False
        self._failures = 0
        self.failed_transactions = 0
        """Joint and gripper transactions that failed, in all (a lost bus's included)."""
        self._failing_since = math.nan
        self._joints: dict[str, JointState] | None = None
        self._read_s = math.nan
        self._torques: FloatArray | None = None
        self._gripper: GripperAction | None = None
        self._due = asyncio.Event()
        self._watch_gripper = False
        self.gripper_readable = True
        """False once the bus said it cannot read the gripper."""
        self._gripper_state: GripperState | None = None
        self._gripper_read_s = -math.inf
        self._last_transaction_s = -math.inf
        """Event-loop time of the last joint transaction [s] (the servos' watchdog clock;
        none yet before :meth:`prepare`)."""
        self.rearmed = 0
        """Times joints answered with their torque off after failed transactions (a servo
        rebooted) and got it back."""
        self._torque_readable = True

    # --------------------------------------------------------------- the cycle's side

    def take(self) -> tuple[dict[str, JointState], float] | None:
        """The joint state read since the last call and its age [s] (on the event loop's
        clock), or None."""
        joints, self._joints = self._joints, None
        if joints is None:
            return None
        return joints, max(_now() - self._read_s, 0.0)

    def command(self, torques_n_m: FloatArray) -> FloatArray:
        """Hand over the joint torques [N m] (clipped to the joints' limits); returns what
        will be written (NaN once the bus is lost)."""
        limits = self.torque_limits
        sent = np.minimum(np.maximum(torques_n_m, -limits), limits)  # np.clip, without its wrapper
        if self.failed:
            return np.full(len(sent), math.nan)
        self._torques = sent
        return sent

    def grip(self, action: GripperAction) -> None:
        """Open or close the gripper on the task's next turn."""
        if action != GripperAction.HOLD:
            self._gripper = action

    def watch_gripper(self, watch: bool) -> None:
        """Read the gripper's state (every :data:`GRIPPER_READ_PERIOD_S`) or stop."""
        self._watch_gripper = watch

    def take_gripper(self) -> GripperState | None:
        """The gripper state read since the last call, or None."""
        state, self._gripper_state = self._gripper_state, None
        return state

    def due(self) -> None:
        """A control cycle ended: write its commands and read the joints."""
        self._due.set()

    # ------------------------------------------------------------------- the task

    async def prepare(self) -> dict[str, JointState]:
        """Preflight: read the joints, make them limp (an earlier abort may have left them
        holding), current (torque) mode, torque on, the gripper open. Tries
        :data:`PREFLIGHT_ATTEMPTS` times on link failures, pausing between tries
        (:data:`PREFLIGHT_PAUSE_S`); raises the last
        :class:`~arm_driver.errors.ArmDriverError`."""
        for attempt in range(1, PREFLIGHT_ATTEMPTS + 1):
            try:
                states = await self.bus.read_joint_states()
                await self.bus.disable_torque()
                await self.bus.set_operating_mode(OperatingMode.CURRENT)
                await self.bus.enable_torque()
                await self.bus.open_gripper()
                self._last_transaction_s = _now()
                return states
            except (BusTimeoutError, CommunicationError) as exc:
                if attempt == PREFLIGHT_ATTEMPTS:
                    raise
                pause_s = PREFLIGHT_PAUSE_S * attempt
                self._note("preflight", f"arm bus: {exc}; trying again in {pause_s:g} s")
                await asyncio.sleep(pause_s)
        raise AssertionError("unreachable")

    async def run(self) -> None:
        """The arm task: after each cycle, write, act the gripper, read."""
        while True:
            await self._due.wait()
            self._due.clear()
            if self.failed:
                await self._apply_safe_state()
                continue
            await self.rearm_after_silence()
            torques, self._torques = self._torques, None
            if torques is not None:
                await self.write_torques(torques)
            action, self._gripper = self._gripper, None
            if action is not None:
                await self._move_gripper(action)
            joints = await self.read_joints()
            if joints is not None:
                self._joints, self._read_s = joints, _now()
            if self._watch_gripper and self.gripper_readable:
                await self._read_gripper()

    async def read_joints(self) -> dict[str, JointState] | None:
        """One Sync Read; None when it failed (counted)."""
        try:
            joints = await self.bus.read_joint_states()
        except ArmDriverError as exc:
            self._failed_once(exc)
            return None
        finally:
            self._last_transaction_s = _now()
        failed = self._failures
        self._failures, self._failing_since = 0, math.nan
        if failed:
            await self._rearm_limp_joints(failed)
        return joints

    async def _rearm_limp_joints(self, failed: int) -> None:
        """After ``failed`` joint transactions failed in a row, enable torque again if a
        joint's servo says it is off (it rebooted meanwhile); a bus that cannot tell is
        noted once."""
        if not self._torque_readable:
            return
        try:
            limp = await self.bus.joints_without_torque()
            if limp:
                await self.bus.enable_torque()
        except BusFailedError as exc:
            self._failed_once(exc)
            return
        except BusStateError as exc:
            self._torque_readable = False
            self._note("servo", f"torque state not read ({exc}): a rebooted servo goes unseen")
            return
        except ArmDriverError as exc:
            self._failed_once(exc)
            return
        finally:
            self._last_transaction_s = _now()
        if limp:
            self.rearmed += 1
            self._note(
                "servo",
                f"{', '.join(limp)}: torque off after {failed} failed transactions (the servo "
                "rebooted): torque enabled again",
            )

    async def write_torques(self, torques_n_m: FloatArray) -> None:
        """One Sync Write of the joint torques [N m] (already clipped); failures counted."""
        if self.failed:
            return
        try:
            await self.bus.write_joint_torques(
                dict(zip(self.names, np.asarray(torques_n_m).tolist(), strict=True))
            )
        except ArmDriverError as exc:
            self._failed_once(exc)
        finally:
            self._last_transaction_s = _now()

    async def rearm_after_silence(self) -> None:
        """Enable torque again if the bus was silent long enough (a link loss, a stall)
        for the servos' watchdog to have stopped the joints. 0.8 of the timeout: the
        servos' clock is not ours."""
        watchdog_s = self.watchdog_s
        silent_s = _now() - self._last_transaction_s
        if watchdog_s <= 0.0 or not math.isfinite(silent_s) or silent_s < 0.8 * watchdog_s:
            return
        try:
            await self.bus.enable_torque()
        except ArmDriverError as exc:
            self._failed_once(exc)
            return
        finally:
            self._last_transaction_s = _now()
        self._note(
            "servo",
            f"bus silent for {silent_s * 1e3:.0f} ms (servo watchdog "
            f"{watchdog_s * 1e3:.0f} ms): torque enabled again",
        )

    async def hold_after_landing(self) -> None:
        """On the landed, disarmed vehicle, once the arm task has stopped: the joints hold
        their pose on the servos' own position loop (:meth:`ArmBus.hold_in_place`), which
        the bus's close leaves holding. A limp arm would fall from its stowed pose onto
        the ground and the landing gear (measured in the SITL: 2.0-2.8 rad/s 0.5 s after
        the torque went off). A lost bus, or a failure here, leaves the close's safe
        state (limp), noted."""
        if self.failed:
            return
        try:
            await self.bus.hold_in_place()
        except ArmDriverError as exc:
            self._note("servo", f"joints not set to hold after the landing ({exc}): limp")
            return
        self._note("servo", "landed: the joints hold their pose on the servos' position loop")

    async def _read_gripper(self) -> None:
        """Read the gripper's state if its period is over; failures counted, a bus that
        cannot read it noted once."""
        now = _now()
        if now - self._gripper_read_s < GRIPPER_READ_PERIOD_S:
            return
        self._gripper_read_s = now
        try:
            self._gripper_state = await self.bus.read_gripper()
        except BusFailedError as exc:
            self._failed_once(exc)
        except BusStateError as exc:
            self.gripper_readable = False
            self._note("gripper", f"not read ({exc}): the estimate alone tells the carry")
        except ArmDriverError as exc:
            self._failed_once(exc)
        finally:
            self._last_transaction_s = _now()

    async def _move_gripper(self, action: GripperAction) -> None:
        """Open or close, tried :data:`GRIPPER_ATTEMPTS` times on link errors; a gripper
        that cannot be commanded loses the bus."""
        move = self.bus.close_gripper if action == GripperAction.CLOSE else self.bus.open_gripper
        for attempt in range(1, GRIPPER_ATTEMPTS + 1):
            try:
                await move()
                self._note("gripper", action.value)
                return
            except (BusTimeoutError, CommunicationError) as exc:
                if attempt == GRIPPER_ATTEMPTS:
                    self._lose(f"gripper: {exc}")
            except ArmDriverError as exc:
                self._lose(f"gripper: {exc}")
                return
            finally:
                self._last_transaction_s = _now()

    def _failed_once(self, exc: ArmDriverError) -> None:
        self._failures += 1
        self.failed_transactions += 1
        now = self._vehicle_time()
        if math.isnan(self._failing_since):
            self._failing_since = now
        lasting = now - self._failing_since >= SERVO_FAILURE_S
        if self._failures >= 3 and (lasting or isinstance(exc, BusFailedError)):
            self._lose(str(exc))

    def _lose(self, reason: str) -> None:
        if not self.failed:
            self.failed = True
            self._on_failure(reason)

    async def _apply_safe_state(self) -> None:
        if self._safe_applied:
            return
        self._safe_applied = True
        await self.bus.enter_safe_state()
        self._note("servo", "bus marked failed: joints limp, gripper holding")
