"""What ``btrun run`` checks before take-off, flying nothing: :func:`check_before_flight`
(``btrun validate --rig``, ``btrun fleet --check`` per drone)."""

from __future__ import annotations

import sys

from bt_engine.inputs import declared_inputs, missing_inputs, typed_inputs
from bt_engine.mission import Mission
from bt_engine.plugins import load_target
from bt_engine.run_cmd import parse_sets, wall_echo
from bt_engine.run_inputs import mission_time_limit
from bt_engine.spec import Loc, MissionError, Problem


def check_before_flight(
    spec, rig: str | None, sets: list[str], seed: int = 0, loads: bool = True
) -> list[Problem]:
    """What ``btrun run`` checks before take-off, without building a platform or flying:
    the ``--set`` items against the mission's inputs (and its time limit, ``max_time``),
    the rig and world files (through the plug-in) and every node's pre-flight check
    (:meth:`bt_engine.mission.Mission.preflight`) with the rig's resources (its world);
    ``loads=False`` leaves out the checks that load models or build a gallery. Returns
    every located problem."""
    bb, overrides, problems = parse_sets(sets, declared_inputs(spec), spec.file)
    if not problems:  # inputs no one gives, or given as no value of their declared type
        problems += missing_inputs(spec, set(bb)) + typed_inputs(spec, bb)
    _limit, limit_problem = mission_time_limit(spec, bb)  # --set max_time=0 is refused too
    problems += [limit_problem] if limit_problem is not None else []
    try:
        target = load_target(rig, overrides)
    except MissionError as exc:
        return problems + exc.problems
    if target is None:
        where = Loc(rig or "--set", 0, 0)
        return [*problems, Problem(where, "no vehicle plug-in is installed to use a rig")]
    if problems:
        return problems
    resources = {"platform": None, "seed": seed, "run_dir": None, "resume_from": None}
    mission = Mission(spec, resources={**resources, **target.resources()}, blackboard=bb)
    # what the checks load or build (a demo gallery: minutes for thousands of pallets) is
    # said as it goes, on stderr: stdout keeps the verdicts
    mission.ctx.echo = wall_echo(sys.stderr)
    try:
        return mission.preflight(set_keys=set(bb), loads=loads)
    finally:
        mission.close()
