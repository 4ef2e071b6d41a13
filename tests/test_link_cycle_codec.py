"""The control cycle's frames without pymavlink's objects: ODOMETRY read with the same
fields and samples as through pymavlink (any other frame left to pymavlink), and
SET_ATTITUDE_TARGET framed byte for byte as pymavlink frames it."""

import struct

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as m

from companion.link import TelemetryDecoder
from companion.link.cycle_codec import OdometryFields, attitude_target_frame, odometry_frame

NAN = float("nan")


class _Discard:
    def write(self, data: bytes) -> int:
        return len(data)


def _frame(mav: m.MAVLink, quality: int = 0, child: int = m.MAV_FRAME_LOCAL_NED) -> bytes:
    cov = [float(i) for i in range(21)]
    message = m.MAVLink_odometry_message(
        123_456_789, m.MAV_FRAME_LOCAL_NED, child, 1.5, -2.25, 3.0, [0.5, 0.5, -0.5, 0.5],
        0.1, NAN if child == m.MAV_FRAME_BODY_FRD else 0.2, 0.3, 0.4, 0.5, 0.6, cov,
        [NAN] * 21, 7, m.MAV_ESTIMATOR_TYPE_AUTOPILOT, quality,
    )  # fmt: skip
    return bytes(message.pack(mav))


def _bits(value: object) -> object:
    """Floats compared by their bits (NaN equal to NaN), sequences entry by entry."""
    if isinstance(value, (list, tuple)):
        return tuple(_bits(v) for v in value)
    return struct.pack("<d", value) if isinstance(value, float) else value


@pytest.mark.parametrize("quality", [0, 90])  # 0: MAVLink 2 trims the last byte
@pytest.mark.parametrize("child", [m.MAV_FRAME_LOCAL_NED, m.MAV_FRAME_BODY_FRD])
def test_fields_and_samples_are_pymavlinks(quality, child):
    mav = m.MAVLink(_Discard(), 1, 1)
    mav.seq = 41
    frame = _frame(mav, quality, child)
    msg = m.MAVLink(_Discard(), 255, 0).parse_buffer(frame)[0]
    fields = odometry_frame(frame)
    assert isinstance(fields, OdometryFields)
    assert (fields.seq, fields.src_system, fields.src_component) == (41, 1, 1)
    for name in OdometryFields._fields[3:]:
        assert _bits(getattr(fields, name)) == _bits(getattr(msg, name)), name
    ours, theirs = TelemetryDecoder().odometry(fields), TelemetryDecoder().decode(msg)
    assert _bits([vars(s) for s in ours]) == _bits([vars(s) for s in theirs])


def test_any_other_frame_is_left_to_pymavlink():
    mav = m.MAVLink(_Discard(), 1, 1)
    frame = _frame(mav)
    corrupt = bytearray(frame)
    corrupt[20] ^= 1
    heartbeat = bytes(mav.heartbeat_encode(2, 12, 0, 0, 4).pack(mav))
    signed = _signed(mav)
    for data in (bytes(corrupt), frame + b"x", frame[:-1], b"", heartbeat, frame + frame, signed):
        assert odometry_frame(data) is None


def _signed(mav: m.MAVLink) -> bytes:
    signed = bytearray(_frame(mav))
    signed[2] = m.MAVLINK_IFLAG_SIGNED  # a signed frame's flag, no signature
    return bytes(signed)


def test_attitude_target_frames_are_pymavlinks():
    mav = m.MAVLink(_Discard(), 1, m.MAV_COMP_ID_ONBOARD_COMPUTER)
    rng = np.random.default_rng(3)
    cases = [((1.0, 0.0, 0.0, 0.0), 0.0, 0), ((0.0, 0.0, 0.0, 1.0), 1.0, 0xFFFFFFFF)]
    for _ in range(200):
        q = rng.normal(size=4)
        cases.append((tuple(q / np.linalg.norm(q)), float(rng.uniform()), int(rng.integers(2**32))))
    for q, thrust, t_ms in cases:
        mav.seq = int(rng.integers(256))
        ours = attitude_target_frame(
            mav.seq, 1, m.MAV_COMP_ID_ONBOARD_COMPUTER, t_ms, 7, 3, 7, q, thrust
        )
        msg = m.MAVLink_set_attitude_target_message(t_ms, 7, 3, 7, list(q), 0.0, 0.0, 0.0, thrust)
        assert ours == bytes(msg.pack(mav))
