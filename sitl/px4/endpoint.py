"""The vehicle's only I/O: one non-blocking UDP MAVLink 2 endpoint per link (or, for a
flight on simulated time, one in-memory channel end: :mod:`bytelink.memory`).

PX4 SITL opens its onboard/API link on local UDP 14580 sending to 127.0.0.1:14540 and its
GCS link on local 18570 sending to 127.0.0.1:14550; :data:`ONBOARD_PORTS` and
:data:`GCS_PORTS` are those defaults. Like PX4's UDP transport, the endpoint sends to the
configured remote until it hears from a client and then answers the address the last
valid message came from (a client on another port, e.g. ``mavutil`` with ``udpout``).
Only correctly decoded (and, with signing, correctly signed) datagrams move the remote,
so garbage from a stray port cannot hijack the link.

Robust input: each datagram is parsed on its own (a frame cut off at the end of a
datagram is not glued to the next one). Random bytes, truncated frames, bad CRCs,
unknown message ids, bad lengths and flags, unsigned or wrongly signed frames (when a
signing key is set) are dropped and counted per reason in :attr:`MavlinkEndpoint.counters`;
nothing raises out of :meth:`MavlinkEndpoint.receive`. MAVLink 1 frames are accepted
without signing, as PX4 does.

Signing (MAVLink 2, pymavlink's implementation): with a 32-byte secret key every outgoing
frame is signed (link id configurable, timestamps in 10 us units since 2015-01-01 from
the wall clock at :meth:`~MavlinkEndpoint.open`), and incoming frames must carry a valid
signature with a timestamp newer than the last one of their stream; others are counted
(``unsigned`` / ``bad_signature``) and dropped. Key files hold the 32 raw bytes or 64 hex
characters (:func:`load_signing_key`).
"""

from __future__ import annotations

import errno
import select
import socket
import struct
import time
from collections import Counter
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink
from pymavlink.generator.mavcrc import x25crc

from bytelink.memory import MemoryEnd
from companion.link.signing import SIGNING_KEY_FILE_LIMIT_BYTES
from companion.user_files import UserFileError, read_small_file

__all__ = [
    "GCS_PORTS",
    "ONBOARD_PORTS",
    "MavlinkEndpoint",
    "SigningKeyError",
    "load_signing_key",
]

ONBOARD_PORTS = (14580, 14540)
"""PX4 SITL onboard/API link: (local port, remote port)."""
GCS_PORTS = (18570, 14550)
"""PX4 SITL GCS link: (local port, remote port)."""

_SIGNING_EPOCH_S = 1_420_070_400
"""2015-01-01 00:00:00 UTC, the MAVLink signing timestamp epoch [s since 1970]."""
_MAX_DATAGRAM = 65_535
_ODOMETRY = mavlink.MAVLink_odometry_message
_ODOMETRY_PAYLOAD = struct.Struct(_ODOMETRY.unpacker.format)
"""ODOMETRY's payload layout (pymavlink's: fields sorted by size, extensions last)."""
_ODOMETRY_ID_LOW, _ODOMETRY_ID_HIGH = _ODOMETRY.id & 0xFFFF, _ODOMETRY.id >> 16
_ODOMETRY_CRC_EXTRA = bytes((_ODOMETRY.crc_extra,))
_HEADER_V2 = struct.Struct("<BBBBBBBHB")
_CRC = struct.Struct("<H")
_REASONS = (
    ("Bad prefix", "garbage"),
    ("invalid MAVLink CRC", "bad_crc"),
    ("Invalid signature", "bad_signature"),
    ("invalid MAVLink message length", "bad_length"),
    ("invalid incompat_flags", "bad_flags"),
)


def odometry_frame(msg: mavlink.MAVLink_odometry_message, mav: mavlink.MAVLink) -> bytes:
    """``msg`` as the unsigned MAVLink 2 frame ``msg.pack(mav)`` makes (``mav``'s sequence
    number and source ids, payload trailing zeros trimmed, the CRC with ODOMETRY's
    ``CRC_EXTRA``), byte for byte, packed with one struct layout and without pymavlink's
    header and CRC objects; the message is left as it was. Only for a ``mav`` that does
    not sign."""
    q, pose, velocity = msg.q, msg.pose_covariance, msg.velocity_covariance
    payload = _ODOMETRY_PAYLOAD.pack(
        msg.time_usec, msg.x, msg.y, msg.z, q[0], q[1], q[2], q[3], msg.vx, msg.vy, msg.vz,
        msg.rollspeed, msg.pitchspeed, msg.yawspeed, *pose[:21], *velocity[:21], msg.frame_id,
        msg.child_frame_id, msg.reset_counter, msg.estimator_type, msg.quality,
    )  # fmt: skip
    payload = payload.rstrip(b"\0") or payload[:1]
    frame = _HEADER_V2.pack(
        mavlink.PROTOCOL_MARKER_V2, len(payload), 0, 0, mav.seq, mav.srcSystem,
        mav.srcComponent, _ODOMETRY_ID_LOW, _ODOMETRY_ID_HIGH,
    ) + payload  # fmt: skip
    return frame + _CRC.pack(x25crc(frame[1:] + _ODOMETRY_CRC_EXTRA).crc)


