"""One control cycle of the arm bus against the emulators: software cost per cycle.

Prints median and 99th-percentile microseconds of one full cycle through the public
``ArmBus`` API, three joints in current (torque) mode, cycles paced at 1 kHz as in the
control loop (the time between cycles is not counted):

- ``dynamixel (pty)``: Sync Write of Goal Current to 3 XM430 emulators + Sync Read of
  Present Current/Velocity/Position from all 3, over a pseudo-terminal. Includes the
  emulator's own work (same process, another thread) and the servos' Return Delay Time
  set to 0 here (factory: 500 us each, a setting of the real servo, not software);
- ``dronecan (virtual)``: ArrayCommand of 3 FORCE commands + read of the 3 actuators'
  latest Status (what a control cycle costs the driver: the Status cache is filled by the
  receiving thread);
- ``dronecan round trip``: ArrayCommand, then wait for a Status of each actuator
  published *after* it (``max_status_age_ms=0.01``): command -> emulator -> feedback,
  through python-can's virtual bus and two threads.

Target: p99 <= 1 ms in software, so a 1 kHz loop is limited by the wire.
Run: ``python benchmarks/bench_arm_bus.py [--cycles N]``.
"""

from __future__ import annotations

import argparse
import asyncio
import time
import uuid

import numpy as np

from arm_driver.bus import ArmBus, JointConfig, OperatingMode, open_bus
from arm_driver.dynamixel import control_table as ct
from sitl.servo import CanActuator, DroneCanActuatorNode, PtyServoBus, XM430Servo

PERIOD_S = 1e-3
"""Control period the cycles are paced at [s]."""
JOINTS = tuple(JointConfig(f"j{i}", i, 4.1 / 2.3, torque_max_n_m=1.0) for i in (1, 2, 3))
TORQUES = {"j1": 0.1, "j2": -0.1, "j3": 0.05}


async def _cycles(bus: ArmBus, cycles: int) -> tuple[np.ndarray, int]:
    """Durations of ``cycles`` write + read cycles [us], and the number that failed."""
    await bus.disable_torque()
    await bus.set_operating_mode(OperatingMode.CURRENT)
    await bus.enable_torque()
    loop = asyncio.get_running_loop()
    durations, failures = [], 0
    next_start = loop.time()
    for k in range(cycles + 200):
        t0 = time.perf_counter_ns()
        try:
            await bus.write_joint_torques(TORQUES)
            await bus.read_joint_states()
        except Exception:  # counted and reported, the benchmark goes on
            failures += 1
            continue
        if k >= 200:  # warm-up
            durations.append((time.perf_counter_ns() - t0) / 1e3)
        next_start += PERIOD_S
        await asyncio.sleep(max(0.0, next_start - loop.time()))
    await bus.write_joint_torques(dict.fromkeys(TORQUES, 0.0))
    return np.array(durations), failures


async def _dynamixel(cycles: int) -> tuple[np.ndarray, int]:
    servos = {i: XM430Servo(i) for i in (1, 2, 3)}
    for servo in servos.values():
        servo.write(ct.RETURN_DELAY_TIME.address, bytes([0]))
    with PtyServoBus(servos) as sim:
        async with open_bus(f"dynamixel://{sim.device}?timeout_margin_ms=20", JOINTS) as bus:
            return await _cycles(bus, cycles)


async def _dronecan(cycles: int, options: str) -> tuple[np.ndarray, int]:
    actuators = {i: CanActuator(i) for i in (1, 2, 3)}
    with DroneCanActuatorNode(actuators, channel=f"bench-{uuid.uuid4().hex}") as sim:
        async with open_bus(sim.url + options, JOINTS) as bus:
            return await _cycles(bus, cycles)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=2000, help="timed cycles per case")
    cycles = parser.parse_args().cycles
    cases = (
        ("dynamixel (pty), 3 servos", _dynamixel(cycles)),
        ("dronecan (virtual), 3 actuators", _dronecan(cycles, "")),
        (
            "dronecan round trip, 3 actuators",
            _dronecan(cycles, "&max_status_age_ms=0.01&timeout_ms=20"),
        ),
    )
    print(
        f"{'cycle: write 3 torques + read 3 states':<40} {'median us':>10} {'p99 us':>10}"
        f" {'failed':>7}"
    )
    for label, case in cases:
        durations, failures = asyncio.run(case)
        median, p99 = np.median(durations), np.percentile(durations, 99)
        print(f"{label:<40} {median:>10.0f} {p99:>10.0f} {failures:>7}")


if __name__ == "__main__":
    main()
