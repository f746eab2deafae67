"""btrun's mission engine: behaviour-tree missions in XML/YAML -> running py_trees trees.

The engine knows nothing of drones; leaves register themselves in :data:`REGISTRY`.
"""

from bt_engine import controls, decorators, leaves, loops  # noqa: F401  (register built-ins)
from bt_engine.clock import SimClock, WallClock
from bt_engine.loading import load_spec
from bt_engine.mission import Mission, check_file
from bt_engine.node import (
    FAILURE,
    IDLE,
    RUNNING,
    SKIPPED,
    SUCCESS,
    BTNode,
    ConditionNode,
    ControlNode,
    DecoratorNode,
    MissionContext,
    NodeStatus,
    StatefulActionNode,
    SyncActionNode,
)
from bt_engine.ports import inout_port, input_port, output_port
from bt_engine.registry import REGISTRY, register
from bt_engine.runner import Runner, RunResult
from bt_engine.spec import MissionError

__all__ = [
    "REGISTRY",
    "register",
    "Mission",
    "MissionError",
    "Runner",
    "RunResult",
    "SimClock",
    "WallClock",
    "check_file",
    "load_spec",
    "BTNode",
    "ConditionNode",
    "ControlNode",
    "DecoratorNode",
    "StatefulActionNode",
    "SyncActionNode",
    "MissionContext",
    "NodeStatus",
    "IDLE",
    "RUNNING",
    "SUCCESS",
    "FAILURE",
    "SKIPPED",
    "input_port",
    "output_port",
    "inout_port",
]
