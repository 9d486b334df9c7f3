"""The loop's input device.

Reading the proxy pose, rendering the force, falling back to the mouse when a device goes
away, and switching devices on command.

Data: proxy poses (6,) float64 relative to part 1; forces and torques (3,) float64 in part
1's frame, already scaled and clamped by the simulation's haptic limits.
"""

from __future__ import annotations

import collections
from dataclasses import replace
from pathlib import Path

import numpy as np

from engine.devices import Device, DeviceError, MouseDevice, TrajectoryDevice, open_device
from engine.runtime.frames import encode_device_name
from engine.runtime.messages import DeviceEvent, ErrorEvent, Event, SetDevice
from engine.sim import Simulation
from engine.sim.guard import (
    MAX_PROXY_STEP_LENGTHS,
    MAX_PROXY_STEP_RADIANS,
    check_proxy_pose,
    limit_proxy_step,
)

__all__ = ["DeviceSlot"]


class DeviceSlot:
    """The device driving a simulation's proxy (owned by the loop thread).

    Parameters
    ----------
    sim : Simulation
    device : Device, optional
        Default: a :class:`MouseDevice` at the proxy's pose.
    events : deque
        Where device events go.
    base_dir : Path, optional
        Relative device files (trajectories) are found from here.
    """

    def __init__(self, sim: Simulation, device: Device | None,
                 events: collections.deque[Event], base_dir: Path | None = None):
        self.sim = sim
        self.events = events
        self.base_dir = base_dir
        self.limits = sim.limits  # the scene's limits, before any device's clamp
        self.device: Device = device or MouseDevice(sim.proxy_pose)
        self._use(self.device)

    def _use(self, device: Device) -> None:
        self.device = device
        self.refused = 0  # poses of this device the simulation refused (out of reach)
        # the proxy follows a device other than the mouse and a scripted trajectory (both
        # the user's own, replayed exactly) at a bounded pace: see limit_proxy_step
        self.paced = not isinstance(device, (MouseDevice, TrajectoryDevice))
        self.target: np.ndarray | None = None  # where a paced proxy is still going
        self.jumped = False
        self.mouse = device if isinstance(device, MouseDevice) else None
        self.name_code = encode_device_name(device.name)
        # clamp the rendered force to the device's maximum unless the scene set a lower one
        caps = device.capabilities
        self.sim.limits = replace(
            self.limits,
            max_force=min(self.limits.max_force, caps.max_force),
            max_torque=min(self.limits.max_torque, caps.max_torque),
        )

    @property
    def name(self) -> str:
        """The device's name."""
        return self.device.name

    def read(self) -> None:
        """Move the proxy to the device's pose (if it moved); a lost device falls back."""
        try:
            pose = self.device.read_pose(self.sim.time)
        except DeviceError as exc:
            self._fall_back(str(exc))
            return
        except Exception as exc:  # noqa: BLE001 -- a driver's failure must not stop the loop
            self._fall_back(f"{self.device.name}: {exc}")
            return
        if self.paced:  # a jump of a device's pose is followed at a bounded pace
            if pose is not None:
                try:  # a target out of reach is refused whole, not approached
                    self.target = check_proxy_pose(pose, self.sim.physics.length)
                except ValueError as exc:
                    self.target = None
                    self._refuse(pose, exc)
                    return
            if self.target is None:
                return
            pose, short = limit_proxy_step(self.sim.proxy_pose, self.target,
                                           self.sim.physics.length)
            if not short:
                self.target = None
            elif not self.jumped and self._big_jump():
                self.jumped = True
                name = self.device.name
                gap = float(np.linalg.norm(self.target[:3] - self.sim.proxy_pose[:3]))
                self.events.append(DeviceEvent(name, True, (
                    f"{name}'s pose jumped {gap:.4g} ({gap / self.sim.physics.length:.3g} "
                    "part lengths) in one reading; the proxy follows it at most "
                    f"{MAX_PROXY_STEP_LENGTHS:g} part lengths and {MAX_PROXY_STEP_RADIANS:g} "
                    "rad per step (later jumps are followed without a message)"), name))
        if pose is None:
            return
        try:
            self.sim.set_proxy(pose)
        except ValueError as exc:  # a device's pose must not stop the loop
            self.target = None
            self._refuse(pose, exc)

    def _big_jump(self) -> bool:
        """Whether the paced target is more than a part length or half a radian away."""
        assert self.target is not None
        gap = self.target - self.sim.proxy_pose
        return bool(np.linalg.norm(gap[:3]) > self.sim.physics.length
                    or np.linalg.norm(gap[3:]) > 0.5)

    def _refuse(self, pose: np.ndarray, exc: ValueError) -> None:
        """Handle a pose the simulation refused; the loop goes on either way.

        A pose that is not finite means a broken driver: the mouse takes over. A pose out of
        reach is dropped, reported once (non-fatal), and the device kept.
        """
        if not np.all(np.isfinite(pose)):
            self._fall_back(f"{self.device.name}: sent a pose that is not finite "
                            f"({np.asarray(pose).tolist()})")
            return
        self.refused += 1
        if self.refused == 1:
            self.events.append(ErrorEvent(f"{self.device.name}: pose dropped ({exc}); later "
                                          "ones are dropped without a message", "InputError"))

    def write(self) -> None:
        """Render the simulation's haptic force (devices with force feedback)."""
        if not self.device.capabilities.force_feedback:
            return
        try:
            self.device.write_force(self.sim.haptic_force, self.sim.haptic_torque)
        except Exception as exc:  # noqa: BLE001 -- as in read
            self._fall_back(str(exc))

    def release(self) -> None:
        """Send zero force (the loop ends)."""
        try:
            self.device.write_force(np.zeros(3), np.zeros(3))
        except Exception:  # noqa: BLE001 -- it may be gone already
            pass

    def set_proxy(self, pose: tuple[float, ...]) -> None:
        """A proxy pose from the GUI.

        It is the mouse's new pose, or (another device in use) the proxy moved directly until the
        device moves it again.
        """
        if self.mouse is not None:
            self.mouse.set_pose(pose)
        else:
            self.sim.set_proxy(np.asarray(pose))

    def reset(self) -> None:
        """The proxy went back to the start: tell the mouse."""
        if self.mouse is not None:
            self.mouse.set_pose(self.sim.proxy_pose)

    def switch(self, cmd: SetDevice) -> None:
        """Open another device; on failure the current one stays (a DeviceEvent says why)."""
        try:
            dev = open_device(cmd.kind, self.sim.proxy_pose, dict(cmd.options), self.base_dir)
        except DeviceError as exc:
            self.events.append(DeviceEvent(cmd.kind, False, str(exc), fallback=self.name))
            return
        self._disconnect()
        self._use(dev)
        self.events.append(DeviceEvent(cmd.kind, True, f"{cmd.kind} connected", cmd.kind))

    def _fall_back(self, message: str) -> None:
        lost = self.device.name
        self._disconnect()
        self._use(MouseDevice())
        self.events.append(DeviceEvent(lost, False, message, fallback="mouse"))

    def _disconnect(self) -> None:
        try:
            self.device.disconnect()
        except Exception:  # noqa: BLE001 -- a lost device may fail to close
            pass
