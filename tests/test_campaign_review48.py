"""Review 48 of plug-ins, the campaign's part: ``btrun campaign --dry-run`` checks port
ranges; a campaign with CRASHED rows exits 3 and ``--retry-crashed`` runs them again; Dask
workers whose worker processes lack the missions' nodes (the plug-in) are refused before any
row is sent."""

from __future__ import annotations

import os
import sys
from typing import Any

import pytest
from helpers import LEAF_PLUGIN_TAIL, REPO, wrap

from bt_engine import plugins
from bt_engine.campaign import execution, pool
from bt_engine.campaign.execution import run_campaign
from bt_engine.campaign.results import ResultStore
from bt_engine.cli import main
from bt_engine.registry import REGISTRY

SQUARE = os.path.join(REPO, "missions", "square.xml")


@pytest.fixture
def plugin_env(tmp_path, monkeypatch):
    """Set ``BTRUN_PLUGINS`` to a module written in ``tmp_path`` (fresh plug-in list); the
    registry is restored afterwards."""
    import nodes  # noqa: F401  (btrun's own leaves registered before the snapshot below)

    module = []

    def use(spec: str, source: str) -> None:
        module.append(spec.partition(":")[0])
        (tmp_path / f"{module[-1]}.py").write_text(source)
        monkeypatch.syspath_prepend(str(tmp_path))
        monkeypatch.setenv("BTRUN_PLUGINS", spec)
        monkeypatch.setattr(plugins, "_loaded", None)

    saved = (dict(REGISTRY._models), dict(REGISTRY._aliases))
    yield use
    plugins._loaded = None
    REGISTRY._models, REGISTRY._aliases = saved
    for name in module:
        sys.modules.pop(name, None)


# --- F6: the campaign's dry run checks port ranges ----------------------------------------


def test_a_campaign_dry_run_refuses_a_value_outside_a_port_range(tmp_path, capsys) -> None:
    import nodes  # noqa: F401

    path = tmp_path / "c.yaml"
    path.write_text(f"missions: [{SQUARE}]\ngrid:\n  height: [-5, 1.0]\n")
    assert main(["campaign", str(path), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert f"{path}:3:3: height: height -5.0: expected 0.05 to 20" in err, err


# --- F5: crashed rows, --retry-crashed, Dask workers without the plug-in ------------------


class _Pool:
    """Every payload answered at once, CRASHED while ``crash`` is set."""

    crash = True
    ran: list[str] = []

    def __init__(self, *args: Any) -> None:
        pass

    def describe(self) -> str:
        return "a fake cluster"

    def check_workers(self, node_ids: Any) -> None:
        pass

    def results(self, payloads: Any):
        for p in payloads:
            _Pool.ran.append(p["key"])
            status = "CRASHED" if _Pool.crash else "SUCCESS"
            yield {"key": p["key"], "status": status, "reason": "", "metrics": {}, "wall_s": 0.1}

    def close(self) -> None:
        pass

    def stop(self) -> None:
        pass


@pytest.fixture
def fake_pool(monkeypatch):
    import nodes  # noqa: F401

    monkeypatch.setattr(execution, "LocalPool", _Pool)
    monkeypatch.setattr(execution, "DaskPool", _Pool)
    _Pool.crash, _Pool.ran = True, []


def test_crashed_rows_exit_3_and_retry_crashed_runs_them_again(tmp_path, fake_pool, capsys) -> None:
    path = tmp_path / "c.yaml"
    path.write_text(f"missions: [{SQUARE}]\nseeds: [0, 1]\n")
    out = str(tmp_path / "out")
    cmd = ["campaign", str(path), "--out", out]
    assert main(cmd) == 3
    err = capsys.readouterr().err
    assert "btrun campaign: 2 of 2 rows CRASHED" in err, err
    assert f"run them again with: btrun campaign {path} --out {out} --retry-crashed" in err
    assert len(_Pool.ran) == 2
    _Pool.crash = False
    assert main(cmd) == 3 and len(_Pool.ran) == 2  # a crashed row is finished: not re-run
    capsys.readouterr()
    assert main([*cmd, "--dry-run", "--retry-crashed"]) == 0
    assert "0 already finished" in capsys.readouterr().out
    assert main([*cmd, "--retry-crashed"]) == 0 and len(_Pool.ran) == 4
    assert {r["status"] for r in ResultStore(out).finished().values()} == {"SUCCESS"}
    again = run_campaign(str(path), out, retry_crashed=True, report=False)
    assert again.ran == [] and len(_Pool.ran) == 4


def test_workers_that_cannot_run_the_missions_are_exit_2_and_nothing_runs(
    tmp_path, fake_pool, monkeypatch, capsys
) -> None:
    def refuse(self, node_ids):
        assert "TakeOff" in node_ids and "GoTo" in node_ids, node_ids
        answer = {"missing": ["Photograph"], "host": "w1"}
        raise pool.WorkersCannotRun([("tcp://10.0.0.1:1234", answer)], 2)

    monkeypatch.setattr(_Pool, "check_workers", refuse)
    path = tmp_path / "c.yaml"
    path.write_text(f"missions: [{SQUARE}]\n")
    out = tmp_path / "out"
    assert main(["campaign", str(path), "--out", str(out), "--scheduler", "tcp://x:1"]) == 2
    err = capsys.readouterr().err
    assert "1 of the 2 Dask workers cannot run this campaign's missions; nothing ran" in err
    assert "tcp://10.0.0.1:1234 (host w1): unknown node(s) Photograph" in err
    assert _Pool.ran == [] and not out.exists()


def test_the_worker_check_reports_unknown_nodes_and_plugins_that_do_not_load(
    tmp_path, monkeypatch
) -> None:
    monkeypatch.delenv("BTRUN_PLUGINS", raising=False)
    answer = pool.check_nodes_on_dask_worker(["AlwaysSuccess", "TakeOff", "Photograph"])
    assert answer["missing"] == ["Photograph"] and answer["host"], answer
    monkeypatch.setenv("BTRUN_PLUGINS", "no_such_plugin_48:PLUGIN")
    answer = pool.check_nodes_on_dask_worker(["AlwaysSuccess"])
    assert (
        "plug-in 'no_such_plugin_48:PLUGIN' (BTRUN_PLUGINS) could not be loaded"
        in (answer["error"])
    ), answer


@pytest.mark.slow  # a Dask LocalCluster and a worker process start
def test_a_dask_cluster_without_the_plugin_is_refused_before_any_run(
    plugin_env, tmp_path, monkeypatch
) -> None:
    from dask.distributed import LocalCluster

    monkeypatch.delenv("BTRUN_PLUGINS", raising=False)
    with LocalCluster(
        n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:  # started without the plug-in's environment
        plugin_env(
            "dask48:PLUGIN",
            "from bt_engine import SyncActionNode, register, SUCCESS\n\n\n@register\n"
            "class Shutter(SyncActionNode):\n    def tick_impl(self):\n        return SUCCESS\n"
            + LEAF_PLUGIN_TAIL,
        )
        monkeypatch.setenv("PYTHONPATH", str(tmp_path))
        (tmp_path / "m.xml").write_text(wrap("<Shutter/>"))
        (tmp_path / "c.yaml").write_text("missions: [m.xml]\n")
        out = tmp_path / "out"
        with pytest.raises(pool.WorkersCannotRun, match=r"unknown node\(s\) Shutter"):
            run_campaign(str(tmp_path / "c.yaml"), str(out), scheduler=cluster.scheduler_address)
    assert not out.exists()
