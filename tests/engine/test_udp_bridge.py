"""The UDP bridge treats the network as hostile (loopback only, bounded in count and time).

Malformed poses (NaN, inf, 1e300, outside the workspace, wrong size or header) are dropped and
counted while valid ones keep being answered; a flood is survived; a second source cannot
move the proxy or receive the force stream; one packet in gives at most one reply out; what is
sent is clamped; the address and port are checked before anything is bound; and the engine
(the loop the window uses, and `skelasm simulate`) runs on through all of it.
"""

from __future__ import annotations

import json
import logging
import math
import shutil
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from engine.devices import (
    FORCE_CLAMPED,
    FORCE_PACKET,
    FORCE_TYPE,
    FORCE_V1,
    MAX_PACKETS_PER_READ,
    POSE_PACKET,
    POSE_REFUSED,
    POSE_TYPE,
    POSE_V1,
    TORQUE_CLAMPED,
    WIRE_MAGIC,
    WIRE_VERSION,
    DeviceError,
    UdpBridgeDevice,
    open_device,
)
from engine.errors import InputError
from engine.params import UDP_MAX_FORCE, UDP_MAX_TORQUE, DeviceConfig, HapticLimits

HOME = (1.0, 2.0, 3.0, 0.0, 0.0, 0.1)


def pose_v1(seq, pose, token=0):
    return POSE_V1.pack(WIRE_MAGIC, WIRE_VERSION, POSE_TYPE, 0, token, seq, *pose)


class Client:
    """A servo loop's end of the bridge: a UDP socket on loopback."""

    def __init__(self, dev):
        self.dev = dev
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))

    def send(self, packet):
        self.sock.sendto(packet, self.dev.address)

    def replies(self, wait=0.05):
        """Every datagram that arrives within ``wait`` seconds."""
        out = []
        self.sock.settimeout(wait)
        while True:
            try:
                out.append(self.sock.recv(256))
            except TimeoutError:
                return out

    def first(self, timeout=2.0):
        """The next datagram, waiting up to ``timeout`` seconds for it."""
        self.sock.settimeout(timeout)
        return self.sock.recv(256)

    def close(self):
        self.sock.close()


@pytest.fixture
def bridge():
    devices, clients = [], []

    def make(**options):
        dev = UdpBridgeDevice("127.0.0.1", 0, **options)
        dev.connect()
        devices.append(dev)
        return dev

    def client(dev):
        c = Client(dev)
        clients.append(c)
        return c

    yield make, client
    for c in clients:
        c.close()
    for dev in devices:
        dev.disconnect()


def step(dev, force=(1.0, 0.0, 0.0), torque=(0.0, 0.0, 0.1)):
    """One engine step as the loop does it: read the pose, then write the force."""
    pose = dev.read_pose(0.0)
    dev.write_force(np.asarray(force), np.asarray(torque))
    return pose


def unit(v):
    return np.asarray(v) / np.linalg.norm(v)


def force_reply(data):
    magic, version, kind, flags, token, seq, *values = FORCE_V1.unpack(data)
    assert (magic, version, kind) == (WIRE_MAGIC, WIRE_VERSION, FORCE_TYPE)
    return flags, token, seq, np.array(values)


# ---------------------------------------------------------------------------------------------
# malformed packets and floods


