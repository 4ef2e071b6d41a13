"""MAVLink 2 message signing: the key file and the signing state of a link.

Key file format
---------------
The 32-byte secret key, either as exactly 32 raw bytes (``head -c 32 /dev/urandom > key``)
or as text: 64 hexadecimal digits, surrounding whitespace ignored
(``python -c "import secrets; print(secrets.token_hex(32))" > key``). Keep it readable by
the flight user only (``chmod 600``); the same key must be set on the autopilot.

Signing follows the MAVLink 2 specification: every outgoing frame carries a link id, a
48-bit timestamp in 10 us units since 2015-01-01 00:00:00 UTC, and the first 6 bytes of
SHA-256(key + frame). Incoming frames are checked by pymavlink (signature, and a
timestamp that must grow per stream). With ``require_signed`` unsigned frames are
rejected, except RADIO_STATUS, which radios inject unsigned (as the specification allows).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink2

from companion.link.errors import SigningKeyError
from companion.user_files import UserFileError, read_small_file

__all__ = [
    "SIGNING_KEY_BYTES",
    "SigningConfig",
    "advance_timestamp",
    "load_signing_key",
    "signing_timestamp",
]

SIGNING_KEY_BYTES = 32
SIGNING_KEY_FILE_LIMIT_BYTES = 1024
"""The largest key file read [bytes]: a key is 32 raw bytes or 64 hex digits."""
_KEY_KIND = "a signing key file (32 raw bytes or 64 hex digits)"
_EPOCH_2015_UNIX_S = 1_420_070_400
_UNSIGNED_ALLOWED = frozenset({mavlink2.MAVLINK_MSG_ID_RADIO_STATUS})


def load_signing_key(path: str | Path) -> bytes:
    """Read a key file (32 raw bytes, or 64 hex digits); raises ``SigningKeyError``."""
    path = Path(path)
    try:
        data = read_small_file(path, SIGNING_KEY_FILE_LIMIT_BYTES, _KEY_KIND)
    except UserFileError as exc:
        raise SigningKeyError(f"signing key {path}: {exc.reason}") from None
    if len(data) == SIGNING_KEY_BYTES:
        return data
    try:
        text = data.decode("ascii").strip()
        key = bytes.fromhex(text) if len(text) == 2 * SIGNING_KEY_BYTES else b""
    except (UnicodeDecodeError, ValueError):
        key = b""
    if len(key) != SIGNING_KEY_BYTES:
        raise SigningKeyError(
            f"signing key {path}: expected {SIGNING_KEY_BYTES} raw bytes or "
            f"{2 * SIGNING_KEY_BYTES} hex digits, got {len(data)} bytes"
        )
    return key


def signing_timestamp(unix_time_s: float) -> int:
    """MAVLink signing timestamp of a Unix time: 10 us units since 2015-01-01 UTC."""
    return max(0, int((unix_time_s - _EPOCH_2015_UNIX_S) * 100_000))


@dataclass(frozen=True)
class SigningConfig:
    """How a link signs and checks frames.

    Parameters
    ----------
    key : bytes
        The 32-byte secret key.
    link_id : int
        This link's id in the signature (0..255), to tell our streams apart.
    require_signed : bool
        Reject unsigned incoming frames (except RADIO_STATUS). If False, unsigned frames
        are accepted and counted, and outgoing frames are still signed.
    """

    key: bytes
    link_id: int = 0
    require_signed: bool = True

    def __post_init__(self) -> None:
        if len(self.key) != SIGNING_KEY_BYTES:
            raise SigningKeyError(f"signing key must be {SIGNING_KEY_BYTES} bytes")
        if not 0 <= self.link_id <= 255:
            raise SigningKeyError(f"signing link_id {self.link_id} is outside 0..255")

    @classmethod
    def from_file(
        cls, path: str | Path, link_id: int = 0, require_signed: bool = True
    ) -> SigningConfig:
        """Load the key with :func:`load_signing_key`."""
        return cls(load_signing_key(path), link_id, require_signed)

    def apply(self, mav: mavlink2.MAVLink) -> None:
        """Switch signing on for a pymavlink ``MAVLink`` codec object."""
        mav.signing.secret_key = self.key
        mav.signing.link_id = self.link_id
        mav.signing.sign_outgoing = True
        mav.signing.timestamp = signing_timestamp(time.time())
        require = self.require_signed
        mav.signing.allow_unsigned_callback = lambda _mav, msg_id: (
            not require or msg_id in _UNSIGNED_ALLOWED
        )


def advance_timestamp(mav: mavlink2.MAVLink) -> None:
    """Keep the outgoing timestamp at least at the wall clock (the specification asks for
    a timestamp that follows real time, so that a receiver's new-stream check, which
    refuses timestamps more than a minute old, keeps accepting us)."""
    mav.signing.timestamp = max(mav.signing.timestamp, signing_timestamp(time.time()))
