"""A pure model of an XM430-W350 servo: control-table bytes, current and position loops.

No I/O and no clock: :class:`XM430Servo` answers decoded instructions
(:meth:`~XM430Servo.handle`) and advances its loops by a time step the caller gives
(:meth:`~XM430Servo.step`). :mod:`sitl.servo.pty_server` puts servos on a
pseudo-terminal; the SITL couples each to a physics joint through :class:`ServoJoint`.

What is modelled (addresses, sizes and units from
:mod:`arm_driver.dynamixel.control_table`, defaults from the e-Manual's XM430-W350 page):

- the control table as bytes (addresses 0-146), factory defaults; writes to read-only or
  undefined addresses and EEPROM writes (addresses 0-63) while Torque Enable(64) is 1 are
  refused with an Access Error, the servo's documented behaviour;
- Status Return Level(68) and Return Delay Time(9) are kept for the server to honour;
- current loop: a first-order lag from the commanded current to Present Current(126)
  with time constant ``current_time_constant_s``, the command clamped to +-Current
  Limit(38);
- Current Control Mode: command = Goal Current(102);
- Position and Current-based Position Control Modes: a PD law on the profile's position,
  ``i = kp (theta_profile - theta) - kd omega`` [A], clamped to +-Current Limit, and in
  Current-based Position mode also to +-|Goal Current| (the mode's torque limit);
- the velocity-based profile: with Profile Velocity(112) 0 (the factory default) the
  profile's position is Goal Position(116) itself; with a Profile Velocity, it moves
  toward Goal Position at that rate (the servo's own smooth ramp to each new goal);
  with torque off it follows the shaft, so torque on starts the ramp where the shaft is;
- the motor's voltage limit: the current the H-bridge can drive at shaft rate omega lies
  in ``[(-V - k_e omega) / R, (V - k_e omega) / R]`` with V = Present Input Voltage(144),
  so a servo on full command runs no faster than the datasheet's no-load speed (46 rpm at
  12 V, 4.8 rad/s) and its current at stall is the datasheet's 2.3 A;
- output torque = ``torque_constant_n_m_per_a`` x present current (0 with torque off)
  minus the gearbox's viscous friction ``viscous_friction_n_m_s_per_rad`` x omega, which
  acts with torque off too (an unpowered arm does not swing freely);
- overload: a command at or above ``overload_current_fraction`` x Current Limit for
  ``overload_time_s`` sets the Overload bit of Hardware Error Status(70); when
  Shutdown(63) selects a bit that is set, torque turns off and stays off until a Reboot;
- Bus Watchdog(98), as the e-Manual describes it (see
  :mod:`arm_driver.dynamixel.control_table`): with torque on and a timeout of 1-127 x
  20 ms, a silence longer than the timeout (time counted by :meth:`XM430Servo.step`)
  trips it. Every :meth:`~XM430Servo.read`, :meth:`~XM430Servo.write`,
  :meth:`~XM430Servo.handle` and :meth:`~XM430Servo.reboot` is an instruction packet
  addressed to the servo and restarts the count (the server calls them for packets to
  its id, broadcasts, and Sync Read/Write packets that list it). Tripped, it reads -1,
  writes to the goal values (addresses 100-119) get a Data Range Error and change
  nothing, and writing 0 clears it; Torque Enable is left as it is.

Watchdog behaviour the e-Manual leaves open, modelled on the conservative side: a
Sync packet that does not list the servo does not count as communication; "the
servo stops" is 0 A in Current Control Mode (the joint goes limp) and holding the
shaft angle where it tripped in the position modes; writing 1-127 while tripped is
refused (Data Range Error), only 0 clears; once cleared, the servo applies its old
Goal Current or Goal Position again, so a host must write a new goal.

Not modelled: velocity and PWM modes (refused: Data Range Error), Profile
Acceleration(108) (infinite, as its 0) and the time-based profile (Drive Mode bit 2),
indirect addresses, voltage and temperature dynamics, Drive Mode's reverse bit, the gearbox's
Coulomb friction and backlash.

Torque constant: 1.78 N m/A is the ratio of the datasheet's stall torque (4.1 N m) to
stall current (2.3 A) at 12 V, an example value, not a calibration. Winding resistance
12 V / 2.3 A and back-EMF constant 12 V / 4.8 rad/s come from the same datasheet figures;
the viscous friction (0.02 N m s/rad at the output) is an example value.
"""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from arm_driver.dynamixel import control_table as ct
from arm_driver.dynamixel.instructions import encode_int
from arm_driver.dynamixel.protocol import InstructionPacket
from arm_driver.errors import HardwareErrorStatus, StatusError
from companion.compiled import twin
from sitl import vehicle_step

