"""The exception tree of ``arm_driver``: every fault the driver reports is one of these.

::

    ArmDriverError
    ├── BusTimeoutError      (also a TimeoutError) no reply, or only part of one, in time
    ├── CommunicationError   bytes that are not a valid packet: header, length, id, stuffing
    │   └── CrcError         a frame whose CRC-16 does not match its bytes
    ├── InstructionError     the servo answered, rejecting the instruction (error number)
    ├── HardwareError        the servo reports a hardware fault (Alert bit, address 70)
    │   └── NodeHealthError  a DroneCAN actuator node reports health ERROR or CRITICAL
    └── LimitError           (also a ValueError) a joint-space command outside its limits,
                             refused before anything is sent

No function of the driver returns an error code: it raises one of these, with a message
that names the servo and says what happened. Callers that know more (which joint, which
instruction) add it with :meth:`BaseException.add_note`.

Protocol facts used here (ROBOTIS e-Manual, DYNAMIXEL Protocol 2.0, "Status Packet" /
"Error"; e-Manual XM430-W350, "Hardware Error Status(70)" and "Shutdown(63)"):

- the status packet's error byte holds the Alert flag in bit 7 and an error number in
  bits 0-6; the numbers 0x01-0x07 are :class:`StatusError`;
- Alert means the device has a problem whose cause is in Hardware Error Status (address
  70), bits as :class:`HardwareErrorStatus` (the same layout as Shutdown(63), whose
  factory value 52 selects Overheating, Electrical Shock and Overload). A servo whose
  Shutdown(63) selects the reported bit has cleared Torque Enable(64); only a REBOOT
  instruction (or a power cycle) turns torque on again.
"""

from __future__ import annotations

import enum
from typing import Any

__all__ = [
    "ArmDriverError",
    "BusTimeoutError",
    "CommunicationError",
    "CrcError",
    "HardwareError",
    "HardwareErrorStatus",
    "InstructionError",
    "LimitError",
    "NodeHealth",
    "NodeHealthError",
    "StatusError",
]


class StatusError(enum.IntEnum):
    """Error numbers of a Protocol 2.0 status packet (error byte bits 0-6).

    Values and meanings from the e-Manual, Protocol 2.0, "Status Packet" -> "Error".
    """

    RESULT_FAIL = 0x01
    INSTRUCTION = 0x02
    CRC = 0x03
    DATA_RANGE = 0x04
    DATA_LENGTH = 0x05
    DATA_LIMIT = 0x06
    ACCESS = 0x07

    @property
    def description(self) -> str:
        """What the e-Manual says this error number means."""
        return _STATUS_ERROR_TEXT[self]


_STATUS_ERROR_TEXT = {
    StatusError.RESULT_FAIL: "Result Fail: the servo failed to process the instruction packet",
    StatusError.INSTRUCTION: (
        "Instruction Error: undefined instruction, or Action without a Reg Write"
    ),
    StatusError.CRC: "CRC Error: the servo received a packet whose CRC did not match",
    StatusError.DATA_RANGE: (
        "Data Range Error: the value written is outside the address's minimum/maximum"
    ),
    StatusError.DATA_LENGTH: (
        "Data Length Error: the data is shorter than the item at that address"
    ),
    StatusError.DATA_LIMIT: "Data Limit Error: the value written is outside its Limit value",
    StatusError.ACCESS: (
        "Access Error: read-only or undefined address, or an EEPROM write while torque is enabled"
    ),
}


class HardwareErrorStatus(enum.IntFlag):
    """Bits of Hardware Error Status (address 70) of the XM430-W350 (X-series layout).

    Bits 1, 6 and 7 are unused ("always 0") per the e-Manual; a value with them set is
    kept as is (``IntFlag`` keeps unknown bits) so nothing read from a servo is lost.
    """

    INPUT_VOLTAGE = 0x01
    """Input voltage outside Min/Max Voltage Limit(34, 32)."""
    OVERHEATING = 0x04
    """Internal temperature above Temperature Limit(31)."""
    MOTOR_ENCODER = 0x08
    """Malfunction of the motor encoder."""
    ELECTRICAL_SHOCK = 0x10
    """Electrical shock on the circuit, or too little power to run the motor."""
    OVERLOAD = 0x20
    """Persistent load above the maximum output."""

    def describe(self) -> str:
        """The set bits as readable names, e.g. ``"Overheating Error, Overload Error"``."""
        names = [_HARDWARE_ERROR_TEXT[bit] for bit in HardwareErrorStatus if bit in self]
        unknown = int(self) & ~_KNOWN_HARDWARE_BITS
        if unknown:
            names.append(f"unknown bits 0x{unknown:02X}")
        return ", ".join(names) if names else "no bit set"


