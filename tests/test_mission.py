"""The pickup mission planner: phases, gripper and estimator actions, smooth references."""

import math
from dataclasses import replace

import numpy as np
import pytest

from companion.config import load_config
from companion.coordinates import Z
from companion.mission.pickup import (
    LIFT_RESTART_M,
    PICKUP_ORDER,
    WEIGH_HEIGHT_M,
    EstimatorAction,
    GripperAction,
    Phase,
    PickupMission,
    PickupPlan,
    min_jerk,
)

SCENARIO = load_config("configs/sitl_pickup.toml")
PLAN = PickupPlan(home_m=(0.0, 0.0), payload_at_m=(1.5, 1.0, 0.05), place_at_m=(-1.0, 0.5, 0.05))
DT = 0.004


def fly(plan=PLAN, confident_after_s=8.0, lag=0, payload_kg=0.0):
    """Track q_d perfectly (or ``lag`` cycles late), the estimator saying ``payload_kg``;
    return the per-cycle record."""
    mission = PickupMission(plan, SCENARIO)
    q = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.0, 0.0, -1.5])
    mission.start(0.0, q)
    history = [q.copy()] * (lag + 1)
    records = []
    t = 0.0
    excite_start = None
    while mission.phase != Phase.DONE and t < 600.0:
        conf = excite_start is not None and t - excite_start >= confident_after_s
        cmd = mission.update(t, history[0], conf, payload_kg)
        if cmd.phase == Phase.EXCITE and excite_start is None:
            excite_start = t
        records.append((t, cmd))
        history = [*history[1:], cmd.desired.q.copy()]
        t += DT
    return mission, records


@pytest.mark.parametrize("stuck", [False, True])
def test_the_carry_waits_until_the_swing_has_let_the_vehicle_back(stuck):
    """After the excitation's fade-out the vehicle, pushed off by the arm, must have been
    back within arrive_tolerance_m for settle_s before to_place; one that stays off goes on
    after arrive_timeout_s."""
    mission = PickupMission(PLAN, SCENARIO)
    q = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.0, 0.0, -1.5])
    mission.start(0.0, q)
    t, excite_start = 0.0, None
    offset = np.zeros(8)
    offset[0] = 0.4  # > arrive_tolerance_m (0.15 m)
    back_after_s = 13.0  # 3 s after the fade-out of a confident excitation (6 s + 4 s)
    while mission.phase != Phase.TO_PLACE and t < 300.0:
        pushed = excite_start is not None and (stuck or t - excite_start < back_after_s)
        cmd = mission.update(t, q + offset if pushed else q, confident=True)
        if cmd.phase == Phase.EXCITE and excite_start is None:
            excite_start = t
        q = cmd.desired.q.copy()
        t += DT
    assert mission.phase == Phase.TO_PLACE
    start = dict((p, ts) for ts, p in mission.phase_log)[Phase.TO_PLACE]
    fade_end = excite_start + PLAN.excite_min_s + PLAN.excite_period_s
    back = excite_start + back_after_s + PLAN.settle_s
    expected = fade_end + PLAN.arrive_timeout_s if stuck else back
    assert start == pytest.approx(expected, abs=2 * DT)


def test_min_jerk_is_at_rest_at_both_ends():
    a, b = np.zeros(2), np.array([1.0, -2.0])
    for t, expected in ((0.0, a), (3.0, b)):
        q, qd, qdd = min_jerk(t, 3.0, a, b)
        np.testing.assert_allclose(q, expected)
        np.testing.assert_allclose(qd, 0.0, atol=1e-12)
        np.testing.assert_allclose(qdd, 0.0, atol=1e-12)
    # Peak speed of a minimum-jerk move is 1.875 x the mean speed.
    assert min_jerk(1.5, 3.0, a, b)[1][0] == pytest.approx(1.875 / 3.0)


def test_phases_run_in_order_with_gripper_and_estimator_actions():
    mission, records = fly()
    assert [p for _, p in mission.phase_log] == list(PICKUP_ORDER)
    closes = [cmd for _, cmd in records if cmd.gripper == GripperAction.CLOSE]
    opens = [cmd for _, cmd in records if cmd.gripper == GripperAction.OPEN]
    assert [c.phase for c in closes] == [Phase.GRASP]
    assert [c.phase for c in opens] == [Phase.RELEASE]
    actions = [cmd.estimator for _, cmd in records]
    # the grasp; the lift's start; the lift off the ground; the release
    assert actions.count(EstimatorAction.RESTART) == 4
    assert actions.count(EstimatorAction.RESET_EMPTY) == 1
    assert mission.confident_when_done