@pytest.mark.parametrize("bad, reason", [
    (float("nan"), "non_finite"),
    (float("inf"), "non_finite"),
    (-float("inf"), "non_finite"),
    (1e300, "workspace"),
    (1e6, "workspace"),  # finite, but 1000 km from part 1 in a millimetre scene
])
def test_malformed_pose_is_dropped_counted_and_answered_as_refused(bridge, bad, reason):
    make, client = bridge
    dev = make()
    c = client(dev)
    c.send(pose_v1(1, HOME))
    np.testing.assert_array_equal(step(dev), HOME)
    flags, _, seq, _ = force_reply(c.replies()[0])
    assert (seq, flags) == (1, 0)
    for axis in range(6):  # the bad number in every coordinate, one packet each
        pose = list(HOME)
        pose[axis] = bad
        c.send(pose_v1(2 + axis, pose))
        assert dev.read_pose(0.0) is None  # (a rotation vector of 1e6 rad is refused too)
        dev.write_force(np.ones(3), np.zeros(3))
        flags, _, seq, _ = force_reply(c.replies()[0])
        assert flags & POSE_REFUSED and seq == 1  # still the newest pose it used
    assert dev.dropped[reason] == 6 and sum(dev.dropped.values()) == 6
    assert dev.stats()["dropped_by_reason"] == {reason: 6}
    c.send(pose_v1(9, (0.5, 0.0, 0.0, 0.0, 0.0, 0.0)))  # valid again: used and answered
    np.testing.assert_array_equal(step(dev), (0.5, 0, 0, 0, 0, 0))
    flags, _, seq, _ = force_reply(c.replies()[0])
    assert (seq, flags & POSE_REFUSED) == (9, 0)


def test_wrong_size_and_foreign_headers_are_ignored(bridge, caplog):
    make, client = bridge
    dev = make()
    c = client(dev)
    wrong_header = bytearray(pose_v1(1, HOME))
    wrong_header[4] = 7  # a version this engine does not speak
    force_shaped = FORCE_V1.pack(WIRE_MAGIC, WIRE_VERSION, FORCE_TYPE, 0, 0, 1, *HOME)
    with caplog.at_level(logging.WARNING, logger="engine.devices"):
        for packet in (b"", b"x" * 55, b"y" * 57, b"z" * 200, bytes(wrong_header), force_shaped):
            c.send(packet)
        assert step(dev) is None
    assert c.replies() == []  # no peer yet: nobody to answer
    assert dev.dropped["size"] == 4 and dev.dropped["header"] == 2
    # the first of each kind is logged once
    assert sum("not the size of a pose packet" in r.message for r in caplog.records) == 1
    c.send(pose_v1(2, HOME))
    np.testing.assert_array_equal(step(dev), HOME)
    assert len(c.replies()) == 1


def test_flood_of_ten_thousand_packets_is_survived(bridge, monkeypatch):
    import engine.devices

    # a smaller bound per read than the kernel's buffer holds, so that the bound is exercised
    per_read = MAX_PACKETS_PER_READ // 8
    monkeypatch.setattr(engine.devices, "MAX_PACKETS_PER_READ", per_read)
    make, client = bridge
    dev = make()
    c = client(dev)
    c.send(pose_v1(0, HOME))
    step(dev)
    c.replies()
    t0 = time.monotonic()
    for i in range(10_000):  # valid, NaN and garbage, as fast as the socket takes them
        kind = i % 3
        c.send(pose_v1(i + 1, (i * 1e-4, 0, 0, 0, 0, 0)) if kind == 0
               else pose_v1(i + 1, (math.nan,) * 6) if kind == 1 else b"\0" * (i % 100))
    seen = 0
    for _ in range(200):  # each read takes a bounded number of packets
        before = dev.packets_in + sum(dev.dropped.values())
        step(dev)
        taken = dev.packets_in + sum(dev.dropped.values()) - before
        assert taken <= per_read
        seen += taken
        if taken == 0:
            break
    assert time.monotonic() - t0 < 30
    assert seen > per_read  # the kernel kept what its buffer holds and dropped the rest
    assert len(c.replies()) <= seen  # never more replies than packets
    c.send(pose_v1(20_000, HOME))
    np.testing.assert_array_equal(step(dev), HOME)  # and it still answers
    flags, _, seq, _ = force_reply(c.replies()[-1])
    assert seq == 20_000


# ---------------------------------------------------------------------------------------------
# one peer, one reply per packet


