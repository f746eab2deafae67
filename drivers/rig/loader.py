"""Rig files: what a mission flies on (link, control loop, sensors, world, faults).

``load_rig(path, overrides)`` validates a rig file (every problem located as
``file:line:col: message``, unknown keys with a "did you mean"), applies ``--set`` overrides
and returns a :class:`Rig`; ``drivers.rig.factory.make_platform(rig, clock, seed)`` builds the
platform the runner drives. :data:`~drivers.rig.schema.RIG_SCHEMA` declares every setting (docs/rig-settings.md).
"""

from __future__ import annotations

import os
from typing import Any

import yaml

from drivers.rig.paths import DEFAULT_RIG, REPO_ROOT
from drivers.rig.schema import RIG_SCHEMA, SIM_PARAMS
from drivers.safety.policies import SafetyConfig
from drivers.settings import (
    ConfigError,
    Marks,
    SettingProblem,
    check_value,
    did_you_mean,
    problem_at,
    written_by,
)
from drivers.settings import (
    apply_overrides as _apply,
)
from drivers.settings_yaml import load_yaml_file, read_settings_text
from drivers.sim.crazyflie_params import crazyflie_params

__all__ = ["ConfigError", "Rig", "RIG_SCHEMA", "apply_overrides", "load_rig", "REPO_ROOT"]


def apply_overrides(config: dict, overrides: dict[str, str] | None) -> dict:
    """Apply ``--set dotted.key=value`` overrides to validated rig data (type-checked).

    Raises :class:`ConfigError` (all problems at once; unknown keys with "did you mean").
    """
    return _apply(config, overrides, RIG_SCHEMA)


#: What an empty file is refused with, per kind of settings file.
_EMPTY = {
    "rig": "rig settings: a mapping such as `link: sim`, stating what differs from the "
    "defaults (docs/rig-settings.md)",
    "world": "a world: a mapping of its floor, lighting, pallets, racks, ... "
    "(worlds/warehouse.yaml is an example)",
}


def _is_empty_yaml(text: str) -> bool:
    """True if ``text`` holds no YAML value at all: nothing, blank lines, comments, a bare
    ``---``. (A text that is not YAML is not empty: the loader says what is wrong.)"""
    empty = (
        yaml.StreamStartToken,
        yaml.StreamEndToken,
        yaml.DocumentStartToken,
        yaml.DocumentEndToken,
        yaml.DirectiveToken,
    )
    try:
        return all(isinstance(t, empty) for t in yaml.scan(text, Loader=yaml.SafeLoader))
    except yaml.YAMLError:
        return False


def refuse_empty(path: str, kind: str) -> str:
    """The text of the settings file ``path`` (``kind``: ``rig`` or ``world``), read by
    :func:`~drivers.settings_yaml.read_settings_text` (its refusals as they are); raises
    :class:`ConfigError` if it is empty (0 bytes, comments only): an empty rig flew on the
    defaults, an empty world failed on a default it never wrote."""
    text = read_settings_text(path, f"{kind} files")
    if _is_empty_yaml(text):
        message = f"the {kind} file is empty: expected {_EMPTY[kind]}"
        raise ConfigError([SettingProblem(path, 1, 1, message)])
    return text