__all__ = [
    "EXAMPLE_TORQUE_CONSTANT_N_M_PER_A",
    "TABLE_SIZE",
    "ServoJoint",
    "ServoReply",
    "XM430Parameters",
    "XM430Servo",
]

EXAMPLE_TORQUE_CONSTANT_N_M_PER_A = 4.1 / 2.3
"""Stall torque / stall current of the XM430-W350 datasheet at 12 V [N m/A] (~1.78)."""
_DATASHEET_VOLTAGE_V = 12.0
_DATASHEET_STALL_CURRENT_A = 2.3
_DATASHEET_NO_LOAD_SPEED_RAD_S = 46.0 * 2.0 * math.pi / 60.0
TABLE_SIZE = ct.PRESENT_TEMPERATURE.end
"""Bytes of control table modelled: addresses 0-146."""

_WRITABLE_EEPROM = range(ct.ID.address, ct.SHUTDOWN.end)
# RAM entries the host may write: Torque Enable .. Status Return Level (64-68), then
# Velocity/Position gains, feedforward gains, Bus Watchdog, Goal PWM/Current/Velocity,
# profiles and Goal Position (76-119), per the e-Manual's RAM table.
_WRITABLE_RAM = (range(64, 69), range(76, 120))
_MODES = (
    ct.OperatingMode.CURRENT,
    ct.OperatingMode.POSITION,
    ct.OperatingMode.EXTENDED_POSITION,
    ct.OperatingMode.CURRENT_BASED_POSITION,
)
_FACTORY = (
    (ct.MODEL_NUMBER, ct.XM430_W350_MODEL_NUMBER),
    (ct.FIRMWARE_VERSION, 48),
    (ct.BAUD_RATE, 1),
    (ct.RETURN_DELAY_TIME, 250),
    (ct.OPERATING_MODE, ct.OperatingMode.POSITION),
    (ct.TEMPERATURE_LIMIT, 80),
    (ct.MAX_VOLTAGE_LIMIT, 160),
    (ct.MIN_VOLTAGE_LIMIT, 95),
    (ct.CURRENT_LIMIT, 1193),
    (ct.VELOCITY_LIMIT, 200),
    (ct.MAX_POSITION_LIMIT, 4095),
    (ct.MIN_POSITION_LIMIT, 0),
    (ct.SHUTDOWN, 52),
    (ct.STATUS_RETURN_LEVEL, ct.StatusReturnLevel.ALL),
    (ct.PRESENT_INPUT_VOLTAGE, 120),
    (ct.PRESENT_TEMPERATURE, 30),
)


@runtime_checkable
class ServoJoint(Protocol):
    """What a physics joint sees of a simulated servo: angle and rate in, torque out."""

    def set_state(self, angle_rad: float, rate_rad_s: float) -> None:
        """Give the servo its output shaft angle [rad] (0 at tick 2048) and rate [rad/s]."""

    def torque_n_m(self) -> float:
        """Torque the servo applies to the joint now [N m], counter-clockwise positive."""

    def couple(self, angle_rad: float, rate_rad_s: float) -> float:
        """:meth:`set_state`, then :meth:`torque_n_m` [N m] (once per plant step)."""

    def step(self, dt_s: float) -> None:
        """Advance the servo's control loops by ``dt_s`` [s]."""


