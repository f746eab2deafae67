"""A halt that never returns does not keep the drone in the air.

At the end of a run the tree is halted, then the drone lands. A plug-in whose
``on_halted`` spins, swallows every stop or sleeps in C had kept ``btrun`` halting for ever
(the drone hovering, no summary). The halt now has a wall-clock budget
(:data:`bt_engine.runner.HALT_BUDGET_S`): it is stopped as an overrunning tick is, and given
up a budget later, when the run ends without the main thread as a tick given up does.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest
from helpers import leaf_plugin_env

from bt_engine.runner import HALT_BUDGET_S

BTRUN = os.path.join(os.path.dirname(sys.executable), "btrun")

PLUGIN = '''
"""Test plug-in: an action that runs until halted, and whose halt never returns."""

import time

from bt_engine.node import RUNNING, NodeStatus, StatefulActionNode
from bt_engine.ports import STRING, input_port
from bt_engine.registry import register


@register
class StuckHaltTestOnly(StatefulActionNode):
    """RUNNING until halted; its on_halted spins, swallows every stop, or sleeps."""

    category = "test"
    ports = (input_port("mode", STRING, "spin", "spin, swallow or sleep"),)

    def on_start(self) -> NodeStatus:
        return RUNNING

    def on_running(self) -> NodeStatus:
        return RUNNING

    def on_halted(self) -> None:
        mode = self.get_input("mode")
        if mode == "sleep":
            time.sleep(1000)
        while mode == "swallow":
            try:
                while True:
                    pass
            except BaseException:
                pass
        while mode == "spin":
            pass
'''

MISSION = """<root BTCPP_format="4" main_tree_to_execute="M">
  <BehaviorTree ID="M">
    <Sequence>
      <TakeOff height="1.0" speed="0.5"/>
      <StuckHaltTestOnly mode="{mode}"/>
    </Sequence>
  </BehaviorTree>
</root>
"""


@pytest.mark.slow  # a btrun process that waits out the halt budget (3-6 s of wall time)
@pytest.mark.parametrize("mode", ["spin", "swallow", "sleep"])
def test_a_halt_that_never_returns_still_lands_and_writes_the_summary(tmp_path, mode) -> None:
    env = leaf_plugin_env(tmp_path, "btrun_test_stuck_halt", textwrap.dedent(PLUGIN))
    (tmp_path / "m.xml").write_text(MISSION)
    out = tmp_path / "run"
    proc = subprocess.run(
        [BTRUN, "m.xml", "--set", f"mode={mode}", "--max-time", "5", "--quiet", "--no-report"]
        + ["--out", str(out)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=60 + 4 * HALT_BUDGET_S,
    )
    assert proc.returncode == 1, (proc.returncode, proc.stdout, proc.stderr)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "ABORTED", summary["reason"]
    assert "written_by" not in summary  # btrun's own summary, not the guard's
    reason = summary["reason"]
    assert "; while halting: watchdog: halting did not return within " in reason, reason
    assert "StuckHaltTestOnly" in reason and "m.xml:5:7" in reason, reason
    if mode != "spin":  # the stop did not bring the halt back: given up
        assert reason.endswith("given up"), reason
    assert summary["sim"]["landed"], summary["sim"]
    assert "Traceback" not in proc.stderr, proc.stderr