class Rig:
    """A validated rig: ``kind`` (link kind), ``data`` (settings), ``path`` (file).

    ``world_base`` is the folder a relative ``world.path`` is read from: the rig file's
    (as a rig file writes it), or the working folder for a ``world.path`` given by
    ``--set`` (as every path on the command line)."""

    def __init__(
        self,
        data: dict,
        path: str,
        world_overrides: dict | None = None,
        world_base: str | None = None,
    ) -> None:
        self.data, self.path = data, path
        self.kind: str = data["link"]
        #: ``--set world.KEY=VALUE`` items for keys of the world file (``scan_slot.y_m``)
        self.world_overrides: dict[str, str] = dict(world_overrides or {})
        self.world_base = world_base or os.path.dirname(os.path.abspath(path))

    @property
    def realtime_factor(self) -> float | None:
        """Mission seconds per wall second when the rig asks for real time, else None."""
        clock = self.data.get("clock", {})
        return float(clock.get("realtime_factor", 1.0)) if clock.get("mode") == "realtime" else None

    def load_world(self, seed: int = 0) -> Any:
        """The rig's world (:class:`drivers.sim.world.World`), with ``world.scan_pallet``
        (which pallet side stands at the scan slot) and the ``--set world.KEY`` overrides
        applied; ``seed`` draws the world's placement error."""
        from drivers.sim.world import load_world

        overrides = dict(self.world_overrides)
        if self.data["world"]["scan_pallet"] is not None:
            overrides["scan_pallet"] = self.data["world"]["scan_pallet"]
        path = self.world_path
        refuse_empty(path, "world")  # read again by load_world: a world file is small
        return load_world(path, overrides, seed)

    @property
    def world_path(self) -> str:
        """The world file: ``world.path`` as it is if absolute, else relative to
        :attr:`world_base` (the rig file's folder; the working folder for a ``--set``), and
        nowhere else: a mistyped path is an error, never another file of that name."""
        return os.path.normpath(os.path.join(self.world_base, self.data["world"]["path"]))


def load_rig(
    path: str | None = None, overrides: dict[str, str] | None = None, own_start: bool = True
) -> Rig:
    """Load and validate a rig file (None -> the repo's ``rigs/sim.yaml``), apply overrides.

    ``world.path`` and ``world.scan_pallet`` are rig settings; any other ``world.KEY`` is a
    key of the world file (``world.scan_slot.y_m=0.15``, ``world.placement_error.yaw_deg=10``)
    applied when the world is loaded, with the world's own checks.

    The world file is validated too, so a bad world is reported before anything flies.
    ``own_start=False`` leaves out the check that ``sim.start_m`` lies inside the geofence
    (a fleet's drones start on pads of their own, checked where the fleet file names them).
    """
    path = path or DEFAULT_RIG
    marks: Marks = {}
    text = refuse_empty(path, "rig")
    data = load_yaml_file(path, RIG_SCHEMA, text=text, marks=marks, what="rig files")
    _check_rig(data, marks, path, {}, own_start)
    rig_keys = RIG_SCHEMA.children["world"].children
    world_over = {
        k[len("world.") :]: v
        for k, v in (overrides or {}).items()
        if k.startswith("world.") and k.split(".")[1] not in rig_keys
    }
    rest = {k: v for k, v in (overrides or {}).items() if k[len("world.") :] not in world_over}
    data = apply_overrides(data, rest)
    if rest:
        _check_rig(data, marks, path, rest, own_start)
    by_set = written_by("world.path", rest)
    rig = Rig(data, path, world_over, os.getcwd() if by_set else None)
    if rig.kind == "sim":
        if not os.path.lexists(rig.world_path):  # said at the rig's line, not the missing file's
            raise ConfigError([_no_world(rig, marks, by_set)])
        rig.load_world()  # world checks (and the scan pallet) before anything flies
    return rig


def _no_world(rig: Rig, marks: Marks, by_set: bool) -> SettingProblem:
    """``world.path`` names no file: said where it was written, with the file looked for and
    a world file of that folder it may have meant."""
    p = rig.data["world"]["path"]
    found, folder = rig.world_path, os.path.dirname(rig.world_path)
    base = "the working folder" if by_set else "the rig file"
    try:
        names = sorted(n for n in os.listdir(folder) if n.lower().endswith((".yaml", ".yml")))
    except OSError:  # no such folder either, or not readable
        names = []
    # the name as written, with the file of that folder it may have meant
    written = {os.path.join(os.path.dirname(p), n): n for n in names}
    hint = did_you_mean(os.path.basename(found), names)
    hint = next((f" (did you mean {w!r}?)" for w, n in written.items() if f"'{n}'" in hint), "")
    message = f"world.path {p!r}: no such world file ({found}; relative to {base}){hint}"
    if by_set:
        return SettingProblem("--set", 0, 0, message)
    return problem_at(marks, "world.path", rig.path, message)


