"""``btrun campaign``: a small campaign of square flights, one with an injected link fault,
one whose worker process dies and one that hangs past its time-out, gives the same table
on the local pool, after a resume and on a Dask LocalCluster.

The crash and the hang come from a test plug-in (``CampaignProbe``, named in
``BTRUN_PLUGINS`` so that the worker processes load it too) run before the square.
"""

from __future__ import annotations

import importlib
import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest
from helpers import REPO

import nodes  # noqa: F401  (the drone leaves, before the registry snapshot)
from bt_engine.campaign import comparable, read_results, run_campaign
from bt_engine.registry import REGISTRY

MISSIONS = os.path.join(REPO, "missions")
PROBE_MODULE = '''
"""Campaign test plug-in: CampaignProbe succeeds (ok), ends its process (crash) or hangs."""

import os
import time

from bt_engine.node import SUCCESS, NodeStatus, SyncActionNode
from bt_engine.ports import STRING, input_port
from bt_engine.registry import register


@register
class CampaignProbe(SyncActionNode):
    """Campaign test leaf: ok succeeds, crash ends the process, hang never returns."""

    category = "test"
    ports = (input_port("mode", STRING, "ok", "ok, crash or hang"),)

    def tick_impl(self) -> NodeStatus:
        mode = self.get_input("mode")
        if mode == "crash":
            os._exit(3)
        while mode == "hang":
            time.sleep(0.05)
        return SUCCESS


class _Plugin:
    name = "campaign-probe"

    def load_target(self, rig_path, overrides):
        return None

    def write_report(self, run_dir, trace, summary, mission):
        return None

    def commands(self):
        return {}


PLUGIN = _Plugin()
'''
PROBE_MISSION = f"""<root BTCPP_format="4" main_tree_to_execute="Probe">
  <include path="{os.path.join(MISSIONS, "square.xml")}"/>
  <BehaviorTree ID="Probe">
    <Sequence>
      <CampaignProbe mode="{{probe}}"/>
      <SubTree ID="Square" _autoremap="true"/>
    </Sequence>
  </BehaviorTree>
</root>
"""
CAMPAIGN = """\
name: probe
missions: [probe.xml]
seeds: [0, 1]
faults:
  - name: none
    set: {probe: ok}
  - name: link_drop
    set: {probe: ok, faults.link_drop.at_s: 5.0}
  - name: crash
    set: {probe: crash}
  - name: hang
    set: {probe: hang}
    timeout_s: 1.5
timeout_s: 120
metrics:
  time: mission_time_s
  landed: sim.landed
  worst_goto_error_m: {max: "motions[kind=GoTo].final_dist_m"}
  wall: {path: wall_time_s, wall_clock: true}
"""
EXPECTED = {"none": "SUCCESS", "link_drop": "ABORTED", "crash": "CRASHED", "hang": "TIMEOUT"}


@pytest.fixture(scope="module")
def probe(tmp_path_factory):
    """A folder with the probe plug-in, its mission and the campaign; the environment set so
    that worker processes load the plug-in; the registry restored afterwards."""
    folder = tmp_path_factory.mktemp("campaign")
    (folder / "btrun_test_probe.py").write_text(textwrap.dedent(PROBE_MODULE))
    (folder / "probe.xml").write_text(PROBE_MISSION)
    (folder / "probe.yaml").write_text(CAMPAIGN)
    saved = (dict(REGISTRY._models), dict(REGISTRY._aliases))
    with pytest.MonkeyPatch.context() as mp:
        mp.syspath_prepend(str(folder))
        path = os.pathsep.join(p for p in (str(folder), os.environ.get("PYTHONPATH")) if p)
        mp.setenv("PYTHONPATH", path)
        mp.setenv("BTRUN_PLUGINS", "btrun_test_probe:PLUGIN")
        importlib.import_module("btrun_test_probe")
        try:
            yield folder
        finally:
            REGISTRY._models, REGISTRY._aliases = saved
            sys.modules.pop("btrun_test_probe", None)


@pytest.fixture(scope="module")
def pool_run(probe):
    """The campaign flown once on a local pool of two workers."""
    return run_campaign(
        str(probe / "probe.yaml"), str(probe / "pool"), workers=2, include_paths=[MISSIONS]
    )


