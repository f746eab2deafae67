"""The platform factory: the only module that knows every platform.

:func:`make_platform` turns a validated :class:`~drivers.rig.loader.Rig` into the platform
the runner drives:

* ``link: sim`` -> :class:`~drivers.sim.sim_platform.SimPlatform` (lock-step, in-process);
* ``link: crazyflie`` -> :class:`~drivers.crazyflie.cf_platform.CrazyfliePlatform`, assembled
  here from its parts: a cflib link to the rig's URI, a pose source (motion capture, the
  SITL mocap, or one passed in), the AI-deck stream and the fault injector. With
  ``crazyflie.sitl: true`` the CRTP (and AI-deck) emulators are started first on loopback and
  the platform simply connects to their ``udp://`` URI, as cflib would to any Crazyflie.

The hardware modules never import the simulator; this module wires the two together.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from drivers.crazyflie.aideck_stream import AIDeckStream
from drivers.crazyflie.cf_platform import CrazyfliePlatform
from drivers.crazyflie.cflib_link import CrazyflieLink, CrazyflieLinkConfig
from drivers.guard.client import GuardClient, GuardError
from drivers.rig.loader import Rig
from drivers.settings import ConfigError, SettingProblem
from drivers.sim.emulators.aideck import AIDeckEmulator, default_pose, make_frame_source
from drivers.sim.emulators.sitl import SitlSession
from drivers.sim.sim_platform import SimPlatform
from drivers.vehicle.config import VehicleConfig
from drivers.vehicle.faults import FaultInjector
from drivers.vehicle.interfaces import PoseSource


def make_platform(
    rig: Rig,
    clock: Any,
    seed: int,
    pose_source: PoseSource | None = None,
    guard: GuardClient | None = None,
) -> Any:
    """Build the platform of ``rig`` on ``clock`` (all randomness derived from ``seed``).

    ``pose_source`` replaces the rig's pose source of a Crazyflie (tests, other mocap
    systems). With a ``guard`` (not started yet), a Crazyflie's cflib link is opened and
    owned by the guard process and the platform flies through a
    :class:`~drivers.guard.client.GuardLink`; a simulator's guard only watches. Raises
    :class:`~drivers.settings.ConfigError` for a rig that cannot fly here.
    """
    if rig.kind == "sim":
        platform = SimPlatform(rig.load_world(seed), rig.data, seed, clock)
        unable = unable_faults(rig.data, platform.faults)
        if unable:
            raise ConfigError(unable_problems(rig.path, "sim", unable, platform.faults))
        if guard is not None:
            _start_guard(rig, guard, None)
        return platform
    if rig.kind == "crazyflie":
        return make_crazyflie_platform(rig, clock, seed, pose_source, guard)
    raise ConfigError([SettingProblem(rig.path, 1, 1, f"link '{rig.kind}' is not available")])


def unable_faults(data: dict, faults: FaultInjector) -> list[str]:
    """The faults the rig ``data`` schedules (``at_s`` set) that ``faults`` cannot inject."""
    return [
        n
        for n, spec in data["faults"].items()
        if spec.get("at_s") is not None and n not in faults.handlers
    ]


def unable_problems(
    path: str, kind: str, unable: list[str], faults: FaultInjector
) -> list[SettingProblem]:
    """One problem per fault the rig schedules and its platform cannot inject (they had
    been left out without a word, or ended the run in a traceback), naming those it can."""
    can = ", ".join(sorted(faults.handlers)) or "none"
    return [
        SettingProblem(
            path,
            1,
            1,
            f"faults.{name}.at_s: this rig (link: {kind}) cannot inject {name} (it injects: {can})",
        )
        for name in unable
    ]


def make_crazyflie_platform(
    rig: Rig,
    clock: Any,
    seed: int,
    pose_source: PoseSource | None = None,
    guard: GuardClient | None = None,
) -> CrazyfliePlatform:
    """A :class:`CrazyfliePlatform` for a rig with ``link: crazyflie``.

    ``crazyflie.sitl: true`` starts the CRTP emulator in-process on a free loopback port
    (:mod:`drivers.sim.emulators.sitl`) and, with ``pose_source: sitl``, uses its simulated
    mocap. ``pose_source: mocap`` builds a :class:`~drivers.crazyflie.mocap.MocapSource`
    from the rig's ``mocap:`` section.
    """
    data = rig.data
    section = data["crazyflie"]
    if getattr(clock, "is_simulated", True) or rig.realtime_factor not in (None, 1.0):
        raise ConfigError(
            [
                SettingProblem(
                    rig.path,
                    1,
                    1,
                    "link 'crazyflie' flies in real time: set clock.mode: "
                    "realtime and clock.realtime_factor: 1",
                )
            ]
        )
    faults = FaultInjector()
    on_close: list[Callable[[], None]] = []
    truth = None
    uri = None
    sitl = None
    if section["sitl"]:
        world = rig.load_world(seed) if section["sitl_world"] else None
        sitl = SitlSession(data, seed, world).start()
        on_close.append(sitl.stop)
        truth, uri = sitl.truth, sitl.uri
    try:
        camera, camera_emu = _make_camera(rig, seed, sitl, on_close)
    except Exception:
        _close_all(on_close)
        raise
    if sitl is not None:
        sitl.register_faults(faults)
    unable = unable_faults(data, faults)
    if unable:  # they had been left out without a word: a rehearsal without its fault
        _close_all(on_close)
        kind = f"crazyflie{', sitl' if sitl is not None else ''}"
        raise ConfigError(unable_problems(rig.path, kind, unable, faults))
    kind = section["pose_source"]
    if pose_source is None and kind == "sitl":
        if sitl is None or sitl.mocap is None:
            _close_all(on_close)
            raise ConfigError(
                [SettingProblem(rig.path, 1, 1, "pose_source 'sitl' needs crazyflie.sitl")]
            )
        pose_source = sitl.mocap
    elif pose_source is None and kind == "mocap":
        from drivers.crazyflie.mocap import MocapSource  # needs the lab's motioncapture

        pose_source = MocapSource.from_rig(data)
        stop = getattr(pose_source, "close", None) or getattr(pose_source, "stop", None)
        if stop is not None:
            on_close.append(stop)
    config = CrazyflieLinkConfig.from_rig(section, uri)
    connect_start = time.monotonic()
    link: Any
    try:
        if guard is not None:
            link = _start_guard(rig, guard, config)
        else:
            link = CrazyflieLink(config).open()
    except ConnectionError as exc:  # nothing answers at the URI: a rig problem, not a crash
        _close_all(on_close)
        raise ConfigError([SettingProblem(rig.path, 1, 1, str(exc))]) from None
    except Exception:
        _close_all(on_close)
        raise
    for name, spec in data["faults"].items():
        if spec.get("at_s") is not None and name in faults.handlers:
            params = {k: v for k, v in spec.items() if k != "at_s" and v is not None}
            faults.schedule(name, spec["at_s"], **params)
    platform = CrazyfliePlatform(
        link,
        VehicleConfig.from_dict(data["control"]),
        pose_source,
        clock,
        section["shutdown_max_s"],
        truth,
        on_close,
        faults,
        sitl,
        camera,
        camera_emu,
    )
    platform.connect_started_monotonic_s = connect_start
    return platform


def _start_guard(rig: Rig, guard: GuardClient, config: CrazyflieLinkConfig | None) -> Any:
    """Start ``guard`` (with the link for a Crazyflie); its :class:`GuardLink` or None.
    A guard that cannot start (or cannot open the link) is a located rig problem."""
    try:
        guard.start(config)
    except GuardError as exc:
        raise ConfigError([SettingProblem(rig.path, 1, 1, str(exc))]) from None
    return guard.link


def _close_all(on_close: list[Callable[[], None]]) -> None:
    for fn in on_close:
        fn()


def _make_camera(
    rig: Rig, seed: int, sitl: SitlSession | None, on_close: list[Callable[[], None]]
) -> tuple[AIDeckStream | None, AIDeckEmulator | None]:
    """The AI-deck stream (not started) and the in-process emulator serving it, if any.

    ``aideck.enabled: false`` -> (None, None). In SITL the emulator renders the simulated
    drone's true pose; with ``aideck.emulator`` alone (a real drone, no deck) it serves
    ``sensors.camera.renderer`` (or a test pattern) from a fixed pose before the scan pallet.
    """
    data = rig.data
    a = data["aideck"]
    if not a["enabled"]:
        return None, None
    emu = None
    if sitl is not None:
        world = sitl.cf.drone.world
        if world is None:  # the drone flies through nothing, but the camera sees the world
            world = rig.load_world(seed)
        emu = sitl.start_camera(data, seed, world)  # closed by sitl.stop
    elif a["emulator"]:
        world = rig.load_world(seed)
        name = data["sensors"]["camera"]["renderer"]
        source = make_frame_source("pattern" if name in (None, "none") else name, seed, world)
        emu = AIDeckEmulator(
            "127.0.0.1", 0, data["sensors"]["camera"]["rate_hz"], a["format"],
            renderer=source, pose=default_pose(world), seed=seed,
        ).start()  # fmt: skip
        on_close.append(emu.close)
    kw: dict[str, Any] = {"autostart": False}
    if emu is not None:
        kw.update(host="127.0.0.1", port=emu.port)
    stream = AIDeckStream.from_rig(data, **kw)
    on_close.insert(0, stream.close)  # the client goes before the emulators
    return stream, emu