_FENCE = ("safety.geofence.min_m", "safety.geofence.max_m", "safety.geofence.enabled")


def rig_problems(data: dict, own_start: bool = True) -> list[tuple[tuple[str, ...], str]]:
    """``(keys, message)`` for what no single setting shows (``keys``: the settings that make
    it, located at the first): a geofence box whose minimum is not below its maximum on an
    axis, or a simulated drone that starts outside it (it would be in breach the moment it
    took off), a battery's critical level above its low one (the landing for low would
    never come first), and the ``sim.params`` problems of :func:`sim_param_problems`."""
    return sim_param_problems(data) + _whole_rig_problems(data, own_start)


#: Where a rig sets what a ``sim.params`` name of the simulator's own might be taken for.
_PARAMS_ELSEWHERE = {
    "battery_charge_current_a": "battery.charge_current_a",
    "battery_swap_soc": "battery.swap_soc",
}
_TIME_CONSTANTS = ("motor_time_constant_s", "attitude_time_constant_s", "yaw_rate_time_constant_s")


def sim_param_problems(data: dict) -> list[tuple[tuple[str, ...], str]]:
    """``(keys, message)`` for the rig's ``sim.params``: a name that is no parameter of
    drivers/sim/crazyflie_params.py (with a "did you mean"), a value out of its range
    (:data:`~drivers.rig.schema.SIM_PARAMS`), and what the parameters make together: motors
    that cannot lift the drone, a lag shorter than one physics step (its step-by-step
    integration then overshoots), a tumble angle within the tilt limit, a watchdog that stops
    the motors before it levels the drone."""
    given: dict = data["sim"]["params"]
    problems: list[tuple[tuple[str, ...], str]] = []
    for name, value in given.items():
        key = f"sim.params.{name}"
        if name not in SIM_PARAMS:
            if name in _PARAMS_ELSEWHERE:
                hint = f" (the rig sets it as {_PARAMS_ELSEWHERE[name]})"
            else:
                hint = did_you_mean(name, list(SIM_PARAMS))
            problems.append(
                (
                    (key,),
                    f"sim.params: unknown key '{name}'{hint}: expected a parameter of "
                    "drivers/sim/crazyflie_params.py (listed in docs/rig-settings.md)",
                )
            )
            continue
        f = SIM_PARAMS[name]
        _, messages = check_value(value, f, key)
        problems += [((key,), f"{m} (its range: {f.min:g}..{f.max:g})") for m in messages]
    if problems:  # the values together only once each is sensible
        return problems
    p = {**crazyflie_params, **given}

    def keys(*names: str) -> tuple[str, ...]:  # located at one the rig wrote, if any
        written = [n for n in names if n in given] + [n for n in names if n not in given]
        return tuple(f"sim.params.{n}" for n in written)

    lift = p["max_thrust_per_motor_n"] * p["motor_count"]
    weight = p["mass_kg"] * p["gravity_mps2"]
    if lift <= weight:
        problems.append(
            (
                keys("mass_kg", "max_thrust_per_motor_n", "motor_count", "gravity_mps2"),
                f"sim.params: the motors cannot lift the drone: {p['motor_count']:g} x "
                f"max_thrust_per_motor_n {p['max_thrust_per_motor_n']:g} N = {lift:g} N "
                f"against mass_kg {p['mass_kg']:g} x gravity_mps2 {p['gravity_mps2']:g} = "
                f"{weight:g} N: expected more thrust than weight",
            )
        )
    step_s = 1.0 / float(data["sim"]["physics_rate_hz"])
    for name in _TIME_CONSTANTS:
        if p[name] < step_s:
            problems.append(
                (
                    (*keys(name), "sim.physics_rate_hz"),
                    f"sim.params.{name} {p[name]:g} s is shorter than one physics step "
                    f"(1 / sim.physics_rate_hz = {step_s:g} s): expected at least {step_s:g} s "
                    "(or a higher physics_rate_hz)",
                )
            )
    if p["tumble_tilt_deg"] <= p["max_tilt_deg"]:
        problems.append(
            (
                keys("tumble_tilt_deg", "max_tilt_deg"),
                f"sim.params.tumble_tilt_deg {p['tumble_tilt_deg']:g} must be above "
                f"max_tilt_deg {p['max_tilt_deg']:g} (the drone would count as tumbled "
                "within its own tilt limit)",
            )
        )
    if p["setpoint_stabilize_timeout_s"] >= p["setpoint_shutdown_timeout_s"]:
        problems.append(
            (
                keys("setpoint_stabilize_timeout_s", "setpoint_shutdown_timeout_s"),
                f"sim.params.setpoint_stabilize_timeout_s {p['setpoint_stabilize_timeout_s']:g}"
                f" s must be below setpoint_shutdown_timeout_s "
                f"{p['setpoint_shutdown_timeout_s']:g} s (the watchdog levels the drone "
                "before it stops the motors)",
            )
        )
    return problems


