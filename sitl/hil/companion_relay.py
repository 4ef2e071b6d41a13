"""The companion in PX4's lockstep: PX4's onboard link relayed through the simulator.

PX4 and the simulator step together (HIL_SENSOR / HIL_ACTUATOR_CONTROLS), but the
companion talks to PX4 over UDP on its own schedule: when the machine is busy it computes
a setpoint late in vehicle time while PX4 flies on. :class:`CompanionRelay` closes that
gap. PX4's onboard MAVLink link is moved onto an internal pair of loopback ports, and the
relay, in the simulator's process, takes its place on the ports the companion was given:
every datagram passes through unchanged, both ways, unless a link fault drops it (a cut
or a lossy stretch, asked per datagram) or holds it back (a latency spike: the datagram
goes on once the simulation has run that long, in order). The relay reads as it passes:

- PX4's ODOMETRY ``time_usec`` (the pose the companion's control cycle runs on),
- the companion's SET_ATTITUDE_TARGET or SET_POSITION_TARGET_LOCAL_NED ``time_boot_ms``,
  which ``companion`` stamps with the pose it answers
  (:meth:`companion.link.mavlink.MavlinkLink.send_setpoint`, ``send_position_target``),
- the text of the companion's STATUSTEXT (its mission phases, which place faults).

Once a setpoint has answered a pose (the client is such a companion, streaming), the
simulator holds PX4's clock after every frame until the companion has answered the last
pose forwarded and has read the joints since (a Sync Read on the servo bus: the joint
state of its next cycle), as ``sitl run --lockstep`` holds the imitation
(:meth:`CompanionRelay.hold`): the companion's computing takes no vehicle time, however
busy the machine. A client that does not echo pose times (MAVSDK's offboard plugin, a
ground station) never engages the hold; a companion that stops streaming (landing, a link
cut) releases it after ``answer_timeout_s`` of wall time, until it answers again.

What remains untimed: PX4's MAVLink receiver thread takes the forwarded setpoint on its
own schedule, so a setpoint may reach PX4's attitude loop one frame (4 ms) late; the
servo bus answers from its own thread. Loopback only.
"""

from __future__ import annotations

import select
import socket
import struct
import threading
import time
from collections.abc import Callable, Iterator

from pymavlink.dialects.v20 import common as mavlink

from sitl.vehicle.link_faults import DelayLine

__all__ = ["CompanionRelay", "mavlink_frames"]

_HOST = "127.0.0.1"
_ODOMETRY = mavlink.MAVLINK_MSG_ID_ODOMETRY
_STATUSTEXT = mavlink.MAVLINK_MSG_ID_STATUSTEXT
_TEXT = slice(1, 51)
"""STATUSTEXT's ``text`` (char[50], after ``severity``) in its payload."""
_SETPOINTS = (
    mavlink.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET,
    mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED,
)
"""The setpoints that answer a pose: both start with ``time_boot_ms`` (uint32)."""
_MAX_DATAGRAM = 65536
_READ_POLL_S = 5e-5
"""How often a hold looks whether the companion's Sync Read was answered [s]."""
_V2_STX, _V1_STX = 0xFD, 0xFE
_V2_HEADER, _V1_HEADER, _CRC, _SIGNATURE = 10, 6, 2, 13


def mavlink_frames(data: bytes) -> Iterator[tuple[int, bytes]]:
    """``(message id, payload)`` of each MAVLink 1 or 2 frame in a datagram, in order
    (bytes between frames skipped; a truncated last frame ignored; CRC not checked: the
    relay forwards the bytes as they came and PX4 or the companion judge them)."""
    i, n = 0, len(data)
    while i < n:
        stx = data[i]
        if stx == _V2_STX and i + _V2_HEADER <= n:
            length = data[i + 1]
            msgid = data[i + 7] | data[i + 8] << 8 | data[i + 9] << 16
            start = i + _V2_HEADER
            end = start + length + _CRC + (_SIGNATURE if data[i + 2] & 0x01 else 0)
            if end > n:
                return
            yield msgid, data[start : start + length]
            i = end
        elif stx == _V1_STX and i + _V1_HEADER <= n:
            length = data[i + 1]
            start = i + _V1_HEADER
            end = start + length + _CRC
            if end > n:
                return
            yield data[i + 5], data[start : start + length]
            i = end
        else:
            i += 1