def test_hijacker_gets_no_replies_and_cannot_move_the_proxy(bridge):
    make, client = bridge
    dev = make()
    owner, intruder = client(dev), client(dev)
    owner.send(pose_v1(1, HOME))
    np.testing.assert_array_equal(step(dev), HOME)
    assert dev.peer == owner.sock.getsockname()
    for i in range(50):  # the intruder tries both forms, interleaved with the owner
        intruder.send(pose_v1(100 + i, (30.0, 0, 0, 0, 0, 0)))
        intruder.send(POSE_PACKET.pack(200 + i, 30.0, 0, 0, 0, 0, 0))
        owner.send(pose_v1(2 + i, HOME))
        pose = step(dev)
        assert pose is None or tuple(pose) == HOME
    assert intruder.replies(0.1) == []
    assert dev.dropped["foreign"] == 100
    owner_replies = owner.replies(0.1)
    assert len(owner_replies) == 51 and force_reply(owner_replies[-1])[2] == 51  # 1 each


def test_token_decides_who_may_become_the_peer(bridge):
    make, client = bridge
    dev = make(token=123456789)
    guess, legacy, owner = client(dev), client(dev), client(dev)
    guess.send(pose_v1(1, (9.0, 0, 0, 0, 0, 0), token=42))
    legacy.send(POSE_PACKET.pack(1, 9.0, 0, 0, 0, 0, 0))  # header-less: no token to check
    assert step(dev) is None and dev.peer is None
    owner.send(pose_v1(7, HOME, token=123456789))
    np.testing.assert_array_equal(step(dev), HOME)
    assert dev.peer == owner.sock.getsockname()
    assert dev.dropped["token"] == 1 and dev.dropped["legacy"] == 1
    _, token, seq, _ = force_reply(owner.replies()[0])
    assert (token, seq) == (123456789, 7)
    assert guess.replies() == [] and legacy.replies() == []


def test_configured_peer_is_the_only_source(bridge):
    make, client = bridge
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    host, port = probe.getsockname()
    dev = make(peer=f"{host}:{port}")
    other = client(dev)
    other.send(pose_v1(1, (9.0, 0, 0, 0, 0, 0)))  # first to send, but not the peer
    assert step(dev) is None and dev.peer is None and dev.dropped["foreign"] == 1
    probe.sendto(pose_v1(2, HOME), dev.address)
    np.testing.assert_array_equal(step(dev), HOME)
    probe.settimeout(0.5)
    assert force_reply(probe.recv(256))[2] == 2
    probe.close()


def test_one_packet_in_gives_one_reply_out(bridge):
    make, client = bridge
    dev = make()
    c = client(dev)
    c.send(pose_v1(1, HOME))
    for _ in range(1000):  # a second of engine steps after one packet
        step(dev)
    assert len(c.replies(0.2)) == 1
    for seq in range(2, 6):  # several packets in one step: one reply, for the newest
        c.send(pose_v1(seq, HOME))
    step(dev)
    step(dev)
    replies = c.replies(0.2)
    assert len(replies) == 1 and force_reply(replies[0])[2] == 5
    assert dev.packets_out == 2 and dev.packets_in == 5


def test_legacy_packet_is_answered_in_kind_when_no_token(bridge):
    make, client = bridge
    dev = make()
    c = client(dev)
    c.send(POSE_PACKET.pack(11, *HOME))
    np.testing.assert_array_equal(step(dev, (0.5, 0, 0), (0, 0, 0.25)), HOME)
    (reply,) = c.replies()
    assert len(reply) == FORCE_PACKET.size
    seq, *values = FORCE_PACKET.unpack(reply)
    assert seq == 11
    np.testing.assert_array_equal(values, [0.5, 0, 0, 0, 0, 0.25])


# ---------------------------------------------------------------------------------------------
# what is sent