def test_the_pool_records_every_outcome_and_goes_on(pool_run) -> None:
    table = pool_run.table
    assert [r["row"] for r in table] == [f"r{i:05d}" for i in range(8)]
    assert {r["fault"]: r["status"] for r in table} == EXPECTED
    by = {(r["fault"], r["seed"]): r for r in table}
    assert by["crash", 0]["reason"] == "the worker process died during the run (exit code 3)"
    assert "1.5 s time-out" in by["hang", 0]["reason"]
    assert by["none", 0]["landed"] is True and by["none", 0]["time"] > 20
    assert by["none", 0]["worst_goto_error_m"] < 0.03
    assert by["crash", 0]["time"] is None  # no summary: no metric
    # run folders kept for the runs that did not succeed, with their flight report
    assert all(bool(r["run_dir"]) == (r["status"] != "SUCCESS") for r in table)
    out = pool_run.out_dir
    assert os.path.exists(os.path.join(out, by["link_drop", 0]["run_dir"], "report.html"))
    assert os.path.exists(os.path.join(out, by["hang", 1]["run_dir"], "ticks.jsonl"))


def test_the_tables_and_the_report_are_written(pool_run) -> None:
    out = pool_run.out_dir
    table = read_results(out)
    assert table.num_rows == 8
    assert table.column_names[:6] == ["row", "mission", "rig", "world", "seed", "fault"]
    assert "wall" not in comparable(table).column_names  # wall-clock columns set apart
    with open(os.path.join(out, "results.csv"), encoding="utf-8") as f:
        assert len(f.read().splitlines()) == 9
    with open(pool_run.report, encoding="utf-8") as f:
        html = f.read()
    assert "Success rate per setting value" in html and "Failure reasons" in html
    link = next(r for r in pool_run.table if r["fault"] == "link_drop")["run_dir"]
    assert f'href="{link}/report.html"' in html
    assert os.path.exists(os.path.join(out, "plots", "time.png"))


def test_a_resumed_campaign_runs_only_the_missing_rows(probe, pool_run) -> None:
    out = str(probe / "resumed")
    first = run_campaign(
        str(probe / "probe.yaml"), out, workers=1, limit=3, include_paths=[MISSIONS]
    )
    assert first.ran == ["r00000", "r00001", "r00002"] and first.complete
    rest = run_campaign(str(probe / "probe.yaml"), out, workers=2, include_paths=[MISSIONS])
    assert sorted(rest.ran) == [f"r{i:05d}" for i in range(3, 8)]
    assert comparable(read_results(out)).equals(comparable(read_results(pool_run.out_dir)))
    again = run_campaign(str(probe / "probe.yaml"), out, workers=2, include_paths=[MISSIONS])
    assert again.ran == [] and again.complete


def test_another_campaign_is_refused_where_one_has_its_results(probe, pool_run, capsys) -> None:
    """A different campaign run into a campaign's --out had replaced its tables and report
    and mixed both campaigns' run folders, without a word (the dry run said nothing)."""
    from bt_engine.cli import main

    other = probe / "other.yaml"
    other.write_text((probe / "probe.yaml").read_text().replace("name: probe", "name: other"))
    before = read_results(pool_run.out_dir)
    for extra in (["--dry-run"], ["--workers", "1"]):
        code = main(["campaign", str(other), "--out", pool_run.out_dir, *extra])
        err = capsys.readouterr().err
        assert code == 2, err
        assert f"--out {pool_run.out_dir} holds the results of campaign 'probe'" in err, err
        assert "not of 'other'" in err
    assert read_results(pool_run.out_dir).equals(before)


@pytest.mark.slow
def test_a_dask_local_cluster_gives_the_same_table(probe, pool_run) -> None:
    from dask.distributed import LocalCluster

    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        run = run_campaign(
            str(probe / "probe.yaml"),
            str(probe / "dask"),
            scheduler=cluster.scheduler_address,
            include_paths=[MISSIONS],
        )
    assert sorted(run.ran) == [f"r{i:05d}" for i in range(8)]
    assert comparable(read_results(run.out_dir)).equals(comparable(read_results(pool_run.out_dir)))


@pytest.mark.slow
def test_ctrl_c_keeps_the_finished_rows_and_says_how_to_resume(probe, pool_run) -> None:
    out = probe / "interrupted"
    cmd = [sys.executable, "-m", "bt_engine.cli", "campaign", "probe.yaml", "--out", str(out)]
    cmd += ["--workers", "1", "--include-path", MISSIONS]
    proc = subprocess.Popen(cmd, cwd=probe, stderr=subprocess.PIPE, text=True)
    rows = out / "rows"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None:
        if rows.is_dir() and any(n.endswith(".json") for n in os.listdir(rows)):
            break
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 1, err
    assert "resume with: btrun campaign probe.yaml --out" in err
    finished = {json.loads((rows / n).read_text())["row"] for n in os.listdir(rows)}
    assert 1 <= len(finished) < 8
    rest = run_campaign(str(probe / "probe.yaml"), str(out), workers=2, include_paths=[MISSIONS])
    assert set(rest.ran) == {f"r{i:05d}" for i in range(8)} - finished
    assert comparable(read_results(str(out))).equals(comparable(read_results(pool_run.out_dir)))
