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
import struct
from array import array
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from arm_driver.dynamixel import control_table as ct
from arm_driver.dynamixel import units
from arm_driver.dynamixel.instructions import encode_int
from arm_driver.dynamixel.protocol import InstructionPacket
from arm_driver.errors import HardwareErrorStatus, StatusError

try:
    from sitl.servo import _xm430
except ImportError:  # a source checkout without ``python setup.py build_ext --inplace``
    _xm430 = None  # type: ignore[assignment]

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


def _compiled_constants(p: XM430Parameters) -> array:
    """The compiled step's constants (``sitl/servo/_xm430.c``'s C_*) for parameters ``p``."""
    return array(
        "d",
        (
            p.torque_constant_n_m_per_a,
            p.current_time_constant_s,
            p.position_kp_a_per_rad,
            p.position_kd_a_s_per_rad,
            p.overload_current_fraction,
            p.overload_time_s,
            p.winding_resistance_ohm,
            p.back_emf_v_s_per_rad,
            p.viscous_friction_n_m_s_per_rad,
            units.RAD_PER_TICK,
            units.POSITION_CENTER_TICKS,
            units.VELOCITY_RAD_S_PER_UNIT,
            units.CURRENT_A_PER_UNIT,
            units.VOLTAGE_V_PER_UNIT,
            _TORQUE_ENABLE,
            _OPERATING_MODE,
            _CURRENT_LIMIT,
            _GOAL_CURRENT,
            _GOAL_POSITION,
            _PRESENT_CURRENT,
            _PRESENT_VELOCITY,
            _PRESENT_INPUT_VOLTAGE,
            _PROFILE_VELOCITY,
            _BUS_WATCHDOG,
            _TRIPPED,
            ct.BUS_WATCHDOG_MAX,
            ct.BUS_WATCHDOG_UNIT_S,
            _CURRENT_MODE,
            _CURRENT_BASED_POSITION_MODE,
            TABLE_SIZE,
        ),
    )


class _LoopValue:
    """One float of :attr:`XM430Servo._loop`, the loops' state the compiled step shares."""

    def __init__(self, index: int) -> None:
        self.index = index

    def __get__(self, obj: XM430Servo, owner: type | None = None) -> float:
        return obj._loop[self.index]

    def __set__(self, obj: XM430Servo, value: float) -> None:
        obj._loop[self.index] = value


_LOOP_SIZE = 9
"""Floats in :attr:`XM430Servo._loop`, in the order of its :class:`_LoopValue` indices
(``sitl/servo/_xm430.c``'s L_*)."""


