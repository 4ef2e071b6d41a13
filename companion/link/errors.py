"""The exception tree of :mod:`companion.link` (STYLE.md habit 3: one tree, no return codes).

::

    LinkError
    ├── LinkUrlError            a connection URL that cannot be parsed (also a ValueError)
    ├── SigningKeyError         a signing key file that is missing or malformed
    ├── SetpointError           a setpoint that cannot be sent (NaN, thrust outside [0, 1])
    ├── UnknownModeError        a PX4 mode name that is not in the table (also a KeyError)
    ├── TelemetryError          a received message with garbage values (counted, never
    │                           raised out of the reader)
    ├── LinkClosedError         the link is closed, or its reader failed (see __cause__)
    ├── VehicleNotFoundError    no PX4 heartbeat within the wait (also a TimeoutError)
    ├── LinkLostError           heartbeat or telemetry silent for longer than configured
    ├── CommandError            a COMMAND_LONG that did not succeed
    │   ├── CommandDenied       the vehicle answered with a result other than ACCEPTED
    │   └── CommandTimeout      no final COMMAND_ACK after every attempt (also a TimeoutError)
    └── ParamError              a parameter that could not be read or set
        ├── ParamTimeout        no PARAM_VALUE after every attempt (also a TimeoutError)
        └── ParamRefused        the vehicle kept another value than the one set
"""

from __future__ import annotations

__all__ = [
    "CommandDenied",
    "CommandError",
    "CommandTimeout",
    "LinkClosedError",
    "LinkError",
    "LinkLostError",
    "LinkUrlError",
    "ParamError",
    "ParamRefused",
    "ParamTimeout",
    "SetpointError",
    "SigningKeyError",
    "TelemetryError",
    "UnknownModeError",
    "VehicleNotFoundError",
]


class LinkError(Exception):
    """Base of every error raised by :mod:`companion.link`."""


class LinkUrlError(LinkError, ValueError):
    """A connection URL that cannot be parsed; the message names the URL and the reason."""


class SigningKeyError(LinkError):
    """A MAVLink 2 signing key file that is missing, unreadable or not a 32-byte key."""


class SetpointError(LinkError, ValueError):
    """A setpoint with a non-finite or out-of-range value; nothing was sent."""


class UnknownModeError(LinkError, KeyError):
    """A PX4 flight mode name that is not in :data:`companion.link.px4_modes.PX4_MODES`."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


class TelemetryError(LinkError, ValueError):
    """A message whose values are unusable (NaN, zero quaternion, unsupported frame).

    Raised by the pure decoders; the link's reader counts it per reason and drops the
    message, it never ends the reader.
    """

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


class LinkClosedError(LinkError):
    """The link is closed, or its reader stopped on a transport error (``__cause__``)."""


class VehicleNotFoundError(LinkError, TimeoutError):
    """No PX4 HEARTBEAT arrived within the wait."""


class LinkLostError(LinkError):
    """The vehicle's heartbeat or telemetry has been silent for longer than configured."""

    def __init__(self, reason: str, silent_s: float) -> None:
        super().__init__(f"link lost: no {reason} for {silent_s:.2f} s")
        self.reason = reason
        self.silent_s = silent_s


class CommandError(LinkError):
    """A COMMAND_LONG that did not succeed."""

    def __init__(self, message: str, command: int) -> None:
        super().__init__(message)
        self.command = command


class CommandDenied(CommandError):
    """The vehicle answered the command with ``result`` (a MAV_RESULT other than ACCEPTED)."""

    def __init__(self, command: int, result: int, command_name: str, result_name: str) -> None:
        super().__init__(f"{command_name} refused by the vehicle: {result_name}", command)
        self.result = result
        self.result_name = result_name


class CommandTimeout(CommandError, TimeoutError):
    """No final COMMAND_ACK after ``attempts`` transmissions."""

    def __init__(self, command: int, command_name: str, attempts: int, timeout_s: float) -> None:
        super().__init__(
            f"{command_name}: no COMMAND_ACK after {attempts} attempts of {timeout_s:g} s",
            command,
        )
        self.attempts = attempts


class ParamError(LinkError):
    """A parameter of the vehicle that could not be read or set (``name``)."""

    def __init__(self, message: str, name: str) -> None:
        super().__init__(message)
        self.name = name


class ParamTimeout(ParamError, TimeoutError):
    """No PARAM_VALUE of the parameter after every attempt (PX4 does not answer a
    parameter it does not have)."""

    def __init__(self, name: str, attempts: int, timeout_s: float) -> None:
        super().__init__(
            f"parameter {name}: no PARAM_VALUE after {attempts} attempts of {timeout_s:g} s "
            "(the vehicle may not have it)",
            name,
        )


class ParamRefused(ParamError):
    """The vehicle answered a PARAM_SET with another value than the one set."""

    def __init__(self, name: str, wanted: float, kept: float) -> None:
        super().__init__(f"parameter {name}: set to {wanted:g}, the vehicle kept {kept:g}", name)
        self.wanted = wanted
        self.kept = kept
