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
    with pytest.raises(InputError, match="cannot open"):
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