class SigningKeyError(ValueError):
    """A signing key file that is neither 32 raw bytes nor 64 hex characters."""


def load_signing_key(path: str | Path) -> bytes:
    """Read a MAVLink 2 signing key: 32 raw bytes, or 64 hex characters (whitespace ok)."""
    try:
        data = read_small_file(path, SIGNING_KEY_FILE_LIMIT_BYTES, "a signing key file")
    except UserFileError as exc:
        raise SigningKeyError(str(exc)) from None
    if len(data) == 32:
        return data
    try:
        key = bytes.fromhex(data.decode("ascii").strip())
    except (UnicodeDecodeError, ValueError):
        key = b""
    if len(key) != 32:
        raise SigningKeyError(f"{path}: expected 32 raw bytes or 64 hex characters")
    return key


class MavlinkEndpoint:
    """A UDP MAVLink 2 endpoint; see the module docstring.

    Parameters
    ----------
    local_port : int
        UDP port to bind (0: any free port; see :attr:`local_address`).
    remote_port : int
        Port to send to until a client is heard from.
    host : str
        Address to bind and default remote host (loopback).
    system_id, component_id : int
        Source ids of outgoing frames (PX4 autopilot: 1, 1).
    signing_key : bytes, optional
        32-byte secret: sign outgoing frames and require signed incoming ones.
    link_id : int
        Signing link id of outgoing frames (0..255).
    port : MemoryEnd, optional
        Send and receive datagrams on this in-memory channel end instead of UDP (the
        ports are then unused).

    Nothing is opened in the constructor; :meth:`open` binds, :meth:`close` (idempotent)
    releases. Also a context manager.
    """

    def __init__(
        self,
        local_port: int,
        remote_port: int,
        *,
        host: str = "127.0.0.1",
        system_id: int = 1,
        component_id: int = 1,
        signing_key: bytes | None = None,
        link_id: int = 0,
        port: MemoryEnd | None = None,
    ) -> None:
        if signing_key is not None and len(signing_key) != 32:
            raise SigningKeyError("signing_key must be 32 bytes")
        self._local = (host, int(local_port))
        self.remote_address: tuple[str, int] = (host, int(remote_port))
        """Where frames go: the configured remote, then the last valid sender."""
        self._system_id = int(system_id)
        self._component_id = int(component_id)
        self._key = signing_key
        self._link_id = int(link_id)
        self._sock: socket.socket | None = None
        self._mav: mavlink.MAVLink | None = None
        self._poller: select.poll | None = None
        self._port = port
        self.counters: Counter[str] = Counter()
        """Datagrams / frames by outcome: ``received``, ``sent`` and the drop reasons."""

    # ------------------------------------------------------------ lifecycle

    def open(self) -> None:
        """Bind the socket (non-blocking) and set up the codec; no-op when open."""
        if self._mav is not None:
            return
        sock = None
        if self._port is None:
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            try:
                sock.setblocking(False)
                sock.bind(self._local)
            except OSError:
                sock.close()
                raise
        mav = mavlink.MAVLink(None, self._system_id, self._component_id)
        mav.robust_parsing = True
        if self._key is not None:
            mav.signing.secret_key = self._key
            mav.signing.sign_outgoing = True
            mav.signing.link_id = self._link_id
            mav.signing.timestamp = int((time.time() - _SIGNING_EPOCH_S) * 1e5)
        self._sock, self._mav = sock, mav
        if sock is not None:
            self._poller = select.poll()
            self._poller.register(sock, select.POLLIN | select.POLLERR)

    def close(self) -> None:
        """Release the socket; safe to call more than once."""
        if self._sock is not None:
            self._sock.close()
        if self._port is not None:
            self._port.close()
        self._sock = None
        self._mav = None
        self._poller = None

    def __enter__(self) -> MavlinkEndpoint:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def is_open(self) -> bool:
        """Whether :meth:`open` has bound the socket (or set up the in-memory end)."""
        return self._mav is not None

    @property
    def local_address(self) -> tuple[str, int]:
        """The bound (host, port) (the free port chosen when ``local_port`` was 0)."""
        if self._mav is None:
            raise RuntimeError("endpoint is not open")
        if self._sock is None:
            return self._local
        return self._sock.getsockname()

    @property
    def heard(self) -> bool:
        """Someone may read what this endpoint sends: always on UDP (a datagram cannot
        tell), on an in-memory channel once a client has attached its other end."""
        port = self._port
        return port is None or (port.peer is not None and port.peer.attached)

    # ----------------------------------------------------------------- I/O

    def send(self, msg: mavlink.MAVLink_message) -> None:
        """Encode (MAVLink 2, signed when a key is set) and send one message.

        Send errors (e.g. ICMP port unreachable reported by the kernel while no client
        listens) are counted as ``send_error`` and dropped: the vehicle keeps flying. On an
        in-memory channel nobody reads (not :attr:`heard`), the message is counted
        ``unheard`` and not encoded.
        """
        mav = self._require_open()
        if not self.heard:
            self.counters["unheard"] += 1  # nobody reads the channel: not even packed
            return
        port = self._port
        if type(msg) is _ODOMETRY and not mav.signing.sign_outgoing:
            buf = odometry_frame(msg, mav)  # the control cycle's 125 Hz message, cheaper
        else:
            buf = msg.pack(mav)
        mav.seq = (mav.seq + 1) % 256
        try:
            if port is not None:
                port.send(buf)
            else:
                assert self._sock is not None
                self._sock.sendto(buf, self.remote_address)
        except OSError:
            self.counters["send_error"] += 1
            return
        self.counters["sent"] += 1

    @property
    def sent(self) -> int:
        """Messages sent so far."""
        return self.counters["sent"]

    @property
    def idle(self) -> bool:
        """Nothing waits to be received, as far as it can tell without a system call: an
        in-memory end with an empty inbox (on UDP: False, a datagram may wait)."""
        port = self._port
        return port is not None and not port.readable

    def wait_readable(self, timeout_s: float) -> None:
        """Block until a datagram waits or ``timeout_s`` [s] has passed (UDP only; an
        in-memory end returns at once)."""
        self._require_open()
        if self._poller is not None:
            self._poller.poll(max(0, round(timeout_s * 1e3)))

    def receive(self, max_datagrams: int = 256) -> list[mavlink.MAVLink_message]:
        """Every valid message of the datagrams waiting (at most ``max_datagrams``)."""
        mav = self._require_open()
        out: list[mavlink.MAVLink_message] = []
        if self._port is not None:
            if not self._port.readable:  # nothing waiting: the usual step
                return out
            for _ in range(max_datagrams):
                data = self._port.receive()
                if not data:
                    break
                self.counters["datagrams"] += 1
                out.extend(self._parse(mav, data))
            return out
        sock = self._sock
        assert sock is not None and self._poller is not None  # made in open()
        if not self._poller.poll(0):  # nothing waiting, no error pending: the usual step
            return out
        for _ in range(max_datagrams):
            try:
                data, sender = sock.recvfrom(_MAX_DATAGRAM)
            except BlockingIOError:
                break
            except OSError as exc:  # ECONNREFUSED from an earlier send, and the like
                self.counters[
                    "receive_error" if exc.errno != errno.ECONNREFUSED else "refused"
                ] += 1
                continue
            self.counters["datagrams"] += 1
            valid = self._parse(mav, data)
            if valid:
                self.remote_address = (sender[0], sender[1])
                out.extend(valid)
        return out

    def _parse(self, mav: mavlink.MAVLink, data: bytes) -> list[mavlink.MAVLink_message]:
        """Decode one datagram; count and drop everything that is not a valid message."""
        valid: list[mavlink.MAVLink_message] = []
        try:
            messages = mav.parse_buffer(data) or []
        except Exception:  # pymavlink must never take the vehicle down
            self.counters["parser_error"] += 1
            messages = []
        for msg in messages:
            kind = msg.get_type()
            if kind == "BAD_DATA":
                self.counters[self._reason(msg)] += 1
            elif kind.startswith("UNKNOWN_"):
                self.counters["unknown_id"] += 1
            else:
                self.counters["received"] += 1
                valid.append(msg)
        if mav.buf_len() > 0:
            self.counters["truncated"] += 1
        mav.buf = bytearray()
        mav.buf_index = 0
        mav.expected_length = mavlink.HEADER_LEN_V1 + 2
        return valid

    @staticmethod
    def _reason(bad: mavlink.MAVLink_bad_data) -> str:
        reason = str(bad.reason)
        for prefix, name in _REASONS:
            if reason.startswith(prefix):
                if name == "bad_signature" and not _is_signed(bytes(bad.data)):
                    return "unsigned"
                return name
        return "malformed"

    def _require_open(self) -> mavlink.MAVLink:
        if self._mav is None:
            raise RuntimeError("endpoint is not open; call open() first")
        return self._mav


def _is_signed(frame: bytes) -> bool:
    """A MAVLink 2 frame with the signed incompat flag."""
    return len(frame) > 2 and frame[0] == mavlink.PROTOCOL_MARKER_V2 and bool(frame[2] & 1)