@dataclass(frozen=True)
class XM430Parameters:
    """Physical and loop parameters of the model (not in the control table).

    Attributes
    ----------
    torque_constant_n_m_per_a
        Output torque per motor current [N m/A].
    current_time_constant_s
        Time constant of the current loop's first-order lag [s].
    position_kp_a_per_rad
        Position loop proportional gain [A/rad].
    position_kd_a_s_per_rad
        Position loop derivative gain [A s/rad].
    overload_current_fraction
        Fraction of Current Limit at or above which the command counts as overload [-].
    overload_time_s
        Sustained overload time before the Overload bit is set [s].
    winding_resistance_ohm
        Motor resistance seen by the H-bridge [ohm] (12 V / 2.3 A stall).
    back_emf_v_s_per_rad
        Back-EMF per output shaft rate [V s/rad] (12 V at the 46 rpm no-load speed).
    viscous_friction_n_m_s_per_rad
        Gearbox viscous friction at the output shaft [N m s/rad], torque on or off.
    """

    torque_constant_n_m_per_a: float = EXAMPLE_TORQUE_CONSTANT_N_M_PER_A
    current_time_constant_s: float = 0.5e-3
    position_kp_a_per_rad: float = 10.0
    position_kd_a_s_per_rad: float = 0.3
    overload_current_fraction: float = 0.95
    overload_time_s: float = 1.0
    winding_resistance_ohm: float = _DATASHEET_VOLTAGE_V / _DATASHEET_STALL_CURRENT_A
    back_emf_v_s_per_rad: float = _DATASHEET_VOLTAGE_V / _DATASHEET_NO_LOAD_SPEED_RAD_S
    viscous_friction_n_m_s_per_rad: float = 0.02

    def __post_init__(self) -> None:
        for name in (
            "torque_constant_n_m_per_a",
            "current_time_constant_s",
            "overload_time_s",
            "winding_resistance_ohm",
        ):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        for name in ("back_emf_v_s_per_rad", "viscous_friction_n_m_s_per_rad"):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if not 0.0 < self.overload_current_fraction <= 1.0:
            raise ValueError("overload_current_fraction must be in (0, 1]")


@dataclass(frozen=True)
class ServoReply:
    """What the servo answers to one instruction (before framing).

    Attributes
    ----------
    error
        Error number (0: none).
    params
        Reply parameters.
    alert
        Alert bit: Hardware Error Status(70) is nonzero.
    """

    error: int = 0
    params: bytes = b""
    alert: bool = False


class _LoopValue:
    """One float of :attr:`XM430Servo._loop`, the loops' state (the servos' part of
    :mod:`sitl.vehicle_step`)."""

    def __init__(self, index: int) -> None:
        self.index = index

    def __get__(self, obj: XM430Servo, owner: type | None = None) -> float:
        return obj._loop[self.index]

    def __set__(self, obj: XM430Servo, value: float) -> None:
        obj._loop[self.index] = value