_HARDWARE_ERROR_TEXT = {
    HardwareErrorStatus.INPUT_VOLTAGE: "Input Voltage Error",
    HardwareErrorStatus.OVERHEATING: "Overheating Error",
    HardwareErrorStatus.MOTOR_ENCODER: "Motor Encoder Error",
    HardwareErrorStatus.ELECTRICAL_SHOCK: "Electrical Shock Error",
    HardwareErrorStatus.OVERLOAD: "Overload Error",
}
_KNOWN_HARDWARE_BITS = 0x01 | 0x04 | 0x08 | 0x10 | 0x20


def _servo(servo_id: int | None) -> str:
    return "servo ?" if servo_id is None else f"servo {servo_id}"


def _rebuild(cls: type[ArmDriverError], args: tuple[Any, ...], state: dict[str, Any]) -> Any:
    """Unpickle an :class:`ArmDriverError` without calling its ``__init__``."""
    error = cls.__new__(cls, *args)
    error.args = args
    error.__dict__.update(state)
    return error


class ArmDriverError(Exception):
    """Base of every exception raised by ``arm_driver``.

    Parameters
    ----------
    message
        Complete, human-readable message (servo id and what happened).
    servo_id
        Bus id of the servo concerned, or None when not known (e.g. a frame too damaged
        to tell where it came from).
    """

    def __init__(self, message: str, *, servo_id: int | None = None) -> None:
        super().__init__(message)
        self.servo_id = servo_id

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""

    def __reduce__(self) -> tuple[Any, ...]:
        # Subclasses take other constructor arguments than ``args``: rebuild from state,
        # so errors survive pickling (multiprocessing, logging handlers).
        return (_rebuild, (type(self), self.args, dict(self.__dict__)))


class BusTimeoutError(ArmDriverError, TimeoutError):
    """No reply, or only part of one, arrived within the deadline.

    Parameters
    ----------
    servo_id
        Servo whose reply was awaited (None for a broadcast).
    timeout_s
        The deadline that passed [s].
    received_bytes
        Bytes of the reply received before the deadline (0: nothing at all).
    what
        What was awaited, for the message (default ``"status packet"``).
    """

    def __init__(
        self,
        servo_id: int | None,
        timeout_s: float,
        *,
        received_bytes: int = 0,
        what: str = "status packet",
    ) -> None:
        got = (
            "nothing received"
            if received_bytes == 0
            else f"only {received_bytes} byte(s) of it received"
        )
        super().__init__(
            f"{_servo(servo_id)}: no complete {what} within {timeout_s * 1e3:.1f} ms ({got})",
            servo_id=servo_id,
        )
        self.timeout_s = timeout_s
        self.received_bytes = received_bytes


class CommunicationError(ArmDriverError):
    """Bytes that are not a valid packet: bad header, length, id, stuffing or contents."""


class CrcError(CommunicationError):
    """A frame whose CRC-16 does not match its bytes (damaged on the line).

    Parameters
    ----------
    computed
        CRC-16 computed over the received bytes.
    received
        CRC-16 carried by the frame.
    servo_id
        Id byte of the damaged frame, which may itself be damaged.
    """

    def __init__(self, computed: int, received: int, *, servo_id: int | None = None) -> None:
        super().__init__(
            f"{_servo(servo_id)}: CRC mismatch, frame carries 0x{received:04X} but its "
            f"bytes give 0x{computed:04X}; frame dropped",
            servo_id=servo_id,
        )
        self.computed = computed
        self.received = received


class InstructionError(ArmDriverError):
    """The servo answered with a nonzero error number: it did not carry out the instruction.

    Parameters
    ----------
    servo_id
        Servo that answered.
    error_number
        Bits 0-6 of the status packet's error byte (1-127).
    """

    def __init__(self, servo_id: int, error_number: int) -> None:
        try:
            error: StatusError | None = StatusError(error_number)
        except ValueError:
            error = None
        text = (
            error.description
            if error is not None
            else "an error number the Protocol 2.0 e-Manual does not define"
        )
        super().__init__(
            f"{_servo(servo_id)} rejected the instruction, error 0x{error_number:02X}: {text}",
            servo_id=servo_id,
        )
        self.error_number = error_number
        self.error = error


