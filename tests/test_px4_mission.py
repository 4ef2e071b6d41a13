"""The pickup mission flown against the real PX4 (issue "Fly the real PX4").

PX4 SITL (``PX4_SITL_DIR``) with its SIH rigid body matched to
``configs/px4_sih_pickup.toml`` (the pickup vehicle: 1.22 kg, six 6 N rotors on 0.215 m
arms, linear motors) in motion-capture navigation, the arm's XM430s on a pty on a held base
(``sitl sih``), and ``companion mission pickup`` as a user runs it. SIH has no arm
dynamics, so the estimate is not judged here; the flight is: every phase flown, no fault,
no tilt saturation, tilt below 15 deg outside the excitation, the handover transient
(the first 0.5 s) below 5 deg, the position error against the vehicle's own estimate
below 10 cm RMS,
landed and disarmed. The figures are computed from the flight log, not taken from the
app's summary.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from flight_checks import MISSION_PHASES

from companion.logs.flightlog import read_flight_log
from sitl.vehicle.launch import start_sih

pytestmark = pytest.mark.alone
"""SIH flies on the wall clock (real time) and its servos answer on a pseudo-terminal: beside
another PX4 flight in the test command's parallel phase it starved (servo 1 silent for 21.6
ms before the mission began). The estimate on its bound in the excitation with a saturated
tilt, seen in CI twice (once alone), was the thrust scale carried off along a slope fitted
to noise (reproduced with both cores busy: s 0.98 -> 0.62 over 90 s, m2 on its bound); the
config now holds s, as SIH's thrust does not sag, and a slope must stand out of the noise."""
ROOT = Path(__file__).parent.parent
CONFIG = ROOT / "configs" / "px4_sih_pickup.toml"
PAYLOAD_AT = "1.5,1.0,0.05"
PLACE_AT = "-1.0,0.5,0.05"


def mission(connect: str, arm_bus: str, out: Path, *extra: str, config: Path = CONFIG):
    return subprocess.run(
        [
            sys.executable, "-c", "from companion.cli.main import main; main()",
            "mission", "pickup", "--config", str(config), "--connect", connect,
            "--arm-bus", arm_bus, "--payload-at", PAYLOAD_AT, "--place-at", PLACE_AT,
            "--out", str(out), *extra,
        ],
        capture_output=True, text=True, timeout=900,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )  # fmt: skip


SIH_SPEED = 2.0
"""PX4_SIM_SPEED_FACTOR of this flight. At 2x it takes 83 s (145 s at 1x); flown three times
at 2x against these checks at 11731bc: tilt outside the excitation 10.1-10.5 deg (limit
15), position RMS 7.2-7.3 cm (limit 10), every phase, no fault. A handover check over 2 s
had failed once at 2x (6.8 deg) and once at 1x (5.3 deg): the mission's first move, not the
speed; the check looks at the first 0.5 s."""


def fly(px4_build, tmp: Path, controller: str):
    """The SIH pickup at ``SIH_SPEED`` (83 s)."""
    sih = start_sih(CONFIG, "--navigation", "mocap", "--keep-log", str(tmp / "px4"),
                    "--speed-factor", f"{SIH_SPEED:g}", px4_dir=px4_build.root)  # fmt: skip
    try:
        result = mission(sih.connect, sih.arm_bus, tmp / controller, "--controller", controller)
    finally:
        sih.stop()
    summary_path = tmp / controller / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.exists() else None
    return result, summary, read_flight_log(tmp / controller / "flight.csv")


@pytest.fixture(scope="module", params=["passivity"])
def flight(request, px4_build, tmp_path_factory):
    """The pickup on SIH's armless body (the same mission against real PX4 flies in
    tests/test_px4_hil.py with our physics: the arm's reaction, the payload). The adaptive
    controller: with the non-adaptive one the unmodelled payload against the paper's soft
    joint gains (k Lambda = 0.28 N m/rad) can tip the arm over during the excitation, and on SIH's
    held base nothing stops it spinning (seen once: estimate_bound and a saturated tilt
    from the spinning arm's terms in the controller)."""
    tmp = tmp_path_factory.mktemp(f"px4-{request.param}")
    return (request.param, *fly(px4_build, tmp, request.param))


