"""The UDP MAVLink endpoint of the simulated PX4 against a pymavlink peer on loopback."""

import os
import random
import socket
import time

os.environ.setdefault("MAVLINK20", "1")

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as M

from bytelink.memory import attach, create_channel
from sitl.px4 import MavlinkEndpoint, SigningKeyError, load_signing_key
from sitl.px4.endpoint import odometry_frame

KEY = bytes(range(32))


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def poll(endpoint, predicate=bool, timeout=5.0):
    """Receive until ``predicate(all messages so far)`` or the timeout (wall clock)."""
    got = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        got += endpoint.receive()
        if predicate(got):
            break
        time.sleep(0.005)
    return got


@pytest.fixture
def pair():
    """(vehicle endpoint, pymavlink GCS listening where the endpoint sends)."""
    peer_port = free_port()
    peer = mavutil.mavlink_connection(f"udpin:127.0.0.1:{peer_port}", source_system=255)
    endpoint = MavlinkEndpoint(0, peer_port)
    endpoint.open()
    yield endpoint, peer
    endpoint.close()
    peer.close()


def heartbeat():
    return M.MAVLink_heartbeat_message(13, 12, 1, 0, 3, 3)


def raw_sender(endpoint):
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.connect(endpoint.local_address)
    return s


def test_nothing_is_opened_before_open_and_close_is_idempotent():
    endpoint = MavlinkEndpoint(0, 1)
    assert not endpoint.is_open
    with pytest.raises(RuntimeError):
        endpoint.receive()
    endpoint.open()
    endpoint.open()
    endpoint.close()
    endpoint.close()
    assert not endpoint.is_open


def test_heartbeat_reaches_the_peer_and_commands_come_back(pair):
    endpoint, peer = pair
    endpoint.send(heartbeat())
    hb = peer.recv_match(type="HEARTBEAT", blocking=True, timeout=5)
    assert hb is not None and hb.get_srcSystem() == 1 and hb.get_srcComponent() == 1
    assert peer.mavlink20()
    peer.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
    (cmd,) = poll(endpoint)
    assert (cmd.get_type(), cmd.command, cmd.get_srcSystem()) == ("COMMAND_LONG", 400, 255)
    assert endpoint.counters["received"] == 1


def test_remote_moves_to_a_client_on_another_port():
    endpoint = MavlinkEndpoint(0, free_port())
    with endpoint:
        client = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{endpoint.local_address[1]}", source_system=255
        )
        client.mav.heartbeat_send(6, 8, 0, 0, 0)
        assert poll(endpoint)
        endpoint.send(heartbeat())
        assert client.recv_match(type="HEARTBEAT", blocking=True, timeout=5) is not None
        client.close()


def frame(msg, mav=None):
    return bytearray(msg.pack(mav or M.MAVLink(None, 255, 190)))