def _whole_rig_problems(data: dict, own_start: bool) -> list[tuple[tuple[str, ...], str]]:
    """:func:`rig_problems` other than those of ``sim.params``."""
    rate = float(data["sim"]["physics_rate_hz"])
    if abs(rate / 100.0 - round(rate / 100.0)) > 1e-9:  # the firmware's 100 Hz loop steps
        return [  # a whole number of physics steps: 333 Hz ran it at another rate
            (
                ("sim.physics_rate_hz",),
                f"sim.physics_rate_hz {rate:g}: expected a multiple of 100 (the firmware's "
                "control loop runs at 100 Hz, a whole number of physics steps each)",
            )
        ]
    fence = SafetyConfig.from_dict(data["safety"])
    if fence.battery_critical_v >= fence.battery_low_v > 0.0:
        return [
            (
                ("safety.battery_critical_v", "safety.battery_low_v"),
                f"safety.battery_critical_v {fence.battery_critical_v:g} V must be below "
                f"battery_low_v {fence.battery_low_v:g} V (critical is the lower level)",
            )
        ]
    if not fence.geofence_enabled:
        return []
    lo, hi = fence.geofence_min_m, fence.geofence_max_m
    flat = [a for i, a in enumerate("xyz") if not lo[i] < hi[i]]
    if flat:
        return [
            (
                _FENCE,
                f"safety.geofence: min_m {list(lo)} must be below max_m {list(hi)} on every "
                f"axis (not on {', '.join(flat)})",
            )
        ]
    start = data["sim"]["start_m"]
    if own_start and data["link"] == "sim" and not fence.inside(tuple(start)):
        return [
            (
                ("sim.start_m", "link", *_FENCE),
                f"sim.start_m {list(start)}: the drone would start outside the geofence "
                f"({fence.box_words()}): expected a start inside it",
            )
        ]
    return []


def _check_rig(
    data: dict, marks: Marks, path: str, overrides: dict[str, str], own_start: bool
) -> None:
    """Raise :class:`ConfigError` with :func:`rig_problems`, located at the ``--set`` that
    wrote the key, else where the file wrote it (with the overrides named)."""
    problems = []
    for keys, message in rig_problems(data, own_start):
        if any(written_by(key, overrides) for key in keys):
            problems.append(SettingProblem("--set", 0, 0, message))
        else:
            given = ", ".join(f"--set {k}={v}" for k, v in overrides.items())
            where = problem_at(
                marks, keys[0], path, message + (f" (with {given})" if given else "")
            )
            problems.append(where)
    if problems:
        raise ConfigError(problems)
