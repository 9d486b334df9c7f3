"""Input devices: trajectory CSV, mouse, UDP bridge on loopback, absent devices' messages."""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest

from engine.devices import (
    FORCE_PACKET,
    POSE_PACKET,
    DeviceError,
    MouseDevice,
    OpenHapticsDevice,
    SpaceMouseDevice,
    TrajectoryDevice,
    UdpBridgeDevice,
    open_device,
    read_trajectory,
)
from engine.errors import InputError


def write(tmp_path, text, name="traj.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_trajectory_interpolates_and_holds(tmp_path):
    p = write(tmp_path, "t,tx,ty,tz,rx,ry,rz\n0,0,0,0,0,0,0\n1,2,4,6,0.1,0.2,0.3\n2,2,4,0,0,0,0\n")
    dev = TrajectoryDevice(p)
    np.testing.assert_allclose(dev.read_pose(0.25), [0.5, 1, 1.5, 0.025, 0.05, 0.075])
    np.testing.assert_allclose(dev.read_pose(1.5), [2, 4, 3, 0.05, 0.1, 0.15])
    np.testing.assert_allclose(dev.read_pose(7.0), [2, 4, 0, 0, 0, 0])  # held
    np.testing.assert_allclose(dev.read_pose(-1.0), [0, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(dev.read_pose(1.0), [2, 4, 6, 0.1, 0.2, 0.3])


def test_trajectory_columns_in_any_order_and_extra_columns(tmp_path):
    p = write(tmp_path, "rz,t,extra,tx,ty,tz,rx,ry\n0.5,0,9,1,2,3,0,0\n")
    np.testing.assert_allclose(read_trajectory(p), [[0, 1, 2, 3, 0, 0, 0.5]])


@pytest.mark.parametrize(
    "text,match",
    [
        ("t,tx,ty\n0,1,2\n", "lacks column"),
        ("t,tx,ty,tz,rx,ry,rz\n0,0,0,0,0,0,0\n0,1,1,1,0,0,0\n", ":3: times must increase"),
        ("t,tx,ty,tz,rx,ry,rz\n0,0,0,zero,0,0,0\n", ":2: expected numbers"),
        ("", "empty"),
    ],
)
def test_bad_trajectory_messages(tmp_path, text, match):
    with pytest.raises(InputError, match=match):
        read_trajectory(write(tmp_path, text))


def test_missing_trajectory_file(tmp_path):
    with pytest.raises(InputError, match="no such trajectory file"):
        read_trajectory(tmp_path / "nope.csv")
    with pytest.raises(DeviceError, match="trajectory"):
        open_device("trajectory", np.zeros(6), {"file": "nope.csv"}, tmp_path)


def test_mouse_reports_only_new_poses():
    m = MouseDevice()
    assert m.read_pose(0.0) is None
    m.set_pose([1, 2, 3, 0, 0, 0])
    np.testing.assert_allclose(m.read_pose(0.0), [1, 2, 3, 0, 0, 0])
    assert m.read_pose(0.001) is None
    with pytest.raises(ValueError):
        m.set_pose([np.nan] * 6)


def test_absent_devices_say_what_to_do():
    # neither pyspacemouse nor pyOpenHaptics is installed here (or no device is plugged in)
    for dev in (SpaceMouseDevice(np.zeros(6)), OpenHapticsDevice(np.zeros(6))):
        with pytest.raises(DeviceError) as err:
            dev.connect()
        msg = str(err.value)
        assert msg.startswith(dev.name) and ("install" in msg or "plug" in msg)
    with pytest.raises(ValueError, match="valid: mouse"):
        open_device("joystick", np.zeros(6))


def test_udp_bridge_on_loopback():
    dev = UdpBridgeDevice("127.0.0.1", 0, timeout=0.2)
    dev.connect()
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client.settimeout(1.0)
    try:
        assert dev.read_pose(0.0) is None  # nothing sent yet: not lost either
        client.sendto(POSE_PACKET.pack(1, 1, 2, 3, 0, 0, 0), dev.address)
        client.sendto(POSE_PACKET.pack(2, 4, 5, 6, 0.1, 0, 0), dev.address)
        time.sleep(0.02)
        np.testing.assert_allclose(dev.read_pose(0.0), [4, 5, 6, 0.1, 0, 0])  # newest wins
        dev.write_force(np.array([1.0, -2.0, 3.0]), np.array([0.0, 0.5, 0.0]))
        seq, *values = FORCE_PACKET.unpack(client.recv(256))
        assert seq == 2
        np.testing.assert_allclose(values, [1, -2, 3, 0, 0.5, 0])
        time.sleep(0.3)
        with pytest.raises(DeviceError, match="no pose packet"):
            dev.read_pose(0.1)
    finally:
        client.close()
        dev.disconnect()


def test_udp_port_in_use_is_a_device_error():
    a = UdpBridgeDevice("127.0.0.1", 0)
    a.connect()
    try:
        b = UdpBridgeDevice("127.0.0.1", a.address[1])
        with pytest.raises(DeviceError, match="cannot listen"):
            b.connect()
    finally:
        a.disconnect()


# --------------------------------------------------------------------------------------------
# OpenHaptics and the 3D mouse through stand-ins of their libraries (tests/engine/fake_device_libs)


def _wait(pred, timeout=2.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.002)
    return pred()


def test_openhaptics_maps_the_stylus_and_renders_force_in_the_servo_loop(monkeypatch):
    from fake_device_libs import FakeTouch, install_openhaptics

    from engine.pose import rotation_matrix, rotation_vector

    touch = FakeTouch()
    install_openhaptics(monkeypatch, touch)
    touch.move((10.0, 20.0, 30.0))  # the stylus where it rests when the session starts
    start = np.array([1.0, 2.0, 3.0, 0.0, 0.2, 0.0])
    dev = open_device("openhaptics", start, {"name": "Touch"})
    try:
        np.testing.assert_allclose(dev.read_pose(0.0), start, atol=1e-12)  # p0 = rest
        turn = rotation_matrix(np.array([0.0, 0.0, 0.1]))
        touch.move((12.0, 19.0, 30.5), turn)
        time.sleep(0.01)  # a few servo ticks
        pose = dev.read_pose(0.01)
        np.testing.assert_allclose(pose[:3], [3.0, 1.0, 3.5], atol=1e-12)
        expected = rotation_vector(turn @ rotation_matrix(start[3:]))
        np.testing.assert_allclose(pose[3:], expected, atol=1e-12)
        # force goes out from inside the servo callback (the fake refuses it elsewhere)
        dev.write_force(np.array([0.5, -1.0, 2.0]), np.zeros(3))
        assert _wait(lambda: touch.forces and touch.forces[-1] == [0.5, -1.0, 2.0])
        with pytest.raises(DeviceError, match="non-finite"):
            dev.write_force(np.array([np.nan, 0.0, 0.0]), np.zeros(3))
        # the cable is pulled: the servo loop stops, and the device says so
        touch.unplugged = True
        time.sleep(dev.stale_after + 0.05)
        with pytest.raises(DeviceError, match="no data from 'Touch'.*reconnect"):
            dev.read_pose(1.0)
    finally:
        dev.disconnect()
    assert touch.closed


@pytest.mark.parametrize("trouble, message", [
    ({"fail_open": True}, "could not open 'Default Device'.*cable"),
    ({"sends": False}, "sent no data within 1 s"),
])
def test_openhaptics_open_failures_say_what_to_do(monkeypatch, trouble, message):
    from fake_device_libs import FakeTouch, install_openhaptics

    install_openhaptics(monkeypatch, FakeTouch(**trouble))
    with pytest.raises(DeviceError, match=message):
        OpenHapticsDevice(np.zeros(6)).connect()


def test_spacemouse_is_rate_control_and_reports_unplugging(monkeypatch):
    from fake_device_libs import FakeSpaceMouse, install_spacemouse

    mouse = FakeSpaceMouse()
    install_spacemouse(monkeypatch, mouse)
    start = np.array([0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    dev = open_device("spacemouse", start,
                      {"translation_speed": 20.0, "rotation_speed": 0.5})
    np.testing.assert_allclose(dev.read_pose(0.0), start)  # the first read sets the clock
    mouse.deflect(x=0.5, z=-1.0, yaw=1.0)
    for k in range(1, 101):  # 0.1 s at 1 kHz
        pose = dev.read_pose(k * 0.001)
    np.testing.assert_allclose(pose, [1.0, 0.0, 3.0, 0.0, 0.0, 0.05], atol=1e-9)
    mouse.deflect()
    np.testing.assert_allclose(dev.read_pose(0.2), pose)  # released: the proxy stays
    mouse.unplugged = True
    with pytest.raises(DeviceError, match="spacemouse: the device stopped answering"):
        dev.read_pose(0.3)
    dev.disconnect()
    assert mouse.closed
    install_spacemouse(monkeypatch, FakeSpaceMouse(present=False))
    with pytest.raises(DeviceError, match="no 3D mouse found"):
        SpaceMouseDevice(np.zeros(6)).connect()


def test_engine_renders_coupling_force_to_openhaptics_and_falls_back_when_unplugged(
        monkeypatch):
    from fake_device_libs import FakeTouch, install_openhaptics
    from test_loop import make_loop

    from engine import runtime

    touch = FakeTouch()
    install_openhaptics(monkeypatch, touch)
    loop, _, _ = make_loop(realtime=True, device=open_device("openhaptics", np.zeros(6)))
    touch.move((0.3, 0.0, 0.0))  # pull the proxy 0.3 along x: the spring pulls the part
    loop.start()
    try:
        assert _wait(lambda: touch.forces and abs(touch.forces[-1][0]) > 1e-3, timeout=10.0)
        assert touch.forces[-1][0] < 0  # the user feels the part holding back
        assert np.linalg.norm(touch.forces[-1]) <= OpenHapticsDevice.capabilities.max_force + 1e-9
        touch.unplugged = True
        assert _wait(lambda: loop.device.name == "mouse", timeout=10.0)
        steps = loop.sim.steps
        assert _wait(lambda: loop.sim.steps > steps + 10, timeout=10.0)  # and runs on
    finally:
        loop.stop()
    lost = [e for e in loop.poll_events() if isinstance(e, runtime.DeviceEvent)]
    assert lost and lost[-1].fallback == "mouse" and "openhaptics" in lost[-1].message


def test_a_trajectory_with_a_byte_order_mark_reads(tmp_path):
    # spreadsheet programs save CSV as UTF-8 with a BOM; it used to read as part of the
    # first column's name ("header lacks column t")
    from engine.devices import read_trajectory

    path = tmp_path / "bom.csv"
    path.write_bytes("\ufefft,tx,ty,tz,rx,ry,rz\n0,1,2,3,0,0,0\n1,1,2,4,0,0,0\n".encode())
    rows = read_trajectory(path)
    assert rows.shape == (2, 7) and rows[1, 3] == 4.0
