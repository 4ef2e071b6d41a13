"""Write ``docs/pickup.png``, the README's figure: the default pickup flown on simulated
time (``sitl demo --clock virtual``'s flight, seed 0), seen from above and in its payload
estimate against the simulator's truth.

    python docs/gen_figure.py

Left: the vehicle's path from above, desired and flown, with where the object stood and
where it was placed. Right: the estimated payload mass m2 and centre of mass lc of link 2
over the flight, shaded where the estimator is confident, with the truth dashed.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from companion.cli.mission import plan_for
from companion.logs.flightlog import read_flight_log
from sitl.flight_figures import truth_lines
from sitl.scenario import load_scenario
from sitl.vehicle.options import RunOptions
from sitl.vehicle.virtual_flight import fly_virtual

ROOT = Path(__file__).resolve().parent.parent
FIGURE = ROOT / "docs" / "pickup.png"
PLACE_AT = (-1.0, 0.5, 0.05)


def main() -> None:
    scenario = load_scenario(ROOT / "configs" / "sitl_pickup.toml")
    assert scenario.world is not None and scenario.world.payload_position_m is not None
    payload_at = scenario.world.payload_position_m
    plan = plan_for(scenario.beliefs, payload_at, PLACE_AT, 1.5)
    with tempfile.TemporaryDirectory(prefix="pickup-figure-") as work:
        out = Path(work)
        options = RunOptions(seed=0, truth_log=out / "truth.jsonl")
        _, failure = fly_virtual(scenario, plan, out, options, figures=False, mcap=False)
        if failure is not None:
            raise SystemExit(f"the pickup failed: {failure}")
        c = read_flight_log(out / "flight.csv").columns
        truth = truth_lines(out / "truth.jsonl")

    t0 = float(c["t_vehicle_s"][0])
    t = c["t_vehicle_s"] - t0
    fig, (top, est) = plt.subplots(1, 2, figsize=(11, 4.2))
    top.plot(c["qd_x_m"], c["qd_y_m"], "r--", linewidth=1.0, label="desired")
    top.plot(c["q_x_m"], c["q_y_m"], "b-", linewidth=1.2, label="flown")
    top.plot(*payload_at[:2], "ks", label="object")
    top.plot(*PLACE_AT[:2], "g^", label="place point")
    top.set_xlabel("east [m]")
    top.set_ylabel("north [m]")
    top.set_aspect("equal", adjustable="datalim")
    top.legend(fontsize=8, loc="upper left")
    top.set_title("The pickup from above")

    confident = np.nan_to_num(c["theta_confident"]) > 0.5
    span = (truth.t_s >= t0) & (truth.t_s <= t0 + t[-1])
    est.plot(t, c["theta_hat_m2_kg"], "b-", label="m2 estimate [kg]")
    est.plot(truth.t_s[span] - t0, truth.m2_kg[span], "b--", linewidth=0.9, label="m2 truth")
    est.plot(t, c["theta_hat_lc_m"], "m-", label="lc estimate [m]")
    est.plot(truth.t_s[span] - t0, truth.lc_m[span], "m--", linewidth=0.9, label="lc truth")
    est.fill_between(t, 0.0, 1.0, where=confident, color="g", alpha=0.12, linewidth=0,
                     transform=est.get_xaxis_transform(), label="confident")  # fmt: skip
    est.set_xlabel("t [s]")
    est.set_ylim(0.0, 0.45)
    est.legend(fontsize=8, loc="center right", ncol=1)
    est.set_title("Link 2 with its payload: learnt in flight")
    fig.tight_layout()
    fig.savefig(FIGURE, dpi=90)
    plt.close(fig)
    print(f"wrote {FIGURE.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