@pytest.mark.parametrize("options, limits", [
    ({}, (UDP_MAX_FORCE, UDP_MAX_TORQUE)),
    ({"max_force": 2.5, "max_torque": 0.5}, (2.5, 0.5)),
    ({"max_force": "auto", "max_torque": "auto"}, (UDP_MAX_FORCE, UDP_MAX_TORQUE)),
])
def test_force_and_torque_are_clamped(bridge, options, limits):
    make, client = bridge
    dev = make(**options)
    assert (dev.capabilities.max_force, dev.capabilities.max_torque) == limits
    c = client(dev)
    for seq, (force, torque) in enumerate([
        ((-3.3e9, 0.0, 4e9), (-2.7e9, 1.0, 0.0)),  # the reply to a pose of 1e6
        ((math.nan, 0.0, 0.0), (math.inf, 0.0, 0.0)),  # never sent as such
        ((0.1, 0.2, 0.0), (0.0, 0.0, 0.01)),  # small: unchanged
    ], start=1):
        c.send(pose_v1(seq, HOME))
        step(dev, force, torque)
        flags, _, _, values = force_reply(c.replies()[0])
        assert np.all(np.isfinite(values))
        assert np.linalg.norm(values[:3]) <= limits[0] * (1 + 1e-12)
        assert np.linalg.norm(values[3:]) <= limits[1] * (1 + 1e-12)
        if seq == 1:
            assert flags == FORCE_CLAMPED | TORQUE_CLAMPED
            np.testing.assert_allclose(np.linalg.norm(values[:3]), limits[0])
            # the direction is kept
            np.testing.assert_allclose(values[:3] / limits[0], unit([-3.3, 0, 4]),
                                       rtol=1e-3)
        elif seq == 2:
            assert flags == FORCE_CLAMPED | TORQUE_CLAMPED and not np.any(values)
        else:
            assert flags == 0
            np.testing.assert_array_equal(values, [0.1, 0.2, 0, 0, 0, 0.01])


def test_udp_scene_limits_are_finite():
    # "auto" (the default) no longer resolves to infinity for a udp device
    assert HapticLimits.from_device(DeviceConfig(kind="udp")) == HapticLimits(
        max_force=UDP_MAX_FORCE, max_torque=UDP_MAX_TORQUE)
    cfg = DeviceConfig(kind="udp", max_force=40.0, options=(("max_torque", 3.0),))
    assert HapticLimits.from_device(cfg) == HapticLimits(max_force=40.0, max_torque=3.0)
    # the table's max_force reaches the device, which clamps at the same value
    dev = open_device("udp", np.zeros(6), {**dict(cfg.options), "port": 0})
    try:
        assert (dev.capabilities.max_force, dev.capabilities.max_torque) == (40.0, 3.0)
    finally:
        dev.disconnect()
    with pytest.raises(InputError, match="max_force is given twice"):
        DeviceConfig(kind="udp", max_force=40.0, options=(("max_force", 5.0),))


# ---------------------------------------------------------------------------------------------
# where it listens


@pytest.mark.parametrize("options, message", [
    ({"port": 99999}, "udp port 99999 is not a UDP port: a port is a whole number from 0 to "
                      "65535"),
    ({"port": -1}, "udp port -1 is not a UDP port"),
    ({"reply_port": 0}, "udp reply_port 0 is not a UDP port"),
    ({"host": "0.0.0.0"}, "udp host 0.0.0.0 is beyond this machine.*allow_remote = true"),
    ({"host": "192.168.1.10"}, "beyond this machine"),
    ({"host": "0.0.0.0", "allow_remote": True}, "needs a session token"),
    ({"peer": "10.0.0.2:5000"}, "udp peer 10.0.0.2:5000 is beyond this machine"),
    ({"host": "not an address"}, "is not an IPv4 address"),
    ({"token": 0}, "is not a session token"),
    ({"max_force": math.inf}, "max_force must be a positive finite number"),
    ({"workspace": -1.0}, "workspace must be a positive finite number"),
    ({"bogus": 1}, "unknown"),
])
def test_bad_address_or_option_is_refused_before_binding(options, message):
    with pytest.raises(DeviceError, match=message):
        UdpBridgeDevice(**{"port": 0, **options})
    scene_options = {"port": 0, **options}
    if "bogus" not in scene_options:  # a scene rejects unknown keys itself
        with pytest.raises(InputError, match=message):
            DeviceConfig(kind="udp", options=tuple(scene_options.items()))