def _leading_uint(payload: bytes, fmt: str) -> int:
    """The payload's first field (MAVLink 2 drops trailing zero bytes: padded back)."""
    size = struct.calcsize(fmt)
    return int(struct.unpack_from(fmt, payload.ljust(size, b"\0"))[0])


class CompanionRelay:
    """PX4's onboard link relayed between PX4 and the companion (module docstring).

    ``companion_side`` = (local port, companion's port): the relay binds 127.0.0.1:local
    and sends to 127.0.0.1:companion's port (then to wherever the companion last sent
    from), as PX4's onboard link did. ``joint_reads`` counts the servo bus's Sync Reads.
    :meth:`open` binds, and :attr:`px4_ports` gives the (local, remote) pair to start
    PX4's onboard link on. ``answer_timeout_s``: wall time to wait for each of the
    setpoint and the joint read [s]. ``on_text`` is given the text of each STATUSTEXT the
    companion sends (its mission phases); ``drops`` is asked before each datagram, either
    way, whether the link loses it (a link fault: the datagram is read and not forwarded);
    ``delay`` gives each datagram's extra latency [s of simulated time, ``clock``'s], a
    held datagram going on at the first :meth:`pump` after it is due, in order.
    """

    def __init__(
        self,
        companion_side: tuple[int, int],
        joint_reads: Callable[[], int],
        answer_timeout_s: float,
        on_text: Callable[[str], None] | None = None,
        drops: Callable[[], bool] | None = None,
        delay: Callable[[], float] | None = None,
        clock: Callable[[], float] | None = None,
    ) -> None:
        if (delay is None) != (clock is None):
            raise ValueError("a delay needs the clock it is counted on")
        if answer_timeout_s <= 0.0:
            raise ValueError(f"answer_timeout_s must be positive, got {answer_timeout_s!r}")
        self._joint_reads = joint_reads
        self._on_text = on_text
        self._drops = drops
        self._delay = delay
        self._clock = clock
        self._late: DelayLine[tuple[bool, bytes]] = DelayLine()
        """Held datagrams: (towards the companion, bytes), in order."""
        self._reads_at_pose = 0
        self._reads_stopped_at = -1
        self._local_port, companion_port = companion_side
        self._companion_addr: tuple[str, int] = (_HOST, companion_port)
        self._px4_addr: tuple[str, int] | None = None
        self._companion: socket.socket | None = None
        self._px4: socket.socket | None = None
        self.answer_timeout_s = answer_timeout_s
        self.engaged = False
        """True while the companion answers poses (the hold is on)."""
        self.last_pose_ms = -1
        """Vehicle time of the last ODOMETRY forwarded to the companion [ms]."""
        self.answered_ms = -1
        """Latest pose time a setpoint of the companion answered [ms]."""
        self.holds = 0
        """Frames the simulator waited for the companion."""
        self.held_s = 0.0
        """Wall time waited for the companion [s]."""
        self.releases = 0
        """Times the companion did not answer within ``answer_timeout_s`` (hold released)."""
        self.dropped = 0
        """Datagrams the link lost (``drops``), both ways."""
        self.delayed = 0
        """Datagrams held back (``delay``), both ways."""

    @property
    def px4_ports(self) -> tuple[int, int]:
        """(PX4's onboard local port, the relay's port PX4 sends to)."""
        if self._px4 is None or self._px4_addr is None:
            raise RuntimeError("open the relay first")
        return self._px4_addr[1], self._px4.getsockname()[1]

    def open(self) -> None:
        """Bind the companion's side and the PX4 side (OSError when a port is taken)."""
        companion = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        px4 = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            companion.bind((_HOST, self._local_port))
            px4.bind((_HOST, 0))
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
                probe.bind((_HOST, 0))
                px4_local = probe.getsockname()[1]
        except OSError:
            companion.close()
            px4.close()
            raise
        companion.setblocking(False)
        px4.setblocking(False)
        self._companion, self._px4 = companion, px4
        self._px4_addr = (_HOST, px4_local)

    def close(self) -> None:
        """Close both sockets (safe twice)."""
        for sock in (self._companion, self._px4):
            if sock is not None:
                sock.close()
        self._companion = self._px4 = None

    def pump(self) -> None:
        """Forward every datagram waiting on either side, without blocking."""
        assert self._companion is not None and self._px4 is not None
        if self._late:
            assert self._clock is not None
            for to_companion, data in self._late.due(self._clock()):
                if to_companion:
                    self._to_companion(data)
                else:
                    self._to_px4(data)
        while self._from_px4():
            pass
        while self._from_companion():
            pass

    def hold(self, stop: threading.Event | None = None) -> None:
        """While engaged, wait until the companion has answered the last pose forwarded
        (forwarding all the while), then until it has read the joints since; release the
        hold when either takes longer than ``answer_timeout_s`` [s]."""
        self.pump()
        if not self.engaged or self.answered_ms >= self.last_pose_ms:
            return
        assert self._companion is not None and self._px4 is not None
        start = time.perf_counter()
        self.holds += 1
        if self._await(start, stop) and self._joint_reads() != self._reads_stopped_at:
            deadline = time.perf_counter() + self.answer_timeout_s
            while self._joint_reads() <= self._reads_at_pose:
                if time.perf_counter() > deadline:
                    self._reads_stopped_at = self._joint_reads()  # e.g. landed: no more reads
                    break
                time.sleep(_READ_POLL_S)  # the servo bus's thread answers meanwhile
        self.held_s += time.perf_counter() - start

    def _await(self, start: float, stop: threading.Event | None) -> bool:
        """Forward until the last pose is answered (True) or the hold is released."""
        assert self._companion is not None and self._px4 is not None
        deadline = start + self.answer_timeout_s
        while self.answered_ms < self.last_pose_ms:
            left = deadline - time.perf_counter()
            if left <= 0.0 or (stop is not None and stop.is_set()):
                self.engaged = False
                self.releases += 1
                return False
            select.select([self._companion, self._px4], [], [], min(left, 0.05))
            self.pump()
        return True

    def _from_px4(self) -> bool:
        assert self._px4 is not None and self._companion is not None
        try:
            data, _ = self._px4.recvfrom(_MAX_DATAGRAM)
        except (BlockingIOError, ConnectionRefusedError):
            return False
        if not self._lost() and not self._held(data, to_companion=True):
            self._to_companion(data)
        return True

    def _to_companion(self, data: bytes) -> None:
        """Forward PX4's datagram, reading its pose time."""
        assert self._companion is not None
        for msgid, payload in mavlink_frames(data):
            if msgid == _ODOMETRY:
                self.last_pose_ms = _leading_uint(payload, "<Q") // 1000
                self._reads_at_pose = self._joint_reads()
        try:
            self._companion.sendto(data, self._companion_addr)
        except OSError:
            pass  # nobody on the companion's port yet: PX4's link would drop it too

    def _from_companion(self) -> bool:
        assert self._px4 is not None and self._companion is not None and self._px4_addr
        try:
            data, sender = self._companion.recvfrom(_MAX_DATAGRAM)
        except (BlockingIOError, ConnectionRefusedError):
            return False
        self._companion_addr = sender
        if not self._lost() and not self._held(data, to_companion=False):
            self._to_px4(data)
        return True

    def _to_px4(self, data: bytes) -> None:
        """Forward the companion's datagram, reading its setpoint's pose time and its
        STATUSTEXT."""
        assert self._px4 is not None and self._px4_addr is not None
        for msgid, payload in mavlink_frames(data):
            if msgid in _SETPOINTS:
                answered = _leading_uint(payload, "<I")
                if answered == self.last_pose_ms:
                    self.engaged = True
                self.answered_ms = max(self.answered_ms, answered)
            elif msgid == _STATUSTEXT and self._on_text is not None:
                text = payload[_TEXT].split(b"\0", 1)[0]
                self._on_text(text.decode("utf-8", errors="replace"))
        try:
            self._px4.sendto(data, self._px4_addr)
        except OSError:
            pass  # PX4's onboard link not started yet

    def _held(self, data: bytes, to_companion: bool) -> bool:
        """Hold the datagram just read back for its delay (counted), behind any held
        before it: the link keeps its order."""
        if self._delay is None or self._clock is None:
            return False
        if not self._late.hold((to_companion, data), self._clock(), self._delay()):
            return False
        self.delayed += 1
        return True

    def _lost(self) -> bool:
        """The link loses the datagram just read (counted)."""
        if self._drops is None or not self._drops():
            return False
        self.dropped += 1
        return True
