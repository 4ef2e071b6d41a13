"""``flight.mcap`` (companion.logs.mcap_log, sitl.truth_mcap): one virtual pickup read back with
the ``mcap`` reader, its Protobuf messages decoded by ``google.protobuf`` with the schemas the
file holds (Foxglove's as published in foxglove-sdk), against its own CSV log and truth, and
the writer on hand-made records."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import foxglove
import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.message import Message
from mcap.reader import make_reader
from test_virtual_flights import SHORT, fly
from typer.testing import CliRunner

from companion.cli.main import app
from companion.control.setpoints import AttitudeThrustSetpoint
from companion.frames import rotation_from_quaternion
from companion.logs.flightlog import CycleRecord, FlightLogError, read_flight_log
from companion.logs.mcap_log import (
    CHANNELS,
    Q_KEYS,
    SCHEMAS,
    ArmGeometry,
    FlightLogWithMcap,
    McapLogWriter,
    describe_mcap,
)
from sitl.truth_mcap import TRUTH_CHANNELS, add_truth

ALL_CHANNELS = {**CHANNELS, **TRUTH_CHANNELS}
CYCLE_TOPICS = ("/tf", "/vehicle/pose", "/state", "/desired", "/estimate", "/timing")
"""Topics with one message per cycle of a flight (every cycle of a flight has its q)."""


def as_dict(message: Message) -> dict:
    """A decoded Protobuf message as a dict of every field (zeros included); a
    ``google.protobuf.Timestamp`` as ``{"sec", "nsec"}``."""
    if message.DESCRIPTOR.full_name == "google.protobuf.Timestamp":
        return {"sec": message.seconds, "nsec": message.nanos}  # type: ignore[attr-defined]
    out: dict = {}
    for field in message.DESCRIPTOR.fields:
        value = getattr(message, field.name)
        if field.message_type is None:
            out[field.name] = value
        elif field.is_repeated:
            out[field.name] = [as_dict(v) for v in value]
        else:
            out[field.name] = as_dict(value)
    return out


_CLASSES: dict[tuple[str, bytes], type[Message]] = {}


def decode(schema_name: str, encoding: str, schema_data: bytes, data: bytes) -> dict:
    """A message decoded by its schema: JSON, or Protobuf with the ``FileDescriptorSet`` of
    its schema record."""
    if encoding == "jsonschema":
        return json.loads(data)
    assert encoding == "protobuf", encoding
    cls = _CLASSES.get((schema_name, schema_data))
    if cls is None:
        pool = descriptor_pool.DescriptorPool()
        for file in descriptor_pb2.FileDescriptorSet.FromString(schema_data).file:
            pool.Add(file)
        cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))
        _CLASSES[(schema_name, schema_data)] = cls
    return as_dict(cls.FromString(data))


def read_mcap(path: Path) -> dict[str, list]:
    """Topic -> [(schema name, schema encoding, message encoding, log time, publish time,
    decoded message)] in file order."""
    out: dict[str, list] = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        for channel in summary.channels.values():
            out.setdefault(channel.topic, [])
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert schema is not None
            out[channel.topic].append(
                (
                    schema.name,
                    schema.encoding,
                    channel.message_encoding,
                    message.log_time,
                    message.publish_time,
                    decode(schema.name, schema.encoding, schema.data, message.data),
                )
            )
    return out


def ns(t_s: float) -> int:
    return round(t_s * 1e9)


def stamp_ns(message: dict) -> int:
    """The Foxglove timestamp of a message (of its transforms' for FrameTransforms; a
    companion message has none: its log time is its time)."""
    stamps = [t["timestamp"] for t in message.get("transforms", [message])]
    values = {s["sec"] * 1_000_000_000 + s["nsec"] for s in stamps}
    assert len(values) == 1
    return values.pop()


def rot_zyx(phi: float, theta: float, psi: float) -> np.ndarray:
    """R = Rz(psi) Ry(theta) Rx(phi) (DESIGN.md section 2), written out here."""
    cx, sx = math.cos(phi), math.sin(phi)
    cy, sy = math.cos(theta), math.sin(theta)
    cz, sz = math.cos(psi), math.sin(psi)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def gripper_fk(q, geometry: ArmGeometry) -> np.ndarray:
    """End effector in the world: p + R (r_a + l1 u1 + l2 u2) (DESIGN.md section 3)."""
    x, y, z, phi, theta, psi, e1, e2 = q
    u1 = np.array([math.cos(e1), 0.0, math.sin(e1)])
    u2 = np.array([math.cos(e1 + e2), 0.0, math.sin(e1 + e2)])
    body = np.array(geometry.mount_point_m) + geometry.link1_length_m * u1
    body = body + geometry.link2_length_m * u2
    return np.array([x, y, z]) + rot_zyx(phi, theta, psi) @ body


def chain(transforms: list[dict], child: str) -> np.ndarray:
    """Position of frame ``child``'s origin in ``world`` by composing the transforms."""
    by_child = {t["child_frame_id"]: t for t in transforms}
    position = np.zeros(3)
    frame = child
    while frame != "world":
        t = by_child[frame]
        r = t["rotation"]
        rot = rotation_from_quaternion([r["w"], r["x"], r["y"], r["z"]])
        tr = t["translation"]
        position = np.array([tr["x"], tr["y"], tr["z"]]) + rot @ position
        frame = t["parent_frame_id"]
    return position