def _estimate_by_phase(log) -> str:
    """m2 and the thrust scale s (min..max) in each flown phase: what a fault of the
    estimate needs to be told apart (s carried off along a slope, m2 on its bound)."""
    c = log.columns
    lines = []
    for phase in MISSION_PHASES:
        m = c["phase"] == phase
        if m.any():
            m2, s = c["theta_hat_m2_kg"][m], c["thrust_scale_hat"][m]
            lines.append(f"{phase}: m2 {np.nanmin(m2):.3f}..{np.nanmax(m2):.3f} kg, "
                         f"s {np.nanmin(s):.3f}..{np.nanmax(s):.3f}")  # fmt: skip
    return "\n".join(lines)


def _offboard(log):
    phase = log.columns["phase"]
    return np.isin(phase, MISSION_PHASES)


@pytest.mark.slow
def test_the_mission_completes_against_px4_without_a_fault(flight):
    controller, result, summary, log = flight
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    assert summary["controller"] == controller and summary["completed"]
    assert summary["faults"] == [], _estimate_by_phase(log)
    assert summary["landed"] and summary["disarmed"]
    assert [p["phase"] for p in summary["phases"]] == MISSION_PHASES
    assert 100.0 < summary["control_rate_hz"] < 130.0  # PX4: ODOMETRY at its EKF's 125 Hz
    assert "THR_MDL_FAC 0" in summary["vehicle_params"]
    modes = set(log.columns["px4_mode"])
    assert {"TAKEOFF", "LOITER", "OFFBOARD", "LAND"} <= modes


@pytest.mark.slow
def test_tilt_stays_small_and_never_saturates(flight):
    _, _, _, log = flight
    c = log.columns
    flown = _offboard(log)
    tilt_deg = np.degrees(np.hypot(c["q_phi_rad"], c["q_theta_rad"]))
    assert not np.any(c["sp_tilt_saturated"][flown] == 1.0)
    outside = flown & (c["phase"] != "excite")
    assert tilt_deg[outside].max() < 15.0


@pytest.mark.slow
def test_the_offboard_handover_is_bumpless(flight):
    """PX4 flies the last streamed setpoint the moment it accepts OFFBOARD: the attitude
    the vehicle had and the hover thrust; the loop closes on the acknowledgement. Judged
    over the first 0.5 s: after that the tilt is the mission's own (the first move starts
    from the velocity the vehicle had; one run tilted 5.3 deg at 1.8 s following a 6 deg
    setpoint, which a 2 s window counted as the handover's)."""
    _, _, _, log = flight
    c = log.columns
    flown = np.flatnonzero(_offboard(log))
    t0 = c["t_vehicle_s"][flown[0]]
    tilt_deg = np.degrees(np.hypot(c["q_phi_rad"], c["q_theta_rad"]))
    window = flown[c["t_vehicle_s"][flown] <= t0 + 0.5]
    assert np.max(np.abs(tilt_deg[window] - tilt_deg[flown[0]])) < 5.0
    # The stream before the acknowledgement was the hold setpoint, at hover thrust.
    hold = c["phase"] == "hold"
    streamed = hold & ~np.isnan(c["thrust_rel"])
    assert streamed.sum() > 0
    weight_n = 1.22 * 9.81
    np.testing.assert_allclose(c["sp_thrust_n"][streamed], weight_n, rtol=0.01)


@pytest.mark.slow
def test_position_error_against_the_vehicles_own_estimate_is_below_10_cm(flight):
    _, _, summary, log = flight
    c = log.columns
    flown = _offboard(log)
    error = np.stack([c[f"q_{a}_m"][flown] - c[f"qd_{a}_m"][flown] for a in "xyz"])
    rms = math.sqrt(float(np.mean(np.sum(error**2, axis=0))))
    assert rms < 0.10
    assert summary["position_rms_m"] == pytest.approx(rms, rel=0.05)


def test_a_config_that_contradicts_px4s_thrust_linearization_is_refused(px4_build, tmp_path):
    """The belief that broke the first flights: the config's motors curve 0.3 against
    PX4's THR_MDL_FAC 0. The app reads PX4's parameter before arming and refuses."""
    sih = start_sih(CONFIG, "--navigation", "mocap", px4_dir=px4_build.root)
    try:
        result = mission(sih.connect, sih.arm_bus, tmp_path / "o",
                         config=ROOT / "configs" / "sitl_pickup.toml")  # fmt: skip
    finally:
        sih.stop()
    assert result.returncode == 1, result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    failure = [line for line in result.stderr.splitlines() if "THR_MDL_FAC" in line]
    assert len(failure) == 1 and "vehicle.rotors.thr_mdl_fac is 0.3" in failure[0]
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert not summary["completed"] and summary["control_cycles"] == 0