class HardwareError(ArmDriverError):
    """The servo reports a hardware fault: the Alert bit (0x80) of its status packet.

    The status packet only says *that* there is a fault; *which* is in Hardware Error
    Status (address 70). The codec raises this with ``status=None``; the bus then reads
    address 70 (ignoring the Alert bit for that read) and raises it again with the bits.

    Parameters
    ----------
    servo_id
        Servo reporting the fault.
    status
        Decoded Hardware Error Status (address 70), or None when not read yet.
    error_number
        Error number that came with the Alert bit in the same status packet (0: none).
    """

    def __init__(
        self,
        servo_id: int,
        status: HardwareErrorStatus | None = None,
        *,
        error_number: int = 0,
    ) -> None:
        if status is None:
            cause = "Hardware Error Status (address 70) not read yet"
        else:
            cause = f"Hardware Error Status 0x{int(status):02X}: {status.describe()}"
        also = f"; the status also carried error 0x{error_number:02X}" if error_number else ""
        super().__init__(
            f"{_servo(servo_id)}: hardware error (Alert bit set): {cause}{also}. Torque is "
            "off if Shutdown(63) selects these bits; only a REBOOT turns it on again",
            servo_id=servo_id,
        )
        self.status = status
        self.error_number = error_number


class NodeHealth(enum.IntEnum):
    """Health of a DroneCAN node (``uavcan.protocol.NodeStatus.health``, DSDL 341)."""

    OK = 0
    """The node is functioning properly."""
    WARNING = 1
    """A critical parameter went out of range or the node encountered a minor failure."""
    ERROR = 2
    """The node encountered a major failure."""
    CRITICAL = 3
    """The node suffered a fatal malfunction."""


class NodeHealthError(HardwareError):
    """A DroneCAN node driving an actuator reports health ERROR or CRITICAL.

    DroneCAN says only *how bad* (``NodeStatus.health``); *what* is in the node's
    ``vendor_specific_status_code``, whose meaning the vendor defines (the emulator in
    :mod:`sitl.servo.dronecan_node` puts :class:`HardwareErrorStatus` bits there).

    Parameters
    ----------
    servo_id
        Actuator id of the joint concerned.
    node_id
        DroneCAN node id of the node hosting the actuator.
    health
        The reported health.
    vendor_status_code
        ``NodeStatus.vendor_specific_status_code`` (uint16), undecoded.
    """

    def __init__(
        self, servo_id: int, node_id: int, health: NodeHealth, vendor_status_code: int
    ) -> None:
        ArmDriverError.__init__(
            self,
            f"actuator {servo_id}: its DroneCAN node {node_id} reports health "
            f"{health.name} (vendor status code 0x{vendor_status_code:04X}); the node "
            "decides whether its output is still driven",
            servo_id=servo_id,
        )
        self.status = None
        self.error_number = 0
        self.node_id = node_id
        self.health = health
        self.vendor_status_code = vendor_status_code


class LimitError(ArmDriverError, ValueError):
    """A joint-space command outside its limits, refused before anything was sent.

    Parameters
    ----------
    joint
        Joint name, for the message.
    value
        The commanded value [``unit``].
    lower, upper
        The limits it violates [``unit``].
    unit
        Unit of ``value``, ``lower`` and ``upper`` (e.g. ``"rad"``, ``"rad/s"``, ``"N m"``).
    servo_id
        Servo that drives the joint, when known.
    """

    def __init__(
        self,
        joint: str,
        value: float,
        lower: float,
        upper: float,
        *,
        unit: str = "rad",
        servo_id: int | None = None,
    ) -> None:
        where = f"joint {joint!r}" + ("" if servo_id is None else f" (servo {servo_id})")
        super().__init__(
            f"{where}: command {value:.6g} {unit} is outside its limits "
            f"[{lower:.6g}, {upper:.6g}] {unit}; nothing was sent",
            servo_id=servo_id,
        )
        self.joint = joint
        self.value = value
        self.lower = lower
        self.upper = upper
        self.unit = unit
