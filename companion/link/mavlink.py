"""The companion's MAVLink 2 link to a PX4 autopilot, over pymavlink, on asyncio.

One reader task per link (STYLE.md habit 6). The port is non-blocking; the event loop's
``add_reader`` sets an event when its file descriptor is readable, and the reader task
then drains every available datagram / byte chunk, parses it with pymavlink's MAVLink 2
codec and fans each message out (:mod:`companion.link.fanout`): to the latest-value cache
of its type, to every subscriber of its type, and, for the vehicle's telemetry, as
samples in our frames (:mod:`companion.link.telemetry`). A datagram that is one plain
ODOMETRY frame, the pose of every control cycle, is read without pymavlink
(:mod:`companion.link.cycle_codec`) and gives only its samples, unless something subscribes
to the ``"ODOMETRY"`` message itself (it is then not kept as the latest message either).
No threads, except one short-lived worker that opens the port in ``__aenter__`` (a TCP
connect may wait).

Besides the reader, two small tasks run while the link is open: the companion's own
HEARTBEAT at 1 Hz (MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, component
MAV_COMP_ID_ONBOARD_COMPUTER) and a watchdog that publishes :class:`LinkLost` when the
vehicle's heartbeat or telemetry is silent for longer than configured. If any of the three
fails, the link closes and every subscriber's ``get`` raises :class:`LinkClosedError`
carrying the cause.

The vehicle is the first PX4 autopilot heard (HEARTBEAT with MAV_AUTOPILOT_PX4, optionally
of a given system id); commands and setpoints go to its system and component id.
"""

from __future__ import annotations

import asyncio
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, TypeVar, overload

from numpy.typing import ArrayLike
from pymavlink.dialects.v20 import common as mavlink2

from companion.link.cycle_codec import (
    ODOMETRY_ID,
    OdometryFields,
    attitude_target_frame,
    odometry_frame,
)
from companion.link.errors import LinkClosedError, LinkLostError, VehicleNotFoundError
from companion.link.events import LinkLost, LinkRegained, VehicleDetected, VehicleId
from companion.link.fanout import FanOut, Key, Subscription
from companion.link.messages import CommandAck, MavlinkMessage, MessageInterval, ParamValue
from companion.link.px4_commands import Px4Commands
from companion.link.setpoint import (
    ATTITUDE_ONLY_TYPE_MASK,
    POSITION_VELOCITY_ACCELERATION_YAW_TYPE_MASK,
    attitude_target_ned_frd,
    checked_thrust,
    position_target_local_ned,
    quaternion_from_euler_zyx,
)
from companion.link.signing import SigningConfig, advance_timestamp
from companion.link.telemetry import PoseSource, TelemetryDecoder
from companion.link.transport import MemoryTransport, Transport, open_transport
from companion.link.url import LinkUrl, parse_link_url

if TYPE_CHECKING:
    from companion.control.setpoints import AttitudeThrustSetpoint, PositionSetpoint

__all__ = ["LinkStats", "MavlinkLink"]

_MAX_READS_PER_WAKE = 64
_MAGIC_V2 = bytes((mavlink2.PROTOCOL_MARKER_V2,))
"""Datagrams / chunks read before the reader yields to other tasks once."""

_T = TypeVar("_T")


@dataclass(frozen=True)
class LinkStats:
    """Counters of a link since it opened (a snapshot)."""

    messages_received: int
    """Frames decoded into known messages (any sender)."""
    messages_sent: int
    bad_frames: int
    """Frames with a bad CRC, length or flags."""
    garbage_bytes: int
    """Bytes that were not the start of any frame."""
    signature_rejected: int
    """Unsigned or badly signed frames refused by signing."""
    unknown_messages: int
    """Well-formed frames of message ids outside the common dialect."""
    sequence_lost: int
    """Frames missing from the senders' sequence numbers."""
    unsent_frames: int
    """Frames that could not be sent (full buffer, or no ``udpin`` peer yet)."""
    telemetry_rejected: dict[str, int]
    """Vehicle messages dropped by the telemetry decoder, per reason."""