# -- one virtual pickup ------------------------------------------------------------------


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    out = tmp_path_factory.mktemp("mcap_flight")
    failure, _, truth = fly(out, SHORT, mcap=True)
    assert failure is None
    return out, read_flight_log(out / "flight.csv"), truth, read_mcap(out / "flight.mcap")


def test_two_identical_flights_give_the_same_mcap_bytes(flight, tmp_path):
    """The same flight on simulated time flown again: its flight.mcap is the same file
    (the wall-clock latencies, which differ, are in flight.timing.csv only)."""
    out, _, _, _ = flight
    failure, _, _ = fly(tmp_path / "again", SHORT, mcap=True)
    assert failure is None
    again = tmp_path / "again"
    assert (again / "flight.timing.csv").read_bytes() != (out / "flight.timing.csv").read_bytes()
    assert (again / "flight.mcap").read_bytes() == (out / "flight.mcap").read_bytes()


PUBLISHED = {
    "foxglove.FrameTransforms": foxglove.messages.FrameTransforms,
    "foxglove.PoseInFrame": foxglove.messages.PoseInFrame,
    "foxglove.Log": foxglove.messages.Log,
}
"""Foxglove's schemas as foxglove-sdk publishes them."""


def test_every_channel_is_there_with_its_schema_and_encodings(flight):
    out, _, _, mcap = flight
    assert set(mcap) == set(ALL_CHANNELS)
    for topic, name in ALL_CHANNELS.items():
        messages = mcap[topic]
        assert messages, topic
        encodings = ("jsonschema", "json") if name == "sitl.Truth" else ("protobuf", "protobuf")
        assert {(m[0], m[1], m[2]) for m in messages} == {(name, *encodings)}
    # Foxglove's schemas are the published ones, byte for byte; the companion's decode to
    # the fields their names promise (every message of the flight decoded in read_mcap).
    with open(out / "flight.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    schemas = {s.name: s.data for s in summary.schemas.values() if s.encoding == "protobuf"}
    for name, published in PUBLISHED.items():
        assert schemas[name] == published.get_schema().data == SCHEMAS[name], name
    state = mcap["/state"][0][5]
    assert list(state) == [f"{k}{s}" for s in ("", "_s") for k in Q_KEYS]
    assert list(mcap["/estimate"][0][5]) == [
        "m2_kg", "m3_kg_m", "m4_kg_m2", "lc_m", "excitation", "spread", "confident", "frozen",
        "thrust_scale",
    ]  # fmt: skip


def test_one_message_per_cycle_at_the_csv_times(flight):
    _, log, _, mcap = flight
    t = log["t_vehicle_s"]
    expected = [ns(v) for v in t]
    for topic in CYCLE_TOPICS:
        messages = mcap[topic]
        times = [m[3] for m in messages]
        assert times == expected, topic
        assert all(m[4] == m[3] for m in messages), topic
        if topic in ("/tf", "/vehicle/pose"):
            assert all(m[3] == stamp_ns(m[5]) for m in messages), topic
        assert all(b > a for a, b in itertools.pairwise(times)), topic
    sent = ~np.isnan(log["sp_roll_rad"])
    setpoints = mcap["/setpoint"]
    assert [m[3] for m in setpoints] == [ns(v) for v in t[sent]]
    assert [m[5]["roll_rad"] for m in setpoints] == list(log["sp_roll_rad"][sent])
    assert [m[5]["thrust_rel"] for m in setpoints] == list(log["thrust_rel"][sent])
    estimates = [m[5] for m in mcap["/estimate"]]
    assert [e["m2_kg"] for e in estimates] == list(log["theta_hat_m2_kg"])
    assert [e["thrust_scale"] for e in estimates] == list(log["thrust_scale_hat"])
    desired = [m[5] for m in mcap["/desired"]]
    assert [d["eta1_rad"] for d in desired] == list(log["qd_eta1_rad"])
    periods = [m[5]["loop_period_ms"] for m in mcap["/timing"]]
    csv_periods = log["loop_period_ms"]
    assert periods == pytest.approx(list(csv_periods), nan_ok=True)
    # The wall-clock latencies stay out of the file: they are in flight.timing.csv.
    for key in ("setpoint_latency_us", "cycle_latency_us", "setpoint_cpu_us"):
        assert not any(key in m[5] for m in mcap["/timing"]), key
    assert np.isfinite(log["setpoint_latency_us"]).any()


def test_events_are_log_messages_with_their_level(flight):
    _, log, _, mcap = flight
    events = mcap["/events"]
    kinds, details, times = log.events["kind"], log.events["detail"], log.events["t_vehicle_s"]
    assert len(events) == len(kinds)
    assert [m[5]["name"] for m in events] == list(kinds)
    assert [m[5]["message"] for m in events] == list(details)
    levels = {"fault": 4, "failure": 5}
    assert [m[5]["level"] for m in events] == [levels.get(k, 2) for k in kinds]
    for m, t in zip(events, times, strict=True):
        if math.isfinite(t):  # an event before the first pose has no vehicle time
            assert m[3] == ns(t)
    log_times = [m[3] for m in events]
    assert log_times == sorted(log_times)


def test_the_transforms_follow_q_and_the_arm_geometry(flight):
    _, log, _, mcap = flight
    geometry = ArmGeometry.from_config(SHORT.beliefs)
    q_columns = [c for c in log.columns if c.startswith("q_")][:8]
    q = np.column_stack([log[c] for c in q_columns])
    tf = [m[5]["transforms"] for m in mcap["/tf"]]
    poses = [m[5]["pose"] for m in mcap["/vehicle/pose"]]
    assert len(tf) == len(q)
    worst = 0.0
    for k in range(0, len(q), 7):
        frames = {t["child_frame_id"]: t for t in tf[k]}
        assert set(frames) == {"base_link", "link1", "link2", "gripper"}
        assert frames["base_link"]["parent_frame_id"] == "world"
        base = frames["base_link"]["translation"]
        assert [base["x"], base["y"], base["z"]] == list(q[k, :3])
        assert poses[k]["position"] == base
        assert poses[k]["orientation"] == frames["base_link"]["rotation"]
        r = frames["base_link"]["rotation"]
        rot = rotation_from_quaternion([r["w"], r["x"], r["y"], r["z"]])
        np.testing.assert_allclose(rot, rot_zyx(*q[k, 3:6]), atol=1e-12)
        worst = max(
            worst, float(np.linalg.norm(chain(tf[k], "gripper") - gripper_fk(q[k], geometry)))
        )
    assert worst < 1e-3


def test_the_truth_is_beside_the_estimate(flight):
    out, log, truth, mcap = flight
    truths = mcap["/truth"]
    assert len(truths) == len(truth) == len(mcap["/truth/pose"])
    assert [m[3] for m in truths] == [ns(r["t_s"]) for r in truth]
    for m, r in zip(truths[::25], truth[::25], strict=True):
        assert [m[5]["m2_kg"], m[5]["m3_kg_m"], m[5]["m4_kg_m2"]] == r["true_theta"]
        assert m[5]["payload_attached"] == r["payload_attached"]
        assert [m[5]["q"][k] for k in ("x_m", "y_m", "z_m")] == r["q"][:3]
    # One time axis: the estimate's time range lies within the truth's.
    estimate_times = [m[3] for m in mcap["/estimate"]]
    assert truths[0][3] <= estimate_times[0] and estimate_times[-1] <= truths[-1][3] + ns(0.05)
    # Carried, the estimate learnt the truth the companion never saw.
    carried = np.isin(log["phase"], ("lift", "to_place"))
    t_carried = log["t_vehicle_s"][carried][-1]
    m2_hat = log["theta_hat_m2_kg"][carried][-1]
    true_then = min(truth, key=lambda r: abs(r["t_s"] - t_carried))["true_theta"][0]
    assert m2_hat == pytest.approx(true_then, rel=0.15)
    # The whole file's messages are in log-time order (the truth merged in, not appended).
    with open(out / "flight.mcap", "rb") as f:
        times = [m.log_time for _, _, m in make_reader(f).iter_messages(log_time_order=False)]
    assert times == sorted(times)
    # The CLI describes it.
    result = CliRunner().invoke(app, ["log", "info", str(out / "flight.mcap")])
    assert result.exit_code == 0
    assert "/truth         sitl.Truth" in result.output
    assert f"{len(log)} messages" in result.output


# -- the writer on hand-made records -------------------------------------------------------

GEOMETRY = ArmGeometry((0.05, 0.0, -0.08), 0.2, 0.15)
SETPOINT = AttitudeThrustSetpoint(0.1, -0.05, 0.3, 20.0, 0.45, True, False)


def record(t: float, **parts) -> CycleRecord:
    q = np.array([1.0, 2.0, 3.0, 0.1, -0.2, 0.3, -math.pi / 2, 0.0])
    base = {
        "q": q,
        "q_dot": np.zeros(8),
        "q_ddot": np.zeros(8),
        "q_d": q,
        "theta_hat": (0.2, 0.02, 0.004),
        "setpoint": SETPOINT,
        "loop_period_ms": 4.0,
        "phase": "lift",
        "px4_mode": "OFFBOARD",
    }
    return CycleRecord(t_vehicle_s=t, **{**base, **parts})


def test_the_writer_writes_what_it_is_given_and_nan_for_what_is_missing(tmp_path):
    with FlightLogWithMcap(tmp_path / "flight.csv", GEOMETRY) as log:
        log.write(record(1.0))
        log.write(record(1.004, q=None, setpoint=None, theta_hat=None, loop_period_ms=None))
        log.write(record(1.008, q=[math.nan] * 8, setpoint_latency_us=250.0))
        log.event("failure", "the link was lost", 1.01)
        log.write(record(1.012, faults=("payload_lost",)))
    mcap = read_mcap(tmp_path / "flight.mcap")
    assert [m[3] for m in mcap["/tf"]] == [ns(1.0), ns(1.012)]
    assert [m[3] for m in mcap["/setpoint"]] == [ns(1.0), ns(1.008), ns(1.012)]
    assert len(mcap["/estimate"]) == len(mcap["/state"]) == len(mcap["/timing"]) == 4
    missing = mcap["/estimate"][1][5]
    assert math.isnan(missing["m2_kg"]) and math.isnan(missing["lc_m"])
    assert mcap["/estimate"][0][5]["lc_m"] == pytest.approx(0.1)
    assert math.isnan(mcap["/state"][2][5]["x_m"])
    assert math.isnan(mcap["/timing"][1][5]["loop_period_ms"])
    assert list(mcap["/timing"][2][5]) == ["loop_period_ms"]  # wall clock: timing.csv's
    sp = mcap["/setpoint"][0][5]
    assert (sp["roll_rad"], sp["thrust_n"], sp["tilt_saturated"]) == (0.1, 20.0, 1.0)
    # The events the CSV writer derives go to the MCAP too, with their level.
    events = [(m[5]["name"], m[5]["message"], m[5]["level"]) for m in mcap["/events"]]
    assert events == [
        ("mode", "->OFFBOARD", 2),
        ("phase", "->lift", 2),
        ("failure", "the link was lost", 5),
        ("fault", "payload_lost", 4),
    ]
    assert len(read_flight_log(tmp_path / "flight.csv").events["kind"]) == len(events)


def test_the_arm_points_where_its_angles_say(tmp_path):
    down = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -math.pi / 2, 0.0]  # straight down
    q = [0.5, -0.5, 1.0, 0.2, -0.1, 1.2, -0.7, 0.4]
    with FlightLogWithMcap(tmp_path / "flight.csv", GEOMETRY) as log:
        log.write(record(1.0, q=np.array(down)))
        log.write(record(1.004, q=np.array(q)))
    tf = [m[5]["transforms"] for m in read_mcap(tmp_path / "flight.mcap")["/tf"]]
    np.testing.assert_allclose(chain(tf[0], "gripper"), [0.05, 0.0, 1.0 - 0.08 - 0.35], atol=1e-12)
    np.testing.assert_allclose(chain(tf[1], "gripper"), gripper_fk(q, GEOMETRY), atol=1e-12)