class XM430Servo:
    """One simulated XM430-W350; implements :class:`ServoJoint`.

    :meth:`set_state` and :meth:`step` run in the compiled ``sitl.servo._xm430`` where it is
    built (``compiled``), on the control table and :attr:`_loop`; their Python versions
    (``_set_state_reference``, ``_step_reference``) are the reference it is tested against
    bit for bit (tests/test_xm430_model.py) and run any step the compiled one declines (a
    value out of range, the Overload bit).

    Parameters
    ----------
    servo_id
        ID(7), 0-252.
    parameters
        Loop and physical parameters.
    angle_rad
        Initial shaft angle [rad] (0 at tick 2048); Goal Position starts there.
    compiled
        Use the compiled step where it is built (False: the Python reference).
    """

    _angle_rad = _LoopValue(0)
    _rate_rad_s = _LoopValue(1)
    _current_a = _LoopValue(2)
    _lag_dt_s = _LoopValue(3)
    _lag = _LoopValue(4)
    _overload_s = _LoopValue(5)
    _silent_s = _LoopValue(6)
    _hold_rad = _LoopValue(7)
    _profile_rad = _LoopValue(8)

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
        self._loop = array("d", [0.0] * _LOOP_SIZE)
        self._compiled = _xm430 if compiled else None
        self._constants = _compiled_constants(self._parameters)
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
        if self.hardware_error and new[ct.TORQUE_ENABLE.address] and not self.torque_enabled:
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
        return ServoReply(int(error), params, alert=bool(self.hardware_error))

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
        """Present Position(132) and Present Velocity(128) from the shaft's angle and rate."""
        compiled = self._compiled
        if compiled is None or not compiled.set_state(
            self.table, self._loop, self._constants, angle_rad, rate_rad_s
        ):
            self._set_state_reference(angle_rad, rate_rad_s)

    def _set_state_reference(self, angle_rad: float, rate_rad_s: float) -> None:
        self._angle_rad = float(angle_rad)
        self._rate_rad_s = float(rate_rad_s)
        ticks = units.rad_to_ticks(self._angle_rad)
        velocity = units.rad_s_to_velocity_units(self._rate_rad_s)
        try:  # the two adjacent entries in one pack (every servo, every plant step)
            _VELOCITY_POSITION.pack_into(self.table, _PRESENT_VELOCITY, velocity, ticks)
        except struct.error:  # out of range: _put raises as the encoders do
            self._put(ct.PRESENT_POSITION, ticks)
            self._put(ct.PRESENT_VELOCITY, velocity)

    # The loops below run for every servo at every plant step: they read the few entries
    # they need straight from the table (as get() does, without its per-call lookups).

    def torque_n_m(self) -> float:
        """Output torque [N m]: torque constant x present current (0 with torque off)
        minus the gearbox's viscous friction."""
        p = self.parameters
        friction = p.viscous_friction_n_m_s_per_rad * self._rate_rad_s
        if self.table[_TORQUE_ENABLE] != 1:
            return -friction
        return p.torque_constant_n_m_per_a * self._current_a - friction

    def commanded_current_a(self) -> float:
        """Current the active control mode asks for now [A], clamped to the limits."""
        if self.table[_TORQUE_ENABLE] != 1:
            return 0.0
        return self._command_a(self._limit_a())

    def _limit_a(self) -> float:
        """Current Limit(38) [A]."""
        return units.current_units_to_a(_UINT16.unpack_from(self.table, _CURRENT_LIMIT)[0])

    def _command_a(self, limit_a: float) -> float:
        """:meth:`commanded_current_a` with torque on and Current Limit ``limit_a`` [A]."""
        table = self.table
        goal_a = units.current_units_to_a(_INT16.unpack_from(table, _GOAL_CURRENT)[0])
        mode = table[_OPERATING_MODE]
        tripped = table[_BUS_WATCHDOG] == _TRIPPED
        if mode == _CURRENT_MODE:
            command = 0.0 if tripped else goal_a
        else:
            if tripped:
                goal_rad = self._hold_rad
            elif _UINT32.unpack_from(table, _PROFILE_VELOCITY)[0] == 0:
                goal_rad = units.ticks_to_rad(_INT32.unpack_from(table, _GOAL_POSITION)[0])
            else:
                goal_rad = self._profile_rad
            p = self.parameters
            command = p.position_kp_a_per_rad * (goal_rad - self._angle_rad)
            command -= p.position_kd_a_s_per_rad * self._rate_rad_s
            if mode == _CURRENT_BASED_POSITION_MODE:
                limit_a = min(limit_a, abs(goal_a))
        return max(-limit_a, min(limit_a, command))

    def step(self, dt_s: float) -> None:
        """Advance the bus watchdog, the current loop and the overload detector by ``dt_s`` [s]."""
        compiled = self._compiled
        if compiled is None or not compiled.step(self.table, self._loop, self._constants, dt_s):
            self._step_reference(dt_s)

    def _step_reference(self, dt_s: float) -> None:
        if not dt_s >= 0.0:
            raise ValueError(f"time step {dt_s} s must be >= 0")
        self._watch(dt_s)
        self._advance_profile(dt_s)
        p = self.parameters
        table = self.table
        limit_a = self._limit_a()
        command = self._command_a(limit_a) if table[_TORQUE_ENABLE] == 1 else 0.0
        driven = self._drivable_a(command)
        if dt_s != self._lag_dt_s:  # the current loop's factor, once per step size
            self._lag_dt_s = dt_s
            self._lag = -math.expm1(-dt_s / p.current_time_constant_s)
        self._current_a += (driven - self._current_a) * self._lag
        overloaded = abs(command) >= p.overload_current_fraction * limit_a > 0.0
        self._overload_s = self._overload_s + dt_s if overloaded else 0.0
        if self._overload_s >= p.overload_time_s:
            self.inject_hardware_error(HardwareErrorStatus.OVERLOAD)
        if table[_TORQUE_ENABLE] != 1:
            self._current_a = 0.0
        current = units.a_to_current_units(self._current_a)
        try:
            _INT16.pack_into(table, _PRESENT_CURRENT, current)
        except struct.error:  # out of range: _put raises as the encoders do
            self._put(ct.PRESENT_CURRENT, current)

    def _advance_profile(self, dt_s: float) -> None:
        """Move the profile's position toward Goal Position at Profile Velocity (at once
        when it is 0); with torque off it follows the shaft. Not kept in Current Control
        Mode, which has no position goal (leaving it needs torque off, which resets it)."""
        table = self.table
        if table[_TORQUE_ENABLE] != 1:
            self._profile_rad = self._angle_rad
            return
        if table[_OPERATING_MODE] == _CURRENT_MODE:
            return
        goal_rad = units.ticks_to_rad(_INT32.unpack_from(table, _GOAL_POSITION)[0])
        rate = units.velocity_units_to_rad_s(_UINT32.unpack_from(table, _PROFILE_VELOCITY)[0])
        if rate == 0.0:
            self._profile_rad = goal_rad
            return
        step = rate * dt_s
        self._profile_rad += max(-step, min(step, goal_rad - self._profile_rad))

    def _drivable_a(self, command_a: float) -> float:
        """``command_a`` [A] within what the supply voltage drives against the back-EMF."""
        p = self.parameters
        volts = units.voltage_units_to_v(_UINT16.unpack_from(self.table, _PRESENT_INPUT_VOLTAGE)[0])
        emf = p.back_emf_v_s_per_rad * self._rate_rad_s
        low = (-volts - emf) / p.winding_resistance_ohm
        high = (volts - emf) / p.winding_resistance_ohm
        return max(low, min(high, command_a))

    def _watch(self, dt_s: float) -> None:
        """Count the silence while the watchdog is armed; trip when it exceeds the timeout."""
        timeout = self.table[_BUS_WATCHDOG]
        if self.table[_TORQUE_ENABLE] != 1 or not 0 < timeout <= ct.BUS_WATCHDOG_MAX:
            self._silent_s = 0.0
            return
        self._silent_s += dt_s
        if self._silent_s > timeout * ct.BUS_WATCHDOG_UNIT_S:
            self.table[_BUS_WATCHDOG] = _TRIPPED
            self._hold_rad = self._angle_rad


