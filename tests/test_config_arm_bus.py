"""companion.config: the optional ``arm_bus`` section and its arm_driver configurations."""

import copy
import math
import tomllib
from pathlib import Path

import pytest

from arm_driver.joint import GripperConfig, JointConfig
from companion.config import ConfigError, arm_bus_configs
from sitl.scenario import load_scenario, parse_scenario

CONFIGS = Path(__file__).parent.parent / "configs"
EXPERIMENT = CONFIGS / "experiment_arm.toml"


def experiment_data() -> dict:
    return tomllib.loads(EXPERIMENT.read_text())


def problem(data: dict) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        parse_scenario(data, "x.toml")
    return info.value


def test_experiment_arm_has_the_paper_arm_bus() -> None:
    cfg = load_scenario(EXPERIMENT)
    assert cfg.arm_bus is not None
    assert cfg.arm_bus.url.startswith("dynamixel://")
    joints, gripper = arm_bus_configs(cfg.arm_bus)
    assert [(j.name, j.servo_id) for j in joints] == [("eta1", 1), ("eta2", 2)]
    assert all(isinstance(j, JointConfig) for j in joints)
    assert isinstance(gripper, GripperConfig) and gripper.servo_id == 3
    assert joints[0].torque_constant_n_m_per_a == pytest.approx(4.1 / 2.3, rel=1e-2)
    # the arm hangs straight down (eta1 = -pi/2) inside the limits
    assert joints[0].position_min_rad < -math.pi / 2 < joints[0].position_max_rad


def test_scenarios_without_the_section_stay_valid() -> None:
    data = experiment_data()
    del data["arm_bus"]
    assert parse_scenario(data).arm_bus is None
    assert load_scenario(CONFIGS / "paper_sim.toml").arm_bus is None


def test_without_gripper() -> None:
    data = experiment_data()
    del data["arm_bus"]["gripper"]
    cfg = parse_scenario(data)
    joints, gripper = arm_bus_configs(cfg.arm_bus)
    assert gripper is None and len(joints) == 2


def test_unknown_key_names_the_joint_and_suggests() -> None:
    data = experiment_data()
    data["arm_bus"]["joints"][1]["servo_idd"] = 4
    error = problem(data)
    assert error.key == "arm_bus.joints[1].servo_idd"
    assert "did you mean 'servo_id'" in error.reason


def test_unknown_key_in_the_gripper_suggests() -> None:
    data = experiment_data()
    data["arm_bus"]["gripper"]["open_position"] = 1.0
    error = problem(data)
    assert error.key == "arm_bus.gripper.open_position"
    assert "did you mean 'open_position_rad'" in error.reason


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("direction", 0),
        ("direction", 1.0),
        ("servo_id", 256),
        ("servo_id", -1),
        ("torque_constant_n_m_per_a", 0.0),
        ("torque_max_n_m", -1.0),
        ("zero_offset_rad", math.inf),
        ("name", ""),
        ("viscous_friction_n_m_s_per_rad", -0.01),
        ("viscous_friction_n_m_s_per_rad", math.nan),
        ("coulomb_friction_n_m", -0.1),
        ("coulomb_friction_n_m", math.inf),
    ],
)
def test_bad_joint_values_name_the_key(field: str, value: object) -> None:
    data = experiment_data()
    data["arm_bus"]["joints"][0][field] = value
    error = problem(data)
    assert error.key == f"arm_bus.joints[0].{field}"


def test_missing_joint_key() -> None:
    data = experiment_data()
    del data["arm_bus"]["joints"][0]["position_min_rad"]
    error = problem(data)
    assert (error.key, error.reason) == ("arm_bus.joints[0].position_min_rad", "missing key")


def test_no_joints_is_rejected() -> None:
    data = experiment_data()
    data["arm_bus"]["joints"] = []
    assert problem(data).key == "arm_bus.joints"


def test_duplicate_servo_ids_are_rejected() -> None:
    data = experiment_data()
    data["arm_bus"]["joints"][1]["servo_id"] = 1
    error = problem(data)
    assert error.key == "arm_bus.joints[1].servo_id"
    assert "eta1" in error.reason


def test_gripper_sharing_a_joint_id_is_rejected() -> None:
    data = experiment_data()
    data["arm_bus"]["gripper"]["servo_id"] = 2
    error = problem(data)
    assert error.key == "arm_bus.gripper.servo_id"


def test_duplicate_joint_names_are_rejected() -> None:
    data = experiment_data()
    data["arm_bus"]["joints"][1]["name"] = "eta1"
    assert problem(data).key == "arm_bus.joints[1].name"


def test_inverted_limits_are_rejected() -> None:
    data = experiment_data()
    joint = data["arm_bus"]["joints"][0]
    joint["position_min_rad"], joint["position_max_rad"] = 1.0, -1.0
    error = problem(data)
    assert error.key == "arm_bus.joints[0].position_max_rad"


def test_conversion_keeps_every_field() -> None:
    data = experiment_data()
    joint = copy.deepcopy(data["arm_bus"]["joints"][0])
    joint.update(direction=-1, zero_offset_rad=0.25)
    data["arm_bus"]["joints"][0] = joint
    (first, _), _ = arm_bus_configs(parse_scenario(data).arm_bus)
    assert first == JointConfig(**joint)
    assert first.servo_angle_rad(0.0) == 0.25
    assert first.joint_angle_rad(0.35) == pytest.approx(-0.1)


def test_the_section_is_frozen() -> None:
    cfg = load_scenario(EXPERIMENT)
    with pytest.raises(Exception, match="frozen"):
        cfg.arm_bus.url = "dronecan://can0"


def test_friction_keys_default_to_none_and_reach_the_joint_config() -> None:
    data = experiment_data()
    data["arm_bus"]["joints"][1]["viscous_friction_n_m_s_per_rad"] = 0.02
    data["arm_bus"]["joints"][1]["coulomb_friction_n_m"] = 0.01
    joints, _ = arm_bus_configs(parse_scenario(data, "x.toml").arm_bus)
    assert (joints[0].viscous_friction_n_m_s_per_rad, joints[0].coulomb_friction_n_m) == (0, 0)
    assert joints[1].viscous_friction_n_m_s_per_rad == 0.02
    assert joints[1].coulomb_friction_n_m == 0.01


def test_friction_on_a_dronecan_bus_is_refused() -> None:
    """DroneCAN actuators report their output torque: the bus would ignore the friction."""
    data = experiment_data()
    data["arm_bus"]["url"] = "dronecan://can0?interface=socketcan"
    data["arm_bus"]["joints"][0]["coulomb_friction_n_m"] = 0.01
    error = problem(data)
    assert error.key == "arm_bus.joints[0].coulomb_friction_n_m"
    assert "DroneCAN" in error.reason


@pytest.mark.parametrize(
    ("rate", "friction"), [(0.0, 0.0), (2.0, 0.02 * 2.0 + 0.01), (-0.5, -0.02 * 0.5 - 0.01)]
)
def test_link_torque_is_the_motor_torque_less_the_friction(rate: float, friction: float) -> None:
    joint = JointConfig(
        "j", 1, 1.5, 4.0, direction=-1,
        viscous_friction_n_m_s_per_rad=0.02, coulomb_friction_n_m=0.01,
    )  # fmt: skip
    assert joint.friction_torque_n_m(rate) == pytest.approx(friction)
    assert joint.link_torque_n_m(0.4, rate) == pytest.approx(-1.5 * 0.4 - friction)
    assert joint.servo_current_a(0.6) == pytest.approx(-0.4)  # no friction feed-forward
