"""The fault campaign's parts that need no flight: the safety judge (docs/faults.md's
numbers), the mission's phase announcements and the simulator's reading of them."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.mission.announce import STATUSTEXT_CHARS, announcement, phase_of
from sitl.campaign.safety import handover_s, judge
from sitl.campaign.spec import Fault
from sitl.servo import XM430Servo
from sitl.servo.memory_bus import MemoryServoBus
from sitl.vehicle.link_faults import (
    DelayLine,
    LinkFaults,
    LinkLatency,
    LinkLoss,
    LowBattery,
    PilotTakeover,
)
from sitl.vehicle.mission_phases import FAULT_PHASES, MissionPhases, PhaseStart
from sitl.vehicle.options import RunOptions, ServoError
from sitl.vehicle.servo_bus_faults import BusCorruption, ServoBusFaults, ServoReboot

PLACE_M = (-1.0, 0.5, 0.05)


def sample(t_s, z_m, *, vz=0.0, roll=0.0, armed=True, mode="OFFBOARD", ground=False,
           held=False, obj=None, joint_rate=0.0):  # fmt: skip
    return {
        "t_s": t_s,
        "q": [0.0, 0.0, z_m, roll, 0.0, 0.0, -1.5, 0.0],
        "q_dot": [0.0, 0.0, vz, 0.0, 0.0, 0.0, joint_rate, 0.0],
        "armed": armed,
        "mode": mode,
        "on_ground": ground,
        "payload_attached": held,
        "object_position_m": obj,
    }


def landing(touchdown_m_s=-0.5, **last):
    """Airborne, then down and disarmed."""
    end = {"armed": False, "mode": "AUTO_LAND", "ground": True, **last}
    return [
        sample(10.0, 1.0, vz=-0.5, mode="AUTO_LAND"),
        sample(10.02, 0.3, vz=touchdown_m_s, mode="AUTO_LAND"),
        sample(10.04, 0.25, **{**end, "armed": True}),
        sample(12.0, 0.25, **end),
    ]


SUMMARY = {"outcome": "aborted", "faults": [{"fault": "link_lost"}]}


def test_a_gentle_landing_is_safe():
    verdict = judge(landing(), SUMMARY, PLACE_M, 12.0)
    assert verdict.safe, verdict.broken
    assert verdict.end == "landed" and verdict.touchdown_m_s == pytest.approx(0.5)


@pytest.mark.parametrize(
    ("truth", "summary", "log_end_s", "words"),
    [
        (landing(-1.2), SUMMARY, 12.0, "touched down at 1.20 m/s"),
        ([sample(12.0, 0.25, ground=True)], SUMMARY, 12.0, "armed on the ground in OFFBOARD"),
        ([sample(1.0, 2.0, armed=False)], SUMMARY, 1.0, "disarmed in the air"),
        ([sample(1.0, 2.0, roll=math.radians(50), mode="AUTO_LOITER")], SUMMARY, 1.0,
         "tilted 50.0 deg"),
        (landing(joint_rate=2.0), SUMMARY, 12.0, "the arm still moves at 2.00 rad/s"),
        (landing(), {"outcome": "aborted", "faults": []}, 12.0, "names no fault"),
        (landing(), {"outcome": None}, 12.0, "names no outcome"),
        (landing(), SUMMARY, None, "does not read back"),
        (landing(), SUMMARY, 9.0, "ends 3.0 s before the flight"),
    ],
)  # fmt: skip
def test_each_broken_number_is_one_named_line(truth, summary, log_end_s, words):
    verdict = judge(truth, summary, PLACE_M, log_end_s)
    assert not verdict.safe
    assert any(words in line for line in verdict.broken), verdict.broken


def test_the_log_is_judged_against_the_disarm_not_the_clean_up_after_it():
    """A lossy link makes the companion's clean-up after the disarm (PX4's streams given
    back, each asked twice) last over a second of the run: the log ended at the disarm."""
    after = [sample(12.0 + 0.5 * i, 0.25, armed=False, mode="AUTO_LAND", ground=True)
             for i in range(1, 5)]  # fmt: skip
    assert judge(landing() + after, SUMMARY, PLACE_M, 12.0).safe
    assert not judge(landing() + after, SUMMARY, PLACE_M, 10.5).safe


def test_an_object_let_go_high_is_unsafe_and_one_let_go_low_or_placed_is_not():
    def flight(z_at_release: float, xy=(1.0, 1.0)):
        obj = [*xy, z_at_release]
        return [
            sample(1.0, 1.5, held=True, obj=obj, mode="AUTO_LOITER"),
            sample(1.02, 1.5, held=False, obj=obj, mode="AUTO_LOITER"),
        ]

    high = judge(flight(0.9), SUMMARY, PLACE_M, 1.02)
    assert not high.safe and high.payload == "let go at 0.90 m"
    assert judge(flight(0.2), SUMMARY, PLACE_M, 1.02).safe
    assert judge(flight(0.9, PLACE_M[:2]), SUMMARY, PLACE_M, 1.02).payload == "placed"


def test_an_object_slipping_out_of_closing_jaws_is_not_a_release():
    obj = [1.0, 1.0, 1.2]

    def flight(jaws_after_rad: float) -> list[dict]:
        return [
            {**sample(1.0, 1.5, obj=obj, mode="AUTO_LOITER"), "gripper_angle_rad": 0.7},
            {**sample(1.2, 1.5, held=True, obj=obj, mode="AUTO_LOITER"), "gripper_angle_rad": 0.0},
            {**sample(5.0, 1.5, held=True, obj=obj, mode="AUTO_LOITER"), "gripper_angle_rad": 0.0},
            {**sample(5.02, 1.5, obj=obj, mode="AUTO_LOITER"), "gripper_angle_rad": 0.0},
            {**sample(5.2, 1.5, obj=obj, mode="AUTO_LOITER"), "gripper_angle_rad": jaws_after_rad},
        ]

    slipped = judge(flight(-0.26), SUMMARY, PLACE_M, 5.2)  # closing on nothing
    assert slipped.safe and slipped.payload == "slipped at 1.20 m"
    released = judge(flight(0.4), SUMMARY, PLACE_M, 5.2)  # opened: let go from 1.2 m
    assert not released.safe and released.payload == "let go at 1.20 m"


def test_hovering_in_hold_is_safe_and_in_offboard_is_not():
    assert judge([sample(5.0, 1.5, mode="AUTO_LOITER")], SUMMARY, PLACE_M, 5.0).safe
    assert not judge([sample(5.0, 1.5)], SUMMARY, PLACE_M, 5.0).safe


def test_a_phase_is_announced_in_one_statustext_the_simulator_reads_back():
    severity, text = announcement("phase", "grasp")
    assert severity == mavlink2.MAV_SEVERITY_INFO
    message = mavlink2.MAVLink_statustext_message(severity, text)
    phases = MissionPhases()
    phases.observe_text(message.text, 28.5)
    phases.observe_text(message.text, 40.0)  # told again later: the first time counts
    assert phases.start_s(PhaseStart("grasp", 0.5)) == pytest.approx(29.0)
    assert phases.start_s(PhaseStart("lift")) is None
    assert phases.start_s(31.0) == 31.0
    assert phase_of("pickup: fault link_lost") is None
    assert announcement("mode", "OFFBOARD") is None
    long = announcement("fault", "servo_bus: " + "x" * 80)
    assert long is not None and len(long[1]) == STATUSTEXT_CHARS


def test_take_off_and_landing_are_the_autopilots_modes():
    phases = MissionPhases()
    phases.observe_mode("AUTO_TAKEOFF", 15.0)
    phases.observe_mode("OFFBOARD", 20.0)
    phases.observe_mode("AUTO_LAND", 60.0)
    assert phases.began_s == {"takeoff": 15.0, "landing": 60.0}
    assert FAULT_PHASES[0] == "takeoff" and FAULT_PHASES[-1] == "landing"
    with pytest.raises(ValueError, match="phase must be one of"):
        PhaseStart("hover")


def test_a_low_battery_is_two_parameters_set_once_from_the_ground_station():
    phases = MissionPhases()
    faults = LinkFaults(phases, 0, battery=LowBattery(PhaseStart("lift", 0.5), 6.0))
    assert faults.battery(40.0) == []
    phases.observe_text("pickup: phase lift", 41.0)
    assert faults.battery(41.2) == []
    sent = faults.battery(41.5)
    assert [(m.param_id, m.param_value) for m in sent] == [
        ("SIM_BAT_DRAIN", 1.0), ("SIM_BAT_MIN_PCT", 6.0),
    ]  # fmt: skip
    assert all(m.param_type == mavlink2.MAV_PARAM_TYPE_REAL32 for m in sent)
    assert faults.battery(42.0) == []
    with pytest.raises(ValueError, match="remaining_pct"):
        LowBattery(10.0, 100.0)


def test_the_servo_bus_faults_start_at_their_phase_and_the_corruption_ends():
    bus = MemoryServoBus({i: XM430Servo(i) for i in (1, 2, 3)}, name="servo-faults-test")
    phases = MissionPhases()
    options = RunOptions(
        seed=4,
        servo_silent=(2, PhaseStart("lift")),
        servo_error=ServoError(1, "overheating", PhaseStart("lift", 1.0)),
        bus_corruption=BusCorruption(PhaseStart("excite"), 5.0, 0.3),
    )
    faults = ServoBusFaults(options, phases)
    faults.update(10.0, bus)  # no phase yet: nothing
    assert bus._responder.faults.silent_ids == frozenset() and not bus.servos[1].hardware_error
    phases.observe_text("pickup: phase lift", 20.0)
    faults.update(20.0, bus)
    assert bus._responder.faults.silent_ids == {2} and not bus.servos[1].hardware_error
    faults.update(21.0, bus)
    assert bus.servos[1].hardware_error and not bus.servos[1].torque_enabled
    phases.observe_text("pickup: phase excite", 30.0)
    faults.update(30.0, bus)
    assert bus._responder.faults.crc_corruption_rate == 0.3
    assert bus._responder.faults.silent_ids == {2} and bus._responder.faults.seed == 4
    faults.update(34.9, bus)
    assert bus._responder.faults.crc_corruption_rate == 0.3 and faults.pending
    faults.update(35.0, bus)
    assert bus._responder.faults.crc_corruption_rate == 0.0 and not faults.pending
    assert bus._responder.faults.silent_ids == {2}


def test_a_rebooting_servo_loses_its_torque_and_answers_nothing_while_it_boots():
    bus = MemoryServoBus({i: XM430Servo(i) for i in (1, 2, 3)}, name="servo-reboot-test")
    bus.servos[1].write(64, b"\x01")  # Torque Enable
    phases = MissionPhases()
    options = RunOptions(seed=4, servo_reboot=ServoReboot(1, PhaseStart("excite", 0.5), 0.1))
    faults = ServoBusFaults(options, phases)
    phases.observe_text("pickup: phase excite", 30.0)
    faults.update(30.4, bus)
    assert bus.servos[1].torque_enabled and bus._responder.faults.silent_ids == frozenset()
    faults.update(30.5, bus)
    assert not bus.servos[1].torque_enabled and bus._responder.faults.silent_ids == {1}
    faults.update(30.59, bus)
    assert bus._responder.faults.silent_ids == {1} and faults.pending
    faults.update(30.6, bus)
    assert bus._responder.faults.silent_ids == frozenset() and not faults.pending
    assert not bus.servos[1].torque_enabled  # limp until the host enables it
    with pytest.raises(ValueError, match=r"boot_s must be in \(0, 10\]"):
        ServoReboot(1, 5.0, 12.0)


def test_a_fault_at_a_phase_is_labelled_with_it():
    fault = Fault(kind="link_cut", at_phase="grasp", offset_s=0.5, duration_s=2.0)
    assert fault.label() == "link_cut(at_phase=grasp, offset_s=0.5, duration_s=2)"
    assert Fault(kind="servo_silent", servo_id=2, at_phase="lift").offset_s is None


def test_a_lossy_link_drops_its_fraction_and_only_while_it_lasts():
    phases = MissionPhases()
    faults = LinkFaults(phases, 3, loss=LinkLoss(PhaseStart("lift"), 5.0, 0.3))
    assert not faults.drops("onboard", 10.0)  # the lift has not begun
    phases.observe_text("pickup: phase lift", 10.0)
    drops = [faults.drops("onboard", 12.0) for _ in range(4000)]
    assert 0.27 < sum(drops) / len(drops) < 0.33
    assert not faults.drops("gcs", 12.0) and not faults.drops("onboard", 15.0)


def test_the_pilots_takeover_is_one_ground_station_mode_command():
    faults = LinkFaults(MissionPhases(), 0, takeover=PilotTakeover(20.0, "AUTO_RTL"))
    assert faults.takeover(19.99) is None
    command = faults.takeover(20.0)
    assert command is not None and command.get_type() == "COMMAND_LONG"
    assert command.command == mavlink2.MAV_CMD_DO_SET_MODE
    assert (command.param2, command.param3) == (4.0, 5.0)  # AUTO, RTL
    assert (command.get_srcSystem(), command.get_srcComponent()) == (255, 190)
    assert faults.takeover(21.0) is None  # once
    with pytest.raises(ValueError, match="mode must be one of"):
        PilotTakeover(20.0, "ACRO")


def test_a_killed_companion_needs_no_summary_but_its_log_to_its_last_block():
    truth = [sample(50.0, 1.5, mode="AUTO_RTL"), sample(60.0, 0.0, armed=False, ground=True)]
    assert judge(truth, None, PLACE_M, 49.9, log_until_s=50.0, killed=True).safe
    late = judge(truth, None, PLACE_M, 47.0, log_until_s=50.0, killed=True)
    assert late.broken == ("the flight log ends 3.0 s before the companion's last control",)
    assert judge(truth, None, PLACE_M, 60.0).broken == ("the summary names no outcome",)
    # A companion that handed over to PX4, which flew on: its log reaches the handover.
    assert judge(truth, SUMMARY, PLACE_M, 49.9, log_until_s=50.0).safe
    assert not judge(truth, SUMMARY, PLACE_M, 49.9).safe


def test_the_handover_is_when_px4_last_left_offboard_armed():
    truth = [
        sample(30.0, 1.5),
        sample(40.0, 1.5, mode="AUTO_LOITER"),
        sample(41.0, 1.5),
        sample(50.0, 1.2, mode="AUTO_RTL"),
        sample(60.0, 0.0, mode="AUTO_RTL", armed=False, ground=True),
        sample(61.0, 0.0, armed=False, ground=True),
    ]
    assert handover_s(truth) == 50.0
    assert handover_s([sample(5.0, 1.0, mode="AUTO_LOITER")]) is None


def test_a_latency_spike_delays_the_onboard_link_while_it_lasts():
    phases = MissionPhases()
    faults = LinkFaults(phases, 0, latency=LinkLatency(PhaseStart("excite", 0.5), 5.0, 0.3))
    assert faults.delay_s("onboard", 60.0) == 0.0
    phases.observe_text("pickup: phase excite", 60.0)
    assert faults.delay_s("onboard", 60.4) == 0.0
    assert faults.delay_s("onboard", 60.5) == 0.3 and faults.delay_s("gcs", 61.0) == 0.0
    assert faults.delay_s("onboard", 65.5) == 0.0
    with pytest.raises(ValueError, match=r"delay_s must be in \(0, 2\]"):
        LinkLatency(10.0, 5.0, 3.0)


def test_a_delay_line_keeps_the_order_and_lets_go_when_each_is_due():
    line: DelayLine[str] = DelayLine()
    assert not line.hold("before", 10.0, 0.0) and not line  # no delay: goes on now
    assert line.hold("a", 10.0, 0.3) and line.hold("b", 10.1, 0.3)
    assert line.hold("after", 10.2, 0.0)  # the spike is over, but "a" and "b" are ahead
    assert line.due(10.29) == []
    assert line.due(10.3) == ["a"]
    assert line.due(10.4) == ["b", "after"] and not line