class MavlinkLink(Px4Commands):
    """MAVLink 2 link to a PX4 vehicle; use ``async with MavlinkLink(url) as link``.

    Nothing happens in the constructor: the port opens in ``__aenter__`` (or
    :meth:`open`), and :meth:`close` is idempotent.

    Parameters
    ----------
    url : str or LinkUrl
        Connection URL, e.g. ``udpin://0.0.0.0:14540`` (see :mod:`companion.link.url`).
    system_id : int
        Our MAVLink system id, 1..255. MAVLink recommends that components on one vehicle
        share the autopilot's system id, hence the default 1.
    component_id : int
        Our component id [default MAV_COMP_ID_ONBOARD_COMPUTER = 191].
    signing : SigningConfig, optional
        MAVLink 2 signing (see :mod:`companion.link.signing`); None sends unsigned frames.
    vehicle_system_id : int, optional
        Accept only this autopilot system id as the vehicle [default: the first PX4].
    heartbeat_timeout_s : float
        Vehicle heartbeat silence that counts as a lost link [s] (PX4 sends 1 Hz): on the
        companion's clock and, while timed telemetry comes, on the vehicle's as well (a
        simulator in lockstep may run slower than real time; its heartbeat comes at 1 Hz
        of its own time).
    telemetry_timeout_s : float
        Telemetry silence (poses, rates, IMU) that counts as a lost link [s]; watched
        from the first telemetry sample on.
    pose_from : {"odometry", "local_position"}
        Source of :class:`VehiclePose` (see :class:`TelemetryDecoder`).
    heartbeat_period_s : float
        Period of our own HEARTBEAT [s].
    """

    def __init__(
        self,
        url: str | LinkUrl,
        *,
        system_id: int = 1,
        component_id: int = mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER,
        signing: SigningConfig | None = None,
        vehicle_system_id: int | None = None,
        heartbeat_timeout_s: float = 3.0,
        telemetry_timeout_s: float = 0.5,
        pose_from: PoseSource = "odometry",
        heartbeat_period_s: float = 1.0,
    ) -> None:
        self.url = url if isinstance(url, LinkUrl) else parse_link_url(url)
        for name, value in (("system_id", system_id), ("component_id", component_id)):
            if not 1 <= value <= 255:
                raise ValueError(f"{name} {value} is outside 1..255")
        for name, period in (
            ("heartbeat_timeout_s", heartbeat_timeout_s),
            ("telemetry_timeout_s", telemetry_timeout_s),
            ("heartbeat_period_s", heartbeat_period_s),
        ):
            if not period > 0.0:
                raise ValueError(f"{name} must be positive, got {period}")
        self.system_id = system_id
        self.component_id = component_id
        self.signing = signing
        self.vehicle_system_id = vehicle_system_id
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.telemetry_timeout_s = telemetry_timeout_s
        self.heartbeat_period_s = heartbeat_period_s
        self.pose_from: PoseSource = pose_from
        self._decoder = TelemetryDecoder(pose_from)
        self._fanout = FanOut()
        self._transport: Transport | MemoryTransport | None = None
        self._mav: mavlink2.MAVLink | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._closed = False
        self._vehicle: VehicleId | None = None
        self._vehicle_found: asyncio.Event | None = None
        self._readable: asyncio.Event | None = None
        self._last_heartbeat: float | None = None
        self._heartbeat_vehicle_ms: int | None = None
        """Vehicle time when the last heartbeat came (the latest telemetry's) [ms]."""
        self._last_telemetry: float | None = None
        self._lost: LinkLost | None = None
        self._lost_at = 0.0
        self._sequence: dict[tuple[int, int], int] = {}
        self._counts: Counter[str] = Counter()
        self._from_vehicle: Counter[int] = Counter()
        """Messages received from the vehicle's system, per message id."""
        self._rejected: Counter[str] = Counter()
        self._command_locks: dict[int, asyncio.Lock] = {}

    # --- lifecycle -----------------------------------------------------------------

    async def __aenter__(self) -> MavlinkLink:
        await self.open()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def open(self) -> None:
        """Open the port and start the reader, heartbeat and watchdog tasks."""
        if self._transport is not None or self._closed:
            raise LinkClosedError("a MavlinkLink opens once; make a new one")
        loop = asyncio.get_running_loop()
        if self.url.scheme == "memory":  # on the lockstep loop: no thread, nothing waits
            transport = open_transport(self.url, self.system_id, self.component_id)
        else:
            transport = await asyncio.to_thread(
                open_transport, self.url, self.system_id, self.component_id
            )
        self._transport = transport
        self._mav = mavlink2.MAVLink(transport, self.system_id, self.component_id)
        self._mav.robust_parsing = True
        if self.signing is not None:
            self.signing.apply(self._mav)
        self._vehicle_found = asyncio.Event()
        self._readable = asyncio.Event()
        loop.add_reader(transport.fd, self._readable.set)
        for work in (self._read_loop(), self._heartbeat_loop(), self._watchdog_loop()):
            task = loop.create_task(work)
            task.add_done_callback(self._task_done)
            self._tasks.append(task)

    async def close(self) -> None:
        """Stop the tasks and close the port (idempotent); subscribers see the end."""
        tasks = self._shutdown(None)
        await asyncio.gather(*tasks, return_exceptions=True)

    def _shutdown(self, error: BaseException | None) -> list[asyncio.Task[None]]:
        tasks, self._tasks = self._tasks, []
        if self._closed:
            return tasks
        self._closed = True
        current = asyncio.current_task()
        for task in tasks:
            if task is not current:
                task.cancel()
        if self._transport is not None:
            asyncio.get_running_loop().remove_reader(self._transport.fd)
            self._transport.close()
        self._fanout.close(error)
        return [t for t in tasks if t is not current]

    def _task_done(self, task: asyncio.Task[None]) -> None:
        if not task.cancelled() and task.exception() is not None:
            self._shutdown(task.exception())

    @property
    def closed(self) -> bool:
        return self._closed

    # --- subscriptions and state -------------------------------------------------

    @overload
    def subscribe(self, key: type[_T], /, *, maxsize: int = 64) -> Subscription[_T]: ...
    @overload
    def subscribe(
        self, key: Literal["COMMAND_ACK"], /, *, maxsize: int = 64
    ) -> Subscription[CommandAck]: ...
    @overload
    def subscribe(
        self, key: Literal["PARAM_VALUE"], /, *, maxsize: int = 64
    ) -> Subscription[ParamValue]: ...
    @overload
    def subscribe(
        self, key: Literal["MESSAGE_INTERVAL"], /, *, maxsize: int = 64
    ) -> Subscription[MessageInterval]: ...
    @overload
    def subscribe(self, key: str, /, *, maxsize: int = 64) -> Subscription[MavlinkMessage]: ...
    @overload
    def subscribe(self, *keys: Key, maxsize: int = 64) -> Subscription[object]: ...
    def subscribe(self, *keys: Key, maxsize: int = 64) -> Subscription[object]:
        """A new queue of the items of ``keys``: MAVLink message names (``"HEARTBEAT"``,
        pymavlink message objects) and/or sample and event classes (``VehiclePose``,
        ``LinkLost``, ...). Each subscription gets every item; a full queue drops its
        oldest item (``Subscription.dropped``).

        Typed by its key: a class gives its instances, a message name a
        :class:`~companion.link.messages.MavlinkMessage` (COMMAND_ACK and PARAM_VALUE
        their own protocols), several keys ``object``."""
        return self._fanout.subscribe(keys, maxsize)

    @overload
    def latest(self, key: type[_T]) -> _T | None: ...
    @overload
    def latest(self, key: str) -> MavlinkMessage | None: ...
    def latest(self, key: Key) -> object | None:
        """The latest item of a key (see :meth:`subscribe`, typed alike), or None if none
        yet."""
        return self._fanout.latest.get(key)

    @property
    def vehicle(self) -> VehicleId | None:
        """The detected autopilot, or None before its first HEARTBEAT."""
        return self._vehicle

    async def wait_vehicle(self, timeout_s: float = 10.0) -> VehicleId:
        """Wait for the first PX4 HEARTBEAT; raises ``VehicleNotFoundError``."""
        if self._vehicle_found is None:
            raise LinkClosedError("the link is not open")
        try:
            async with asyncio.timeout(timeout_s):
                await self._vehicle_found.wait()
        except TimeoutError:
            raise VehicleNotFoundError(
                f"{self.url}: no PX4 heartbeat within {timeout_s:g} s"
            ) from None
        assert self._vehicle is not None
        return self._vehicle

    @property
    def lost(self) -> LinkLost | None:
        """The current loss, or None while heartbeat and telemetry are fresh."""
        return self._lost

    def raise_if_lost(self) -> None:
        """Raise ``LinkLostError`` during a loss, ``LinkClosedError`` after close."""
        if self._closed:
            raise LinkClosedError("the link is closed") from self._fanout.error
        if self._lost is not None:
            silent = asyncio.get_running_loop().time() - self._lost_at + self._lost.silent_s
            raise LinkLostError(self._lost.reason, silent)

    @property
    def stats(self) -> LinkStats:
        c = self._counts
        return LinkStats(
            messages_received=c["received"],
            messages_sent=c["sent"],
            bad_frames=c["bad_frames"],
            garbage_bytes=c["garbage_bytes"],
            signature_rejected=c["signature_rejected"],
            unknown_messages=c["unknown"],
            sequence_lost=c["sequence_lost"],
            unsent_frames=self._transport.unsent_frames if self._transport else 0,
            telemetry_rejected=dict(self._rejected),
        )

    def messages_from_vehicle(self) -> dict[int, int]:
        """How many messages of each id the vehicle's system sent since the link opened
        (its heartbeats and what else came from its system id; a snapshot)."""
        return dict(self._from_vehicle)

    def take_longest_socket_wait_s(self) -> float | None:
        """The longest a datagram waited in the socket, from its arrival to the reader's
        read, since the previous call [s]; None where the transport cannot tell (serial,
        TCP, no kernel arrival times) or the link is not open."""
        return None if self._transport is None else self._transport.take_longest_socket_wait_s()

    # --- sending ---------------------------------------------------------------------

    @property
    def mav(self) -> mavlink2.MAVLink:
        """pymavlink's codec of this link, to build messages (``link.mav.xxx_encode``)."""
        if self._mav is None:
            raise LinkClosedError("the link is not open")
        return self._mav

    def send_message(self, msg: MavlinkMessage) -> None:
        """Send a pymavlink message object now (signed if signing is on)."""
        if self._closed or self._mav is None:
            raise LinkClosedError("the link is closed") from self._fanout.error
        if self.signing is not None:
            advance_timestamp(self._mav)
        self._mav.send(msg)
        self._counts["sent"] += 1

    def _require_vehicle(self) -> VehicleId:
        if self._vehicle is None:
            raise VehicleNotFoundError(f"{self.url}: no vehicle detected yet")
        return self._vehicle

    def send_attitude_target(
        self, q_enu_flu: ArrayLike, thrust_relative: float, time_boot_ms: int
    ) -> None:
        """SET_ATTITUDE_TARGET to the vehicle: attitude body FLU -> world ENU ``[w, x, y,
        z]`` (sent as FRD -> NED), PX4's relative thrust in [0, 1] (a fraction of the
        maximum collective thrust; PX4 linearizes it with THR_MDL_FAC), type_mask 7 (body
        rates ignored), and ``time_boot_ms`` [ms] (sent modulo 2^32). Framed by
        :func:`~companion.link.cycle_codec.attitude_target_frame` (through pymavlink when
        signing).

        Raises ``SetpointError`` for a bad value (nothing is sent), and
        ``VehicleNotFoundError`` before the vehicle is detected.
        """
        vehicle = self._require_vehicle()
        q, thrust = attitude_target_ned_frd(q_enu_flu, thrust_relative)
        self._send_attitude_target(vehicle, q, thrust, time_boot_ms)

    def _send_attitude_target(
        self,
        vehicle: VehicleId,
        q: tuple[float, float, float, float] | list[float],
        thrust: float,
        time_boot_ms: int,
    ) -> None:
        """SET_ATTITUDE_TARGET to ``vehicle`` of ``q`` body FRD -> world NED and the
        relative ``thrust`` (both checked), as :meth:`send_attitude_target` sends it."""
        mav = self.mav
        if self.signing is not None or mav.signing.sign_outgoing:
            msg = mav.set_attitude_target_encode(
                int(time_boot_ms) & 0xFFFFFFFF,
                vehicle.system_id,
                vehicle.component_id,
                ATTITUDE_ONLY_TYPE_MASK,
                q,
                0.0,
                0.0,
                0.0,
                thrust,
            )
            self.send_message(msg)
            return
        if self._closed:
            raise LinkClosedError("the link is closed") from self._fanout.error
        # What pymavlink's send does with the frame it packs (the same bytes).
        frame = attitude_target_frame(
            mav.seq, mav.srcSystem, mav.srcComponent, int(time_boot_ms) & 0xFFFFFFFF,
            vehicle.system_id, vehicle.component_id, ATTITUDE_ONLY_TYPE_MASK, q, thrust,
        )  # fmt: skip
        mav.file.write(frame)
        mav.seq = (mav.seq + 1) % 256
        mav.total_packets_sent += 1
        mav.total_bytes_sent += len(frame)
        self._counts["sent"] += 1

    def send_setpoint(self, setpoint: AttitudeThrustSetpoint, time_boot_ms: int) -> None:
        """:meth:`send_attitude_target` of a
        :class:`companion.control.setpoints.AttitudeThrustSetpoint` (its ZYX Euler angles as a
        quaternion, or the quaternion NED/FRD the compiled step made of them, and its
        relative thrust)."""
        q_ned = setpoint.q_ned_frd
        if q_ned is None:
            q = quaternion_from_euler_zyx(setpoint.roll_rad, setpoint.pitch_rad, setpoint.yaw_rad)
            self.send_attitude_target(q, setpoint.thrust_relative, time_boot_ms)
            return
        vehicle = self._require_vehicle()
        thrust = checked_thrust(setpoint.thrust_relative)
        self._send_attitude_target(vehicle, q_ned, thrust, time_boot_ms)

    def send_position_target(self, setpoint: PositionSetpoint, time_boot_ms: int) -> None:
        """SET_POSITION_TARGET_LOCAL_NED to the vehicle (MAV_FRAME_LOCAL_NED): position,
        velocity, acceleration and yaw of ``setpoint`` (ENU, sent as NED), yaw rate ignored,
        for PX4's position controller to fly; ``time_boot_ms`` [ms] (sent modulo 2^32).

        Raises ``SetpointError`` for a value that is not finite (nothing is sent), and
        ``VehicleNotFoundError`` before the vehicle is detected.
        """
        vehicle = self._require_vehicle()
        target = position_target_local_ned(setpoint)
        msg = self.mav.set_position_target_local_ned_encode(
            int(time_boot_ms) & 0xFFFFFFFF,
            vehicle.system_id,
            vehicle.component_id,
            mavlink2.MAV_FRAME_LOCAL_NED,
            POSITION_VELOCITY_ACCELERATION_YAW_TYPE_MASK,
            *target.position_m,
            *target.velocity_m_s,
            *target.acceleration_m_s2,
            target.yaw_rad,
            0.0,
        )
        self.send_message(msg)

    def send_timesync(self, ts1_ns: int) -> None:
        """A TIMESYNC request (``tc1`` 0) stamped ``ts1_ns`` [ns]; the vehicle answers with
        its clock and the stamp echoed (:class:`~companion.link.telemetry.TimesyncReply`)."""
        self.send_message(self.mav.timesync_encode(0, int(ts1_ns)))

    # --- tasks -------------------------------------------------------------------------

    async def _read_loop(self) -> None:
        assert self._readable is not None and self._transport is not None
        loop = asyncio.get_running_loop()
        readable, transport = self._readable, self._transport
        while True:
            await readable.wait()
            readable.clear()
            for _ in range(_MAX_READS_PER_WAKE):
                data = transport.read()
                if not data:
                    break
                self._receive(data, loop.time())
            else:
                readable.set()
                await asyncio.sleep(0)

    def _receive(self, data: bytes, now: float) -> None:
        assert self._mav is not None
        if (
            data[:1] == _MAGIC_V2
            and self.signing is None
            and not self._fanout.has_subscribers("ODOMETRY")
            and self._mav.buf_len() == 0
        ):
            odometry = odometry_frame(data)
            if odometry is not None:
                self._counts["received"] += 1
                self._odometry(odometry, now)
                return
        for msg in self._mav.parse_buffer(data) or ():
            kind = msg.get_type()
            if kind == "BAD_DATA":
                if msg.reason == "Bad prefix":
                    self._counts["garbage_bytes"] += len(msg.data)
                elif msg.reason == "Invalid signature":
                    self._counts["signature_rejected"] += 1
                else:
                    self._counts["bad_frames"] += 1
                continue
            if kind.startswith("UNKNOWN_"):
                self._counts["unknown"] += 1
                continue
            self._counts["received"] += 1
            self._dispatch(msg, kind, now)

    def _sequence_of(self, src: tuple[int, int], seq: int) -> None:
        """Count the frames lost from ``src`` before this one (its sequence number)."""
        last = self._sequence.get(src)
        if last is not None:
            self._counts["sequence_lost"] += (seq - last - 1) % 256
        self._sequence[src] = seq

    def _odometry(self, fields: OdometryFields, now: float) -> None:
        """An ODOMETRY read from its frame (:mod:`companion.link.cycle_codec`), taken as
        :meth:`_dispatch` takes pymavlink's (its samples published; the message itself
        only while something subscribes to it, which sends it through pymavlink)."""
        src = (fields.src_system, fields.src_component)
        self._sequence_of(src, fields.seq)
        if self._vehicle is None or src[0] != self._vehicle.system_id:
            return
        self._from_vehicle[ODOMETRY_ID] += 1
        self._publish_samples("ODOMETRY", self._decoder.odometry, fields, now)

    def _dispatch(self, msg: Any, kind: str, now: float) -> None:
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        self._sequence_of(src, msg.get_seq())
        self._fanout.publish(kind, msg)
        if kind == "HEARTBEAT":
            if not self._is_vehicle_heartbeat(msg, src):
                return
            self._last_heartbeat = now
            self._heartbeat_vehicle_ms = self._decoder.time_boot_ms
        elif self._vehicle is None or src[0] != self._vehicle.system_id:
            return
        self._from_vehicle[msg.get_msgId()] += 1
        self._publish_samples(kind, self._decoder.decode, msg, now)

    def _publish_samples(
        self, kind: str, decode: Callable[[Any], tuple[object, ...]], msg: Any, now: float
    ) -> None:
        """Publish the samples ``decode`` makes of a message of the vehicle's (a refused
        one counted under its reason), and watch the telemetry's freshness."""
        try:
            samples = decode(msg)
        except Exception as exc:  # TelemetryError, or a field pymavlink left unusable
            self._rejected[getattr(exc, "reason", type(exc).__name__)] += 1
            return
        for sample in samples:
            self._fanout.publish(type(sample), sample)
        if samples and kind not in ("HEARTBEAT", "EXTENDED_SYS_STATE"):
            self._last_telemetry = now
        if self._lost is not None:
            self._check_regained(now)

    def _is_vehicle_heartbeat(self, msg: Any, src: tuple[int, int]) -> bool:
        if self._vehicle is None:
            if msg.autopilot != mavlink2.MAV_AUTOPILOT_PX4:
                return False
            if self.vehicle_system_id not in (None, src[0]):
                return False
            self._vehicle = VehicleId(*src)
            self._fanout.publish(VehicleDetected, VehicleDetected(self._vehicle))
            assert self._vehicle_found is not None
            self._vehicle_found.set()
        return src == (self._vehicle.system_id, self._vehicle.component_id)

    def _deadlines(self) -> list[tuple[str, float]]:
        out = []
        if self._last_heartbeat is not None:
            out.append(("heartbeat", self._last_heartbeat + self.heartbeat_timeout_s))
        if self._last_telemetry is not None:
            out.append(("telemetry", self._last_telemetry + self.telemetry_timeout_s))
        return out

    def _heartbeat_silent_in_vehicle_time(self) -> bool:
        """The vehicle's own clock (its telemetry's time) has also moved on by the heartbeat
        timeout since the last heartbeat (True when it has sent no timed telemetry)."""
        latest, at_heartbeat = self._decoder.time_boot_ms, self._heartbeat_vehicle_ms
        if latest is None or at_heartbeat is None:
            return True
        return latest - at_heartbeat >= self.heartbeat_timeout_s * 1e3

    def _check_regained(self, now: float) -> None:
        if all(deadline > now for _, deadline in self._deadlines()):
            assert self._lost is not None
            regained = LinkRegained(self._lost.reason, now - self._lost_at + self._lost.silent_s)
            self._lost = None
            self._fanout.publish(LinkRegained, regained)

    async def _watchdog_loop(self) -> None:
        loop = asyncio.get_running_loop()
        idle = min(self.heartbeat_timeout_s, self.telemetry_timeout_s)
        while True:
            now = loop.time()
            deadlines = self._deadlines()
            expired = [
                (reason, d)
                for reason, d in deadlines
                if d <= now and (reason != "heartbeat" or self._heartbeat_silent_in_vehicle_time())
            ]
            if self._lost is None and expired:
                reason, deadline = expired[0]
                timeout = (
                    self.heartbeat_timeout_s
                    if reason == "heartbeat"
                    else (self.telemetry_timeout_s)
                )
                self._lost = LinkLost(reason, now - deadline + timeout)
                self._lost_at = now
                self._fanout.publish(LinkLost, self._lost)
            pending = [d - now for _, d in deadlines if d > now]
            await asyncio.sleep(min(pending) if pending else idle)

    async def _heartbeat_loop(self) -> None:
        while True:
            self.send_message(
                self.mav.heartbeat_encode(
                    mavlink2.MAV_TYPE_ONBOARD_CONTROLLER,
                    mavlink2.MAV_AUTOPILOT_INVALID,
                    0,
                    0,
                    mavlink2.MAV_STATE_ACTIVE,
                )
            )
            await asyncio.sleep(self.heartbeat_period_s)
