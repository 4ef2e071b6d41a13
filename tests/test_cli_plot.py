"""``companion plot LOG --out DIR``: figures from a flight log; exit 2 for a bad log."""

import numpy as np
import pytest

from companion.control.setpoints import AttitudeThrustSetpoint
from companion.logs.flightlog import CycleRecord, FlightLogWriter


@pytest.fixture
def flight_log(tmp_path):
    path = tmp_path / "flight.csv"
    with FlightLogWriter(path) as log:
        for i in range(200):
            t = 0.004 * i
            q = np.array([0.5 * np.cos(t), -0.5 * np.cos(t), 0.7, 0.01, -0.01, 0.0, -1.5, 0.2])
            log.write(
                CycleRecord(
                    t_vehicle_s=100.0 + t,
                    q=q,
                    q_dot=np.zeros(8),
                    q_ddot=np.zeros(8),
                    q_d=q + 0.01,
                    theta_hat=(0.1 + 0.001 * i, 0.01, 0.001),
                    theta_excitation=1e-3 * (i + 1),
                    theta_spread=1.0 / (i + 1),
                    theta_confident=i > 120,
                    theta_frozen=False,
                    tau=np.ones(8),
                    setpoint=AttitudeThrustSetpoint(0.01, -0.01, 0.0, 14.0, 0.5, False, False),
                    servo_torque_cmd_n_m=(0.1, 0.02),
                    servo_torque_meas_n_m=(0.11, 0.019),
                    servo_position_rad=(-1.5, 0.2),
                    px4_mode="POSCTL" if i < 50 else "OFFBOARD",
                    armed=True,
                    phase="excite",
                )
            )
    return path


def test_plot_writes_the_three_figures(run_cli, flight_log, tmp_path):
    out = tmp_path / "figures"
    result = run_cli("plot", str(flight_log), "--out", str(out))
    assert result.returncode == 0, result.stderr
    for name in ("tracking.png", "estimation.png", "arm.png"):
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n"
        assert len(data) > 10_000  # drawn, not an empty canvas
    assert "200 rows" in result.stdout


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "cannot read"),
        ("time,x\n0,1\n", "not a flight log header"),
    ],
)
def test_bad_log_is_one_error_line_and_exit_2(run_cli, tmp_path, content, message):
    log = tmp_path / "flight.csv"
    if content is not None:
        log.write_text(content)
    result = run_cli("plot", str(log), "--out", str(tmp_path / "out"))
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0]
    assert not (tmp_path / "out").exists()


def test_empty_log_is_refused(run_cli, tmp_path):
    log = tmp_path / "flight.csv"
    with FlightLogWriter(log):
        pass  # header only
    result = run_cli("plot", str(log), "--out", str(tmp_path / "out"))
    assert result.returncode == 2
    assert "no rows" in result.stderr


def test_a_simulated_flight_is_drawn_with_its_truth_beside_the_estimate(flight_log, monkeypatch):
    """sitl's figures read link 2's truth (m2, lc = m3 / m2) from the truth log and draw it
    as a line on the estimate's axes; with no truth log, the same figures without it."""
    import json

    import matplotlib.axes

    from sitl.flight_figures import draw_with_truth, truth_lines

    out = flight_log.parent
    truth = out / "truth.jsonl"
    drawn = []
    plot = matplotlib.axes.Axes.plot

    def recorded(ax, *args, **kwargs):
        if kwargs.get("label") == "truth":
            drawn.append(args[1])
        return plot(ax, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "plot", recorded)
    paths = draw_with_truth(out)
    assert [p.name for p in paths] == ["tracking.png", "estimation.png", "arm.png"]
    assert drawn == []
    with truth.open("w") as f:
        for i in range(60):
            theta = [0.12, 0.0084, 8.8e-4] if i < 25 else [0.37, 0.0459, 6.5e-3]
            f.write(json.dumps({"t_s": 100.0 + 0.016 * i, "true_theta": theta}) + "\n")
    lines = truth_lines(truth)
    assert lines.t_s[0] == 100.0 and lines.m2_kg[-1] == 0.37
    np.testing.assert_allclose(lines.lc_m[[0, -1]], [0.07, 0.0459 / 0.37])
    paths = draw_with_truth(out)
    assert [p.name for p in paths] == ["tracking.png", "estimation.png", "arm.png"]
    assert len(drawn) == 2  # the truth within the log's time (100.0 to 100.796 s): 50 rows
    np.testing.assert_array_equal(drawn[0], lines.m2_kg[:50])
    np.testing.assert_array_equal(drawn[1], lines.lc_m[:50])


def test_the_flight_page_holds_the_outcome_figures_summary_and_events_in_one_file(tmp_path):
    """flight.html opens offline: no link to any other file or host; the figures are in it."""
    import json

    from companion.cli.flight_page import write_flight_page

    assert write_flight_page(tmp_path) is None  # no summary: no page
    summary = {"completed": False, "failure": "MissionError: payload_lost: slipped", "x": 1.5}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    (tmp_path / "estimation.png").write_bytes(b"\x89PNG\r\n\x1a\nfake")
    (tmp_path / "flight.events.csv").write_text("t_vehicle_s,kind,detail\n12.5,fault,<slip>\n")
    page = write_flight_page(tmp_path).read_text()
    assert "did not complete" in page and "payload_lost: slipped" in page
    assert "data:image/png;base64,iVBORw0KGgpmYWtl" in page
    assert "<th>x</th><td>1.5</td>" in page and "&lt;slip&gt;" in page
    assert "src='http" not in page and "href=" not in page