def test_grasp_puts_the_payload_point_on_the_object():
    _, records = fly()
    grasp = next(cmd for _, cmd in records if cmd.phase == Phase.GRASP)
    q = grasp.desired.q
    arm = SCENARIO.arm
    # Arm straight down: payload point = base + mount + (l1 + lc) down.
    point_z = q[2] + arm.mount_point_m[2] - arm.link1.length_m - (arm.link2.length_m - 0.02)
    assert q[6] == pytest.approx(-math.pi / 2) and q[7] == pytest.approx(0.0)
    np.testing.assert_allclose([q[0], q[1], point_z], PLAN.payload_at_m, atol=1e-9)


def test_references_are_continuous_and_bounded():
    _, records = fly()
    qs = np.array([cmd.desired.q for _, cmd in records])
    qds = np.array([cmd.desired.q_dot for _, cmd in records])
    steps = np.abs(np.diff(qs, axis=0))
    # No jump bigger than what the peak rates allow in one cycle.
    assert steps[:, 0:3].max() < 1.0 * DT
    assert steps[:, 6:8].max() < 1.5 * DT
    speed = np.linalg.norm(qds[:, 0:2], axis=1)
    assert speed.max() < PLAN.cruise_speed_m_s * 1.3
    # q_dot is the derivative of q (central differences).
    fd = (qs[2:] - qs[:-2]) / (2 * DT)
    assert np.max(np.abs(fd - qds[1:-1])) < 0.02


def test_excitation_stops_at_the_time_limit_without_confidence():
    mission, records = fly(confident_after_s=1e9)
    assert mission.phase == Phase.DONE
    assert not mission.confident_when_done
    excite = [t for t, cmd in records if cmd.phase == Phase.EXCITE]
    # the time limit, then settle_s back at the centre (tracked perfectly here)
    assert excite[-1] - excite[0] == pytest.approx(PLAN.excite_max_s + PLAN.settle_s, abs=0.05)


def test_phase_waits_for_the_vehicle_to_arrive():
    # A vehicle that lags far behind the reference keeps the phase from ending on time.
    quick, _ = fly()
    slow, _ = fly(lag=1500)
    t_quick = dict((p, t) for t, p in quick.phase_log)[Phase.DESCEND]
    t_slow = dict((p, t) for t, p in slow.phase_log)[Phase.DESCEND]
    assert t_slow > t_quick + 2.0


def test_plan_rejects_nonsense():
    with pytest.raises(ValueError, match="finite"):
        PickupPlan(home_m=(0.0, math.nan), payload_at_m=(1, 1, 0), place_at_m=(0, 0, 0))
    with pytest.raises(ValueError, match="excite_max_s"):
        PickupPlan((0, 0), (1, 1, 0), (0, 0, 0), excite_min_s=10.0, excite_max_s=11.0)


def test_estimator_learns_only_from_the_grasp_on():
    """Before the grasp the arm is known empty: only the thrust scale is learnt; the
    estimator restarts as the grasp begins (the weight comes on as the jaws close) and as
    the jaws open (the weight leaves), and runs through the release."""
    _, records = fly()
    by_phase = {}
    for _, cmd in records:
        by_phase.setdefault(cmd.phase, set()).add(cmd.estimator)
    assert by_phase[Phase.TO_OBJECT] == {EstimatorAction.CALIBRATE}
    assert by_phase[Phase.DESCEND] == {EstimatorAction.CALIBRATE}
    assert by_phase[Phase.GRASP] == {EstimatorAction.RESTART, EstimatorAction.RUN}
    restarts = [(t, cmd) for t, cmd in records if cmd.estimator == EstimatorAction.RESTART]
    restart, lift, again, release = restarts
    assert restart[1].phase == Phase.GRASP and restart[1].phase_changed
    # As the lift begins (the weight starts to come over from the ground), and once more
    # LIFT_RESTART_M above where it began: the object's weight is on as it leaves the
    # ground.
    assert lift[1].phase == Phase.LIFT and lift[1].phase_changed
    assert again[1].phase == Phase.LIFT and not again[1].phase_changed
    lift_z = next(cmd.desired.q[Z] for _, cmd in records if cmd.phase == Phase.LIFT)
    assert LIFT_RESTART_M <= again[1].desired.q[Z] - lift_z < LIFT_RESTART_M + 0.01
    assert release[1].phase == Phase.RELEASE and release[1].phase_changed
    assert release[1].gripper == GripperAction.OPEN
    assert by_phase[Phase.RELEASE] == {EstimatorAction.RESTART, EstimatorAction.RUN}
    assert EstimatorAction.RUN in by_phase[Phase.EXCITE]
    assert EstimatorAction.RUN in by_phase[Phase.CLIMB]