def test_remote_bind_only_when_asked_and_with_a_warning(caplog):
    dev = UdpBridgeDevice("0.0.0.0", 0, allow_remote=True, token=2**62)
    with caplog.at_level(logging.WARNING, logger="engine.devices"):
        dev.connect()
    try:
        assert dev.address[0] == "0.0.0.0"
        assert any("beyond this machine" in r.message for r in caplog.records)
    finally:
        dev.disconnect()
    caplog.clear()
    quiet = UdpBridgeDevice("127.0.0.1", 0)
    with caplog.at_level(logging.WARNING, logger="engine.devices"):
        quiet.connect()
    quiet.disconnect()
    assert not caplog.records


# ---------------------------------------------------------------------------------------------
# the engine runs on


def test_engine_loop_runs_on_through_malformed_packets_and_clamps():
    """The loop the window uses: bad packets neither stop it nor reach the simulation."""
    from test_loop import make_loop

    from engine import runtime

    dev = UdpBridgeDevice("127.0.0.1", 0, timeout=5.0)
    dev.connect()
    loop, _, _ = make_loop(realtime=True, device=dev)
    c = Client(dev)
    loop.start()
    try:
        c.send(pose_v1(1, (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)))
        assert c.first()
        for seq, x in enumerate((math.nan, math.inf, 1e300, -1e300), start=2):
            c.send(pose_v1(seq, (x, 0.0, 0.0, 0.0, 0.0, 0.0)))
            flags, _, used, _ = force_reply(c.first())
            assert flags & POSE_REFUSED and used == 1
        steps = loop.sim.steps
        # 50 part lengths away: a coupling force of about 2e5, far above the clamp (much
        # farther, and the simulation's own divergence guard stops it: see docs/devices.md)
        c.send(pose_v1(9, (50.0, 0.0, 0.0, 0.0, 0.0, 0.0)))
        time.sleep(0.05)
        for seq in range(10, 40):  # keep the servo loop going: each packet answered
            c.send(pose_v1(seq, (50.0, 0.0, 0.0, 0.0, 0.0, 0.0)))
            time.sleep(0.002)
        replies = [force_reply(r) for r in c.replies(0.5)]
        assert replies and all(np.linalg.norm(v[:3]) <= UDP_MAX_FORCE * (1 + 1e-12)
                               for _, _, _, v in replies)
        assert any(flags & FORCE_CLAMPED for flags, _, _, _ in replies)
        assert loop.is_alive() and loop.sim.steps > steps
        assert np.all(np.isfinite(loop.sim.part_pose())) and loop.device is dev
    finally:
        loop.stop()
        c.close()
        dev.disconnect()
    events = loop.poll_events()
    assert not [e for e in events if isinstance(e, runtime.ErrorEvent)]
    assert dev.dropped["non_finite"] == 2 and dev.dropped["workspace"] == 2


def test_non_finite_pose_from_any_device_falls_back_instead_of_stopping():
    from test_loop import make_loop, run_until

    from engine import runtime
    from engine.devices import Device

    class Broken(Device):
        def read_pose(self, time_s):
            return np.array([math.nan, 0, 0, 0, 0, 0])

    loop, _, _ = make_loop(realtime=False, device=Broken())
    assert run_until(loop, lambda: loop.device.name == "mouse", timeout=5.0)
    loop.run(max_steps=20)  # and it steps on
    assert np.all(np.isfinite(loop.sim.part_pose()))
    lost = [e for e in loop.poll_events() if isinstance(e, runtime.DeviceEvent)]
    assert lost and "not finite" in lost[-1].message