def test_garbage_truncated_bad_crc_and_unknown_ids_are_counted_and_dropped(pair):
    endpoint, _ = pair
    rng = random.Random(5)
    sender = raw_sender(endpoint)
    good = frame(M.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
    bad_crc = bytearray(good)
    bad_crc[-1] ^= 0xFF
    unknown = bytearray(good)
    unknown[7:10] = (9999).to_bytes(3, "little")
    datagrams = [
        bytes([0x00, 0x01, 0x02, 0x42]),  # no start marker
        bytes(good[:15]),  # truncated
        bytes(bad_crc),
        bytes(unknown),
        bytes(rng.getrandbits(8) for _ in range(300)),
        b"",
    ]
    for data in datagrams:
        sender.send(data)
    sender.send(bytes(good))
    got = poll(endpoint, lambda msgs: any(m.get_type() == "COMMAND_LONG" for m in msgs))
    assert [m.get_type() for m in got] == ["COMMAND_LONG"]
    c = endpoint.counters
    assert c["garbage"] >= 1 and c["truncated"] >= 1 and c["bad_crc"] == 1
    assert c["unknown_id"] == 1
    sender.close()


def test_ten_thousand_random_and_mutated_frames_never_raise(pair):
    endpoint, _ = pair
    rng = random.Random(7)
    sender = raw_sender(endpoint)
    good = frame(M.MAVLink_set_attitude_target_message(0, 1, 1, 7, [1, 0, 0, 0], 0, 0, 0, 0.5))
    sent = 0
    for i in range(10_000):
        data = bytearray(good)
        for _ in range(rng.randint(1, 4)):
            data[rng.randrange(len(data))] = rng.getrandbits(8)
        if i % 3 == 0:
            data = data[: rng.randrange(len(data))]
        if i % 5 == 0:
            data = bytearray(rng.getrandbits(8) for _ in range(rng.randrange(1, 120)))
        sender.send(bytes(data))
        sent += 1
        if sent % 200 == 0:
            endpoint.receive()
    poll(endpoint, timeout=0.5)
    sender.send(bytes(good))
    assert any(m.get_type() == "SET_ATTITUDE_TARGET" for m in poll(endpoint))
    assert endpoint.counters["datagrams"] >= 9_000  # loopback may drop a few under load
    sender.close()


def test_signed_link_accepts_only_correctly_signed_frames(tmp_path):
    key_file = tmp_path / "key"
    key_file.write_text(KEY.hex())
    assert load_signing_key(key_file) == KEY
    peer_port = free_port()
    peer = mavutil.mavlink_connection(f"udpin:127.0.0.1:{peer_port}", source_system=255)
    peer.setup_signing(KEY, sign_outgoing=True)
    with MavlinkEndpoint(0, peer_port, signing_key=load_signing_key(key_file)) as endpoint:
        endpoint.send(heartbeat())
        hb = peer.recv_match(type="HEARTBEAT", blocking=True, timeout=5)
        assert hb is not None and hb._signed
        peer.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
        assert [m.command for m in poll(endpoint)] == [400]

        sender = raw_sender(endpoint)
        sender.send(bytes(frame(heartbeat())))  # unsigned
        wrong = M.MAVLink(None, 255, 190)
        wrong.signing.secret_key = bytes(32)
        wrong.signing.sign_outgoing = True
        wrong.signing.timestamp = 10**12
        sender.send(bytes(frame(heartbeat(), wrong)))
        assert poll(endpoint, timeout=0.5) == []
        assert endpoint.counters["unsigned"] == 1
        assert endpoint.counters["bad_signature"] == 1
        sender.close()
    peer.close()


def test_bad_key_files_are_refused(tmp_path):
    bad = tmp_path / "bad"
    bad.write_text("not a key")
    with pytest.raises(SigningKeyError):
        load_signing_key(bad)
    raw = tmp_path / "raw"
    raw.write_bytes(KEY)
    assert load_signing_key(raw) == KEY


def test_send_without_listener_is_counted_not_raised():
    with MavlinkEndpoint(0, free_port()) as endpoint:
        for _ in range(5):
            endpoint.send(heartbeat())
            endpoint.receive()
        assert endpoint.counters["sent"] + endpoint.counters["send_error"] == 5


def test_an_in_memory_end_is_heard_once_a_client_attaches_and_udp_always():
    with create_channel("endpoint-heard") as channel:
        with MavlinkEndpoint(0, 0, port=channel.server) as endpoint:
            assert not endpoint.heard
            endpoint.send(heartbeat())
            assert endpoint.counters["unheard"] == 1 and not channel.client.readable
            attach("endpoint-heard")
            assert endpoint.heard
            endpoint.send(heartbeat())
            assert endpoint.counters["sent"] == 1 and channel.client.readable
    with MavlinkEndpoint(0, free_port()) as udp:
        assert udp.heard


def random_odometry(rng: random.Random):
    def value():
        return rng.choice([0.0, -0.0, 1.0, rng.uniform(-1e3, 1e3), rng.gauss(0.0, 1e-6)])

    def covariance():
        return rng.choice([[0.0] * 21, [value() for _ in range(21)], [*[value()] * 20, 0.0]])

    return M.MAVLink_odometry_message(
        rng.choice([0, rng.randrange(2**64)]), rng.randrange(256), rng.randrange(256),
        *(value() for _ in range(3)), [value() for _ in range(4)],
        *(value() for _ in range(6)), covariance(), covariance(),
        rng.choice([0, rng.randrange(256)]), rng.choice([0, rng.randrange(256)]),
        rng.choice([0, rng.randrange(-128, 128)]),
    )  # fmt: skip


def test_the_odometry_frame_is_pymavlinks_byte_for_byte():
    rng = random.Random(7)
    for _ in range(5000):
        msg = random_odometry(rng)
        mav = M.MAVLink(None, rng.randrange(256), rng.randrange(256))
        mav.seq = rng.randrange(256)
        assert odometry_frame(msg, mav) == msg.pack(mav)
    zeros = M.MAVLink_odometry_message(0, 0, 0, 0.0, 0.0, 0.0, [0.0] * 4, *[0.0] * 6,
                                       [0.0] * 21, [0.0] * 21, 0, 0, 0)  # fmt: skip
    assert odometry_frame(zeros, M.MAVLink(None, 1, 1)) == zeros.pack(M.MAVLink(None, 1, 1))


def test_the_endpoint_sends_odometry_as_pymavlink_packs_it_signed_or_not():
    for key in (None, KEY):
        with create_channel("endpoint-odometry") as channel:
            with MavlinkEndpoint(0, 0, port=channel.server, signing_key=key) as endpoint:
                client = attach("endpoint-odometry")
                reader = M.MAVLink(None, 255, 190)
                reader.signing.secret_key = key
                mirror = M.MAVLink(None, 1, 1)
                rng = random.Random(3)
                for seq in range(300):
                    sent = random_odometry(rng)
                    endpoint.send(sent)
                    data = client.receive()
                    received = reader.parse_char(data)
                    assert received.get_type() == "ODOMETRY" and received.get_seq() == seq % 256
                    if key is None:
                        mirror.seq = seq % 256
                        assert data == sent.pack(mirror)
                    else:
                        assert received.get_signed() and len(data) == len(sent.get_msgbuf())