def test_grasp_waits_until_the_jaws_settle_on_the_object():
    mission = PickupMission(PLAN, SCENARIO)
    q = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.0, 0.0, -1.5])
    mission.start(0.0, q)
    t, wobble_until = 0.0, None
    while mission.phase != Phase.GRASP and t < 200.0:
        cmd = mission.update(t, q, False)
        q = cmd.desired.q.copy()
        if cmd.phase == Phase.DESCEND:
            if wobble_until is None:
                wobble_until = t + 12.0
            if t < wobble_until:  # the vehicle swings 10 cm around the reference
                q[0] += 0.1 * math.sin(2.0 * t)
        t += DT
    assert mission.phase == Phase.GRASP
    grasp_t = dict((p, t) for t, p in mission.phase_log)[Phase.GRASP]
    assert grasp_t > wobble_until  # not during the 10 cm swing, only after it stopped


def test_min_jerk_can_leave_at_a_velocity_and_still_arrive_at_rest():
    a, b, v0 = np.array([0.0, 1.0]), np.array([2.0, 1.0]), np.array([0.3, -0.2])
    q0, qd0, qdd0 = min_jerk(0.0, 4.0, a, b, v0)
    np.testing.assert_allclose(q0, a)
    np.testing.assert_allclose(qd0, v0)
    np.testing.assert_allclose(qdd0, 0.0, atol=1e-12)
    q1, qd1, qdd1 = min_jerk(4.0, 4.0, a, b, v0)
    np.testing.assert_allclose(q1, b)
    np.testing.assert_allclose(qd1, 0.0, atol=1e-12)
    np.testing.assert_allclose(qdd1, 0.0, atol=1e-12)
    h = 1e-5  # the derivatives are those of the position
    qm, _, _ = min_jerk(1.3 - h, 4.0, a, b, v0)
    qp, _, _ = min_jerk(1.3 + h, 4.0, a, b, v0)
    _, qd, _ = min_jerk(1.3, 4.0, a, b, v0)
    np.testing.assert_allclose((qp - qm) / (2 * h), qd, rtol=1e-6)


def test_the_mission_starts_at_the_handed_over_velocity():
    mission = PickupMission(PLAN, SCENARIO)
    q_now = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.7, 0.0, -1.5])
    mission.start(10.0, q_now, np.array([0.3, -0.1, 0.05, 9, 9, 9, 9, 9]))
    first = mission.update(10.0, q_now, False).desired
    np.testing.assert_allclose(first.q_dot[0:3], [0.3, -0.1, 0.05])
    np.testing.assert_allclose(first.q_dot[3:], 0.0)
    assert first.q[5] == pytest.approx(0.7)  # the heading the vehicle had


def test_a_point_below_where_the_vehicle_stands_is_out_of_reach():
    """The arm reaches the object from a hover hang_m above it: with motion capture (z = 0
    on the ground, the vehicle standing at its gear height) and with GPS (EKF2's origin at
    the standing vehicle, the same object at minus the gear height) the pickup reaches; an
    object deeper than the arm can reach from where the vehicle stands is refused."""
    mission = PickupMission(PLAN, SCENARIO)
    gear_m = 0.25
    object_z = PLAN.payload_at_m[2]
    assert mission.unreachable(gear_m, 0.03) is None  # motion capture: lab frame
    gps = PickupMission(
        replace(PLAN, payload_at_m=(*PLAN.payload_at_m[:2], object_z - gear_m),
                place_at_m=(*PLAN.place_at_m[:2], PLAN.place_at_m[2] - gear_m)),
        SCENARIO,
    )  # fmt: skip
    assert gps.unreachable(0.0, 0.03) is None

    def at(z: float) -> PickupMission:
        return PickupMission(replace(PLAN, payload_at_m=(*PLAN.payload_at_m[:2], z)), SCENARIO)

    edge = gear_m + 0.03 - mission.hang_m  # the object whose grasp hovers at the margin
    assert at(edge + 0.001).unreachable(gear_m, 0.03) is None
    why = at(edge - 0.001).unreachable(gear_m, 0.03)
    assert why is not None and why.startswith("the object at z = ") and "reach" in why
    low_place = PickupMission(replace(PLAN, place_at_m=(*PLAN.place_at_m[:2], -1.0)), SCENARIO)
    assert "place point" in (low_place.unreachable(gear_m, 0.03) or "")