def test_pose_out_of_the_simulations_reach_is_dropped_and_the_device_kept():
    from test_loop import make_loop

    from engine import runtime
    from engine.devices import Device

    class Far(Device):
        def read_pose(self, time_s):  # finite, but a million part lengths away
            return np.array([1e6, 0, 0, 0, 0, 0])

    loop, _, _ = make_loop(realtime=False, device=Far())
    loop.run(max_steps=50)
    assert loop.sim.steps == 50 and loop.device.name == "device"
    np.testing.assert_array_equal(loop.sim.proxy_pose, np.zeros(6))
    errors = [e for e in loop.poll_events() if isinstance(e, runtime.ErrorEvent)]
    assert len(errors) == 1 and not errors[0].fatal and "pose dropped" in errors[0].message
    assert loop.inputs.refused == 50


ROOT = Path(__file__).resolve().parents[2]
PEG = ROOT / "assets" / "peg_in_hole" / "scene.toml"


def tiny_udp_scene(tmp_path, device_table):
    for f in PEG.parent.glob("*.step"):
        shutil.copy(f, tmp_path / f.name)
    text = PEG.read_text().replace("grid = 56", "grid = 16").replace("modes = 24", "modes = 8")
    head, sep, tail = text.partition("[[part]]")
    (tmp_path / "scene.toml").write_text(head + device_table + "\n" + sep + tail)
    return tmp_path / "scene.toml"


def free_port():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_simulate_runs_on_through_a_nan_packet(tmp_path, capsys):
    """`skelasm simulate` with a udp device: NaN, inf and 1e300 packets no longer end the run."""
    from app.cli import main

    port = free_port()
    scene = tiny_udp_scene(tmp_path, f'[device]\nkind = "udp"\nport = {port}\ntimeout = 20.0\n')
    status = []
    run = threading.Thread(target=lambda: status.append(main(
        ["simulate", str(scene), "--seconds", "3", "--realtime", "--json"])))
    run.start()
    c = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    c.settimeout(0.05)
    answered = []
    try:
        deadline = time.monotonic() + 60  # scene load and descriptors, then the loop
        while not answered and time.monotonic() < deadline and run.is_alive():
            c.sendto(pose_v1(1, (0.0, 0.0, 5.0, 0.0, 0.0, 0.0)), ("127.0.0.1", port))
            try:
                answered.append(c.recv(256))
            except TimeoutError:
                pass
        assert answered, "the engine never answered"
        for seq, x in enumerate((math.nan, math.inf, 1e300), start=2):
            c.sendto(pose_v1(seq, (x, 0.0, 5.0, 0.0, 0.0, 0.0)), ("127.0.0.1", port))
            time.sleep(0.02)
            c.sendto(pose_v1(10 + seq, (0.0, 0.0, 5.0, 0.0, 0.0, 0.0)), ("127.0.0.1", port))
            time.sleep(0.02)
    finally:
        c.close()
        run.join(60)
    assert status == [0]
    result = json.loads(capsys.readouterr().out)
    assert result["device"]["dropped_by_reason"] == {"non_finite": 2, "workspace": 1}
    assert result["device"]["packets_in"] >= 4 and result["device"]["peer"].startswith("127.")
    assert any("udp: dropped 3 packet(s)" in n for n in result["notes"])
    assert np.all(np.isfinite(result["final_pose"]))
    assert result["steps"] == 3000


@pytest.mark.parametrize("table, message", [
    ('port = 99999', "udp port 99999 is not a UDP port"),
    ('host = "0.0.0.0"', "udp host 0.0.0.0 is beyond this machine"),
])
def test_simulate_refuses_a_bad_udp_table_with_exit_2(tmp_path, capsys, table, message):
    from app.cli import main

    scene = tiny_udp_scene(tmp_path, f'[device]\nkind = "udp"\n{table}\n')
    assert main(["simulate", str(scene), "--guidance", "none", "--seconds", "0.01"]) == 2
    err = capsys.readouterr().err
    assert "scene.toml:" in err  # the file and the line of its [device] table
    assert message in err and "Traceback" not in err
