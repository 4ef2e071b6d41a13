"""PX4 mode encoding, cross-checked with pymavlink's independent table."""

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from companion.link import PX4_MODES, Px4Mode, UnknownModeError, decode_custom_mode, px4_mode

# pymavlink's PX4 table (mavutil.px4_map, what mavfile.mode_mapping() returns for PX4);
# its RTGS is sub mode 7, which PX4 removed in 2020 (RESERVED_DO_NOT_USE).
PYMAVLINK_MODES = {k: v for k, v in mavutil.px4_map.items() if k != "RTGS"}


@pytest.mark.parametrize("name", sorted(PYMAVLINK_MODES))
def test_table_matches_pymavlink(name):
    base, main, sub = PYMAVLINK_MODES[name]
    assert base & mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert PX4_MODES[name] == (main, sub)


@pytest.mark.parametrize("name", sorted(PYMAVLINK_MODES))
def test_heartbeat_custom_mode_round_trip(name):
    mode = PX4_MODES[name]
    custom = mode.custom_mode
    assert custom == (mode.main << 16) | (mode.sub << 24)
    assert decode_custom_mode(custom) == mode
    assert decode_custom_mode(custom).name == name
    assert mavutil.interpret_px4_mode(0, custom) == name


def test_every_name_decodes_to_itself_and_low_bits_are_ignored():
    for name, mode in PX4_MODES.items():
        assert decode_custom_mode(mode.custom_mode | 0xFFFF).name == name
    assert len(set(PX4_MODES.values())) == len(PX4_MODES)


def test_lookup_by_name_and_unknown_modes():
    assert px4_mode("offboard") == Px4Mode(6, 0)
    assert px4_mode("LAND") == Px4Mode(4, 6)
    assert decode_custom_mode(Px4Mode(4, 7).custom_mode).name == "UNKNOWN(4.7)"
    with pytest.raises(UnknownModeError, match="unknown PX4 mode 'HOVER'"):
        px4_mode("HOVER")