def test_events_before_the_first_pose_take_the_last_time_and_bad_times_are_refused(tmp_path):
    with FlightLogWithMcap(tmp_path / "a.csv", GEOMETRY) as log:
        log.event("preflight", "waiting", math.nan)
        log.write(record(2.0))
        log.event("loop", "late", math.nan)
        with pytest.raises(FlightLogError, match="not a time since boot"):
            log.write(record(-1.0))
    mcap = read_mcap(tmp_path / "a.mcap")
    times = [m[3] for m in mcap["/events"] if m[5]["name"] in ("preflight", "loop")]
    assert times == [0, ns(2.0)]
    assert [m[3] for m in mcap["/state"]] == [ns(2.0)]  # the refused row is left out


def test_a_log_is_never_overwritten_and_opens_once(tmp_path):
    (tmp_path / "flight.mcap").write_bytes(b"earlier")
    with pytest.raises(FlightLogError, match="never overwritten"):
        FlightLogWithMcap(tmp_path / "flight.csv", GEOMETRY).open()
    assert not (tmp_path / "flight.csv").exists()
    assert (tmp_path / "flight.mcap").read_bytes() == b"earlier"
    writer = McapLogWriter(tmp_path / "b.mcap", GEOMETRY)
    writer.open()
    with pytest.raises(FlightLogError, match="opens once"):
        writer.open()
    writer.close()
    writer.close()
    with pytest.raises(FlightLogError, match="not open"):
        writer.event("note", "after the close", 1.0)


