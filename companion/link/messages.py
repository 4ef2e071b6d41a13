"""What the link's API gives of pymavlink's messages: typed protocols, not ``Any``.

pymavlink ships no type information, so its message objects are described here by what
the companion reads of them. :class:`MavlinkMessage` is any message (its header); the
others are the messages the command layer reads by field (COMMAND_ACK, PARAM_VALUE,
MESSAGE_INTERVAL).
``MavlinkLink.subscribe`` and ``latest`` return these for a message-name key (see
:class:`~companion.link.mavlink.MavlinkLink`); a new field read by name is a new protocol
here, so that the type checker sees it.
"""

from __future__ import annotations

from typing import Protocol

__all__ = ["CommandAck", "MavlinkMessage", "MessageInterval", "ParamValue"]


class MavlinkMessage(Protocol):
    """Any pymavlink message: its type name and MAVLink header."""

    def get_type(self) -> str:
        """The message name (``"HEARTBEAT"``)."""
        ...

    def get_srcSystem(self) -> int:
        """System id of the sender."""
        ...

    def get_srcComponent(self) -> int:
        """Component id of the sender."""
        ...

    def get_seq(self) -> int:
        """The sender's sequence number, 0..255."""
        ...

    def get_msgId(self) -> int:
        """The MAVLink message id."""
        ...


class CommandAck(MavlinkMessage, Protocol):
    """COMMAND_ACK (#77)."""

    command: int
    """MAV_CMD acknowledged."""
    result: int
    """MAV_RESULT."""
    target_system: int
    target_component: int


class ParamValue(MavlinkMessage, Protocol):
    """PARAM_VALUE (#22); ``param_value`` carries an integer parameter bytewise (see
    :func:`~companion.link.px4_commands.decode_param_value`)."""

    param_id: str
    param_value: float
    param_type: int
    """MAV_PARAM_TYPE."""
    param_count: int
    param_index: int


class MessageInterval(MavlinkMessage, Protocol):
    """MESSAGE_INTERVAL (#244), the answer to MAV_CMD_GET_MESSAGE_INTERVAL."""

    message_id: int
    interval_us: int
    """The stream's interval [us]; -1 not streamed (PX4 also says -1 for a stream sent on
    every update, GPS_RAW_INT on its onboard link), 0 not available."""
