"""The engine at run time: the loop that steps the simulation at a fixed rate.

Beside the loop: its background job worker, the two transports (a thread, or a process of
its own), the one frame layout, and the typed interface the GUI uses.

Modules, bottom to top: :mod:`~engine.runtime.messages` (frozen commands, events, Frame),
:mod:`~engine.runtime.frames` (the frame layout, packed and unpacked in one place, and the
ring that carries rows), :mod:`~engine.runtime.pacing` (deadlines, catch-up policy, period
statistics, real-time scheduling), :mod:`~engine.runtime.jobs` (frozen requests and
responses, one worker), :mod:`~engine.runtime.guidance` (the field and physics kept up to
date with commands), :mod:`~engine.runtime.inputs` (the device),
:mod:`~engine.runtime.loop` (:class:`EngineLoop`), :mod:`~engine.runtime.recorder`,
:mod:`~engine.runtime.process` (the process transport), :mod:`~engine.runtime.api`
(:func:`start_engine`, :class:`EngineHandle`). The design is in docs/runtime.md.
"""

from engine.runtime.api import DEFAULT_SWITCH_INTERVAL, EngineHandle, Transport, start_engine
from engine.runtime.benchmark import AnalyticWell, bench_proxy_motion, bench_trajectory
from engine.runtime.frames import FRAME_WIDTH, SLOTS, FrameRing, pack_frame, unpack_frame
from engine.runtime.jobs import BackgroundWork, JobWorker
from engine.runtime.loop import EngineLoop
from engine.runtime.messages import (
    COMMAND_TYPES,
    CancelRecompute,
    Command,
    DescriptorsSwapped,
    DeviceEvent,
    ErrorEvent,
    Event,
    Frame,
    LandscapeFailed,
    LandscapeReady,
    Pause,
    PeriodStats,
    ProgressEvent,
    ReadyEvent,
    RequestLandscape,
    Reset,
    SetCoupling,
    SetDescriptorParams,
    SetDevice,
    SetEffects,
    SetKappa,
    SetModes,
    SetProxyPose,
    Stop,
    StoppedEvent,
)
from engine.runtime.pacing import REALTIME_PRIORITY, period_stats, raise_thread_priority
from engine.runtime.process import EngineOptions, LoopResult, ProcessEngine
from engine.runtime.recorder import Recorder
from engine.runtime.scene_handle import SceneHandle, open_scene

__all__ = [
    "COMMAND_TYPES",
    "DEFAULT_SWITCH_INTERVAL",
    "FRAME_WIDTH",
    "REALTIME_PRIORITY",
    "SLOTS",
    "AnalyticWell",
    "BackgroundWork",
    "CancelRecompute",
    "Command",
    "DescriptorsSwapped",
    "DeviceEvent",
    "EngineHandle",
    "EngineLoop",
    "EngineOptions",
    "ErrorEvent",
    "Event",
    "Frame",
    "FrameRing",
    "JobWorker",
    "LandscapeFailed",
    "LandscapeReady",
    "Pause",
    "PeriodStats",
    "LoopResult",
    "ProcessEngine",
    "ProgressEvent",
    "ReadyEvent",
    "Recorder",
    "RequestLandscape",
    "Reset",
    "SceneHandle",
    "SetCoupling",
    "SetDescriptorParams",
    "SetDevice",
    "SetEffects",
    "SetKappa",
    "SetModes",
    "SetProxyPose",
    "Stop",
    "StoppedEvent",
    "Transport",
    "bench_proxy_motion",
    "bench_trajectory",
    "open_scene",
    "pack_frame",
    "period_stats",
    "raise_thread_priority",
    "start_engine",
    "unpack_frame",
]
