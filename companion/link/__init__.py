"""The companion's MAVLink link to PX4 (DESIGN.md section 6).

``async with MavlinkLink("udpin://0.0.0.0:14540") as link``: one reader task fans the
vehicle's messages out to a latest-value cache and to any number of subscribers, as raw
pymavlink messages and as telemetry samples in our frames (ENU / FLU); commands wait for
their COMMAND_ACK; setpoints go out as SET_ATTITUDE_TARGET in NED / FRD.
"""

from companion.link.errors import (
    CommandDenied,
    CommandError,
    CommandTimeout,
    LinkClosedError,
    LinkError,
    LinkLostError,
    LinkUrlError,
    ParamError,
    ParamRefused,
    ParamTimeout,
    SetpointError,
    SigningKeyError,
    TelemetryError,
    UnknownModeError,
    VehicleNotFoundError,
)
from companion.link.events import LinkLost, LinkRegained, VehicleDetected, VehicleId
from companion.link.fanout import Subscription
from companion.link.mavlink import LinkStats, MavlinkLink
from companion.link.px4_modes import PX4_MODES, Px4Mode, decode_custom_mode, px4_mode
from companion.link.setpoint import quaternion_from_euler_zyx
from companion.link.signing import SigningConfig, load_signing_key
from companion.link.telemetry import (
    BatteryState,
    BodyRates,
    ImuSample,
    LandedState,
    TelemetryDecoder,
    TimesyncReply,
    VehiclePose,
    VehicleStatus,
)
from companion.link.url import LinkUrl, parse_link_url

__all__ = [
    "PX4_MODES",
    "BatteryState",
    "BodyRates",
    "CommandDenied",
    "CommandError",
    "CommandTimeout",
    "ImuSample",
    "LandedState",
    "LinkClosedError",
    "LinkError",
    "LinkLost",
    "LinkLostError",
    "LinkRegained",
    "LinkStats",
    "LinkUrl",
    "LinkUrlError",
    "MavlinkLink",
    "ParamError",
    "ParamRefused",
    "ParamTimeout",
    "Px4Mode",
    "SetpointError",
    "SigningConfig",
    "SigningKeyError",
    "Subscription",
    "TelemetryDecoder",
    "TelemetryError",
    "TimesyncReply",
    "UnknownModeError",
    "VehicleDetected",
    "VehicleId",
    "VehicleNotFoundError",
    "VehiclePose",
    "VehicleStatus",
    "decode_custom_mode",
    "load_signing_key",
    "parse_link_url",
    "px4_mode",
    "quaternion_from_euler_zyx",
]