def test_heights_above_the_ground_become_px4_heights_before_the_mission_flies():
    """start_from moves the object's, the place point's and the cruise's heights by where
    the ground lies in PX4's frame (GPS: 0.25 m below EKF2's origin at the standing
    vehicle), so an object on the ground is met there; horizontal positions stay."""
    mission = PickupMission(PLAN, SCENARIO)
    assert mission.start_from(0.0, -0.25, 0.03) is None
    assert mission.plan.payload_at_m == pytest.approx(
        (*PLAN.payload_at_m[:2], PLAN.payload_at_m[2] - 0.25)
    )
    assert mission.plan.place_at_m[2] == pytest.approx(PLAN.place_at_m[2] - 0.25)
    assert mission.plan.cruise_altitude_m == pytest.approx(PLAN.cruise_altitude_m - 0.25)
    q = np.array([0.0, 0.0, 1.25, 0.0, 0.0, 0.0, 0.0, -1.5])
    mission.start(10.0, q, np.zeros(8))
    with pytest.raises(RuntimeError, match="before the mission flies"):
        mission.start_from(0.0, -0.25, 0.03)
    # Heights the plan cannot reach from there are refused as before.
    deep = PickupMission(replace(PLAN, payload_at_m=(*PLAN.payload_at_m[:2], -0.5)), SCENARIO)
    assert "out of the arm's reach" in (deep.start_from(0.0, -0.25, 0.03) or "")


def test_the_configs_swing_amplitude_reaches_the_plan():
    """``[flight] excite_eta1_rad`` (0.7 in sitl_pickup.toml, 0.5 by default) is the
    amplitude of joint 1 in the excitation the mission flies."""
    from companion.cli.mission import plan_for

    for name, amplitude in (("sitl_pickup.toml", 0.7), ("px4_sih_pickup.toml", 0.5)):
        config = load_config(f"configs/{name}")
        plan = plan_for(config, (1.5, 1.0, 0.05), (-1.0, 0.5, 0.05), 1.5)
        assert plan.excite_eta1_rad == amplitude


def test_the_payload_is_weighed_in_the_lifts_first_centimetres_only():
    """``weighing``: in the lift, up to WEIGH_HEIGHT_M above where it began (the grasp's
    height); not in the grasp, not higher up."""
    mission = PickupMission(PLAN, SCENARIO)
    q = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.0, 0.0, -1.5])
    mission.start(0.0, q)
    t = 0.0
    grasp_z = None
    while mission.phase != Phase.LIFT:
        cmd = mission.update(t, q, False)
        q = cmd.desired.q.copy()
        if cmd.phase == Phase.GRASP:
            grasp_z = float(q[Z])
            assert not mission.weighing(grasp_z)
        t += DT
    assert grasp_z is not None
    assert mission.weighing(grasp_z) and mission.weighing(grasp_z + WEIGH_HEIGHT_M)
    assert not mission.weighing(grasp_z + WEIGH_HEIGHT_M + 0.01)


@pytest.mark.parametrize(
    ("payload_kg", "swing"), [(0.1, 1.0), (0.25, 1.0), (0.5, math.sqrt(0.5)), (1.0, 0.5)]
)
def test_a_heavier_payload_swings_the_arm_less(payload_kg, swing):
    """The excitation's joint amplitudes are for ``excite_payload_kg``: a heavier payload,
    as estimated when the swing begins, swings by the square root of the mass ratio; the
    circle stays."""
    plan = replace(PLAN, excite_payload_kg=0.25)
    _, records = fly(plan, payload_kg=payload_kg)
    excite = np.array([cmd.desired.q for _, cmd in records if cmd.phase == Phase.EXCITE])
    centre = excite[0]
    reach = np.max(np.abs(excite - centre), axis=0)
    assert reach[6] == pytest.approx(swing * plan.excite_eta1_rad, rel=0.01)
    assert reach[7] == pytest.approx(swing * plan.excite_eta2_rad, rel=0.01)
    assert reach[1] == pytest.approx(plan.excite_radius_m, rel=0.01)


def test_the_swing_is_the_plans_without_a_reference_payload():
    mission = PickupMission(PLAN, SCENARIO)
    assert PLAN.excite_payload_kg is None and mission.swing_scale(2.0) == 1.0
    with pytest.raises(ValueError, match="excite_payload_kg"):
        replace(PLAN, excite_payload_kg=0.0)