assert ct.TORQUE_ENABLE.size == ct.OPERATING_MODE.size == 1
assert not ct.CURRENT_LIMIT.signed and ct.GOAL_CURRENT.signed and ct.GOAL_POSITION.signed
assert (ct.CURRENT_LIMIT.size, ct.GOAL_CURRENT.size, ct.PRESENT_CURRENT.size) == (2, 2, 2)
assert ct.PRESENT_CURRENT.signed and ct.GOAL_POSITION.size == 4
assert not ct.PRESENT_INPUT_VOLTAGE.signed and ct.PRESENT_INPUT_VOLTAGE.size == 2
assert ct.PRESENT_VELOCITY.end == ct.PRESENT_POSITION.address
assert ct.PRESENT_VELOCITY.size == ct.PRESENT_POSITION.size == 4
assert ct.PROFILE_VELOCITY.size == 4 and not ct.PROFILE_VELOCITY.signed
_TORQUE_ENABLE = ct.TORQUE_ENABLE.address
_OPERATING_MODE = ct.OPERATING_MODE.address
_CURRENT_LIMIT = ct.CURRENT_LIMIT.address
_GOAL_CURRENT = ct.GOAL_CURRENT.address
_GOAL_POSITION = ct.GOAL_POSITION.address
_PRESENT_CURRENT = ct.PRESENT_CURRENT.address
_PRESENT_VELOCITY = ct.PRESENT_VELOCITY.address
_PRESENT_INPUT_VOLTAGE = ct.PRESENT_INPUT_VOLTAGE.address
_PROFILE_VELOCITY = ct.PROFILE_VELOCITY.address
_UINT16 = struct.Struct("<H")
_UINT32 = struct.Struct("<I")
_INT16 = struct.Struct("<h")
_INT32 = struct.Struct("<i")
_VELOCITY_POSITION = struct.Struct("<ii")
"""Little-endian control-table fields (Protocol 2.0), read and written in place."""
_BUS_WATCHDOG = ct.BUS_WATCHDOG.address
_TRIPPED = ct.BUS_WATCHDOG_TRIPPED & 0xFF
_GOAL_VALUES = range(100, ct.GOAL_POSITION.end)
"""Goal PWM(100) .. Goal Position(116): read-only while the bus watchdog is tripped."""
_CURRENT_MODE = int(ct.OperatingMode.CURRENT)
_CURRENT_BASED_POSITION_MODE = int(ct.OperatingMode.CURRENT_BASED_POSITION)


def _encode_uint(value: int, size: int) -> bytes:
    return int(value).to_bytes(size, "little", signed=False)


def _writable(address: int, end: int) -> bool:
    if address >= _WRITABLE_EEPROM.start and end <= _WRITABLE_EEPROM.stop:
        return True
    return any(address >= area.start and end <= area.stop for area in _WRITABLE_RAM)