def test_a_failure_of_the_writer_thread_is_raised_by_the_close(tmp_path, monkeypatch):
    def full_disk(*args):
        raise OSError("No space left on device")

    monkeypatch.setattr("companion.logs.mcap_log.encode_block", full_disk)
    writer = McapLogWriter(tmp_path / "flight.mcap", GEOMETRY)
    writer.open()
    writer.write_block(np.zeros((1, 1)))  # the writer thread fails on it
    with pytest.raises(FlightLogError, match="No space left"):
        writer.close()


def test_info_counts_a_file_cut_by_a_crash_and_refuses_what_is_not_mcap(tmp_path):
    path = tmp_path / "flight.mcap"
    with FlightLogWithMcap(tmp_path / "flight.csv", GEOMETRY) as log:
        for k in range(2000):
            log.write(record(1.0 + 0.004 * k))
    whole = describe_mcap(path)
    assert {c.topic: c.messages for c in whole.channels}["/tf"] == 2000
    assert whole.start_ns == ns(1.0) and whole.end_ns == ns(1.0 + 0.004 * 1999)
    assert whole.warnings == ()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    info = describe_mcap(cut)
    counts = {c.topic: c.messages for c in info.channels}
    assert 0 < counts["/tf"] < 2000 and set(counts) == set(CHANNELS)
    assert info.warnings and "cut short" in info.warnings[0]
    (tmp_path / "x.mcap").write_text("t_vehicle_s,q_x_m\n")
    with pytest.raises(FlightLogError, match="not an MCAP file"):
        describe_mcap(tmp_path / "x.mcap")
    result = CliRunner().invoke(app, ["log", "info", str(tmp_path / "x.mcap")])
    assert result.exit_code == 2