class XM430Servo:
    """One simulated XM430-W350; implements :class:`ServoJoint`.

    The per-step physics (:meth:`set_state`, :meth:`step`, :meth:`torque_n_m`,
    :meth:`commanded_current_a`) is the servos' part of :mod:`sitl.vehicle_step` on the
    control table and :attr:`_loop`, compiled where its twin is built from it
    (``compiled``).

    Parameters
    ----------
    servo_id
        ID(7), 0-252.
    parameters
        Loop and physical parameters.
    angle_rad
        Initial shaft angle [rad] (0 at tick 2048); Goal Position starts there.
    compiled
        Use the compiled twin of :mod:`sitl.vehicle_step` where it is built (False:
        its Python source).
    """

    _angle_rad = _LoopValue(vehicle_step.L_ANGLE)
    _rate_rad_s = _LoopValue(vehicle_step.L_RATE)
    _current_a = _LoopValue(vehicle_step.L_CURRENT)
    _lag_dt_s = _LoopValue(vehicle_step.L_LAG_DT)
    _lag = _LoopValue(vehicle_step.L_LAG)
    _overload_s = _LoopValue(vehicle_step.L_OVERLOAD)
    _silent_s = _LoopValue(vehicle_step.L_SILENT)
    _hold_rad = _LoopValue(vehicle_step.L_HOLD)
    _profile_rad = _LoopValue(vehicle_step.L_PROFILE)

    def __init__(
        self,
        servo_id: int,
        parameters: XM430Parameters | None = None,
        *,
        angle_rad: float = 0.0,
        compiled: bool = True,
    ) -> None:
        if not 0 <= servo_id <= 252:
            raise ValueError(f"servo id {servo_id} out of range (0-252)")
        self._parameters = parameters if parameters is not None else XM430Parameters()
        self._loop = array("d", [0.0] * vehicle_step.SERVO_LOOP_SIZE)
        self._physics = twin(vehicle_step, compiled)
        p = self._parameters
        self._params = vehicle_step.servo_parameters(
            p.torque_constant_n_m_per_a,
            p.current_time_constant_s,
            p.position_kp_a_per_rad,
            p.position_kd_a_s_per_rad,
            p.overload_current_fraction,
            p.overload_time_s,
            p.winding_resistance_ohm,
            p.back_emf_v_s_per_rad,
            p.viscous_friction_n_m_s_per_rad,
        )
        self.table = bytearray(TABLE_SIZE)
        for entry, value in _FACTORY:
            self._put(entry, int(value))
        self._put(ct.ID, servo_id)
        self._current_a = 0.0
        self._lag_dt_s = math.nan
        self._lag = 0.0
        self._overload_s = 0.0
        self._silent_s = 0.0
        self._hold_rad = float(angle_rad)
        self._profile_rad = float(angle_rad)
        self.set_state(angle_rad, 0.0)
        self._put(ct.GOAL_POSITION, self.get(ct.PRESENT_POSITION))

    # -- control-table access -------------------------------------------------------

    def get(self, entry: ct.ControlTableEntry) -> int:
        """Raw value of a control-table entry."""
        # entry.decode() without its length check (an entry always fits the table): the
        # servo loops read several entries every plant step.
        address = entry.address
        return int.from_bytes(
            self.table[address : address + entry.size], "little", signed=entry.signed
        )

    def _put(self, entry: ct.ControlTableEntry, value: int) -> None:
        address, size = entry.address, entry.size
        try:
            data = int(value).to_bytes(size, "little", signed=entry.signed)
        except OverflowError:  # out of range: encode_int's ValueError, or _encode_uint's
            encode = encode_int if entry.signed else _encode_uint
            data = encode(value, size)
        self.table[address : address + size] = data

    @property
    def parameters(self) -> XM430Parameters:
        """Loop and physical parameters (fixed at construction: the compiled step holds
        them as constants)."""
        return self._parameters

    @property
    def servo_id(self) -> int:
        """ID(7)."""
        return self.get(ct.ID)

    @property
    def torque_enabled(self) -> bool:
        """Torque Enable(64) is 1."""
        return self.get(ct.TORQUE_ENABLE) == 1

    @property
    def hardware_error(self) -> HardwareErrorStatus:
        """Hardware Error Status(70)."""
        return HardwareErrorStatus(self.get(ct.HARDWARE_ERROR_STATUS))

    @property
    def watchdog_tripped(self) -> bool:
        """Bus Watchdog(98) reads -1: the servo stopped for want of instruction packets."""
        return self.table[_BUS_WATCHDOG] == _TRIPPED

    @property
    def return_delay_s(self) -> float:
        """Return Delay Time(9) [s] (2 us per count)."""
        return self.get(ct.RETURN_DELAY_TIME) * 2e-6

    @property
    def status_return_level(self) -> int:
        """Status Return Level(68)."""
        return self.get(ct.STATUS_RETURN_LEVEL)

    def inject_hardware_error(self, bits: HardwareErrorStatus) -> None:
        """Set bits of Hardware Error Status(70) as a fault would, with its shutdown."""
        self._put(ct.HARDWARE_ERROR_STATUS, int(self.hardware_error | bits))
        if self.get(ct.SHUTDOWN) & int(bits):
            self._put(ct.TORQUE_ENABLE, 0)

    # -- instructions -----------------------------------------------------------------

    def read(self, address: int, length: int) -> ServoReply:
        """Read ``length`` bytes at ``address`` (Read, Sync Read)."""
        self._silent_s = 0.0
        if length < 1 or address + length > TABLE_SIZE:
            return self._reply(StatusError.ACCESS)
        return self._reply(0, bytes(self.table[address : address + length]))

    def write(self, address: int, data: bytes) -> ServoReply:
        """Write ``data`` at ``address`` (Write, Sync Write); all or nothing."""
        self._silent_s = 0.0
        end = address + len(data)
        if not data or not _writable(address, end):
            return self._reply(StatusError.ACCESS)
        if address < ct.TORQUE_ENABLE.address and self.torque_enabled:
            return self._reply(StatusError.ACCESS)
        if self.watchdog_tripped and address < _GOAL_VALUES.stop and end > _GOAL_VALUES.start:
            return self._reply(StatusError.DATA_RANGE)  # goal values are read-only
        if address <= _BUS_WATCHDOG < end:
            timeout = data[_BUS_WATCHDOG - address]
            if timeout > (0 if self.watchdog_tripped else ct.BUS_WATCHDOG_MAX):
                return self._reply(StatusError.DATA_RANGE)
        new = bytearray(self.table)
        new[address:end] = data
        error = self._check(new)
        if error:
            return self._reply(error)
        if (
            self.table[_HARDWARE_ERROR]
            and new[ct.TORQUE_ENABLE.address]
            and not self.torque_enabled
        ):
            return self._reply(StatusError.RESULT_FAIL)  # only a Reboot re-enables torque
        self.table[:] = new
        return self._reply(0)

    def reboot(self) -> ServoReply:
        """Reboot: clear Hardware Error Status and turn torque off (RAM reset in part)."""
        self._silent_s = 0.0
        reply = self._reply(0)
        self._put(ct.HARDWARE_ERROR_STATUS, 0)
        self._put(ct.TORQUE_ENABLE, 0)
        self._put(ct.BUS_WATCHDOG, 0)
        self._put(ct.GOAL_CURRENT, 0)
        self._put(ct.PROFILE_VELOCITY, 0)
        self._put(ct.GOAL_POSITION, self.get(ct.PRESENT_POSITION))
        self._overload_s = 0.0
        return reply

    def handle(self, packet: InstructionPacket) -> ServoReply:
        """Answer a Ping, Read, Write or Reboot addressed to this servo.

        Sync Read and Sync Write are split per servo by the server, which calls
        :meth:`read` and :meth:`write`. Other instructions get an Instruction Error.
        """
        params = packet.params
        self._silent_s = 0.0
        if packet.instruction == 0x01:
            info = self.table[ct.MODEL_NUMBER.address : ct.MODEL_NUMBER.end]
            return self._reply(0, bytes(info) + bytes((self.get(ct.FIRMWARE_VERSION),)))
        if packet.instruction == 0x02 and len(params) == 4:
            return self.read(
                int.from_bytes(params[:2], "little"), int.from_bytes(params[2:], "little")
            )
        if packet.instruction == 0x03 and len(params) > 2:
            return self.write(int.from_bytes(params[:2], "little"), params[2:])
        if packet.instruction == 0x08 and not params:
            return self.reboot()
        if packet.instruction in (0x02, 0x03, 0x08):
            return self._reply(StatusError.DATA_LENGTH)
        return self._reply(StatusError.INSTRUCTION)

    def _reply(self, error: int, params: bytes = b"") -> ServoReply:
        return ServoReply(int(error), params, alert=self.table[_HARDWARE_ERROR] != 0)

    def _check(self, new: bytearray) -> int:
        mode = new[ct.OPERATING_MODE.address]
        if mode not in _MODES:
            return StatusError.DATA_RANGE
        if new[ct.TORQUE_ENABLE.address] > 1 or new[ct.STATUS_RETURN_LEVEL.address] > 2:
            return StatusError.DATA_RANGE
        limit = int.from_bytes(new[ct.CURRENT_LIMIT.address : ct.CURRENT_LIMIT.end], "little")
        goal = int.from_bytes(
            new[ct.GOAL_CURRENT.address : ct.GOAL_CURRENT.end], "little", signed=True
        )
        if limit > 1193 or abs(goal) > limit:
            return StatusError.DATA_LIMIT
        return 0

    # -- physics (ServoJoint) -----------------------------------------------------------

    def set_state(self, angle_rad: float, rate_rad_s: float) -> None:
        """Present Position(132) and Present Velocity(128) from the shaft's angle [rad] and
        rate [rad/s]."""
        self._physics.servo_set_state(self.table, self._loop, angle_rad, rate_rad_s)

    def torque_n_m(self) -> float:
        """Output torque [N m]: torque constant x present current (0 with torque off)
        minus the gearbox's viscous friction."""
        return self._physics.servo_torque_n_m(self.table, self._loop, self._params)

    def couple(self, angle_rad: float, rate_rad_s: float) -> float:
        """:meth:`set_state`, then :meth:`torque_n_m` [N m], in one call of the loop."""
        return self._physics.servo_couple(
            self.table, self._loop, self._params, angle_rad, rate_rad_s
        )

    @property
    def physics_buffers(self) -> tuple[bytearray, array, array]:
        """(control table, loop state, parameters): the buffers the per-step physics works
        on, for a compiled step that couples the servo itself
        (:func:`sitl.vehicle_step.vehicle_step`)."""
        return self.table, self._loop, self._params

    def commanded_current_a(self) -> float:
        """Current the active control mode asks for now [A], clamped to the limits."""
        return self._physics.servo_command_a(self.table, self._loop, self._params)

    def step(self, dt_s: float) -> None:
        """Advance the bus watchdog, the current loop and the overload detector by ``dt_s`` [s]."""
        if self._physics.servo_step(self.table, self._loop, self._params, dt_s):
            self.overloaded()

    def overloaded(self) -> None:
        """The overload timer ran out in the last step (taken here or by a compiled step on
        :attr:`physics_buffers`): set the Overload bit, with its shutdown, and write
        Present Current."""
        self.inject_hardware_error(HardwareErrorStatus.OVERLOAD)
        self._physics.servo_write_current(self.table, self._loop)


_BUS_WATCHDOG = ct.BUS_WATCHDOG.address
_HARDWARE_ERROR = ct.HARDWARE_ERROR_STATUS.address
"""Hardware Error Status(70), one byte: any bit set is the Alert of every reply."""
_TRIPPED = ct.BUS_WATCHDOG_TRIPPED & 0xFF
_GOAL_VALUES = range(100, ct.GOAL_POSITION.end)
"""Goal PWM(100) .. Goal Position(116): read-only while the bus watchdog is tripped."""


def _encode_uint(value: int, size: int) -> bytes:
    return int(value).to_bytes(size, "little", signed=False)


def _writable(address: int, end: int) -> bool:
    if address >= _WRITABLE_EEPROM.start and end <= _WRITABLE_EEPROM.stop:
        return True
    return any(address >= area.start and end <= area.stop for area in _WRITABLE_RAM)