def test_the_truth_merges_in_time_order_once(tmp_path):
    path = tmp_path / "flight.mcap"
    with FlightLogWithMcap(tmp_path / "flight.csv", GEOMETRY) as log:
        for k in range(10):
            log.write(record(1.0 + 0.004 * k))
    q = [1.0, 2.0, 3.0, 0.0, 0.0, 0.0, -1.5, 0.0]
    lines = [
        {"t_s": 1.0 + 0.01 * k, "q": q, "true_theta": [0.5, 0.08, 0.0128], "payload_attached": True}
        for k in range(5)
    ]
    truth = tmp_path / "truth.jsonl"
    truth.write_text("".join(json.dumps(r) + "\n" for r in lines) + '{"t_s": 1.0')  # cut line
    assert add_truth(path, truth) == 10
    mcap = read_mcap(path)
    assert len(mcap["/tf"]) == 10 and len(mcap["/truth"]) == 5 == len(mcap["/truth/pose"])
    assert mcap["/truth"][0][5]["lc_m"] == pytest.approx(0.16)
    with open(path, "rb") as f:
        times = [m.log_time for _, _, m in make_reader(f).iter_messages(log_time_order=False)]
    assert times == sorted(times)
    with pytest.raises(ValueError, match="holds /truth, /truth/pose already"):
        add_truth(path, truth)
    assert not (tmp_path / "flight.mcap.tmp").exists()


def test_a_ulog_that_cannot_be_read_is_one_line(tmp_path, run_cli):
    """``companion log add-ulog``: a missing or corrupt ULog is one ``error:`` line and
    status 2, and the flight log is left as it was."""
    from companion.logs.ulog_mcap import UlogError, add_ulog

    mcap = tmp_path / "flight.mcap"
    mcap.write_bytes(b"not read before the ULog")
    garbage = tmp_path / "bad.ulg"
    garbage.write_bytes(b"ULog\x01\x12\x35" + bytes(range(256)) * 4)
    for ulog, says in ((tmp_path / "none.ulg", "No such file"), (garbage, "not a readable ULog")):
        with pytest.raises(UlogError, match=says):
            add_ulog(mcap, ulog)
        done = run_cli("log", "add-ulog", str(mcap), str(ulog))
        assert done.returncode == 2, done.stdout + done.stderr
        lines = [line for line in done.stderr.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith("error:") and says in lines[0], lines
    assert mcap.read_bytes() == b"not read before the ULog"
    # A flight log that is no MCAP: one line too.
    from companion.logs.mcap_log import merge_messages

    with pytest.raises(ValueError, match="not a readable MCAP log"):
        merge_messages(mcap, {}, [])
