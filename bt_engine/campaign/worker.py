"""One campaign run in a worker process, and the worker process's main loop.

:func:`run_row` is the in-process equivalent of ``btrun run MISSION --rig R --seed S --set
k=v ... --out RUNDIR --quiet`` (:func:`bt_engine.run_cmd.prepare`, ``fly``, ``finish``):
it then reads the run's ``summary.json``, computes the campaign's metrics and keeps or
deletes the run folder (the flight report is written only for a folder that is kept).

``python -m bt_engine.campaign.worker`` is a worker process: it loads the plug-ins once
(models and imports stay loaded between runs), keeps numerical libraries to one thread,
then reads one JSON request per line on stdin and answers one JSON line per run. Its own
stdout is the answer channel; whatever a run prints goes to the run folder's
``console.log``. :mod:`bt_engine.campaign.pool` starts and supervises these processes.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import sys
import time
import traceback
from typing import Any

from bt_engine.campaign.metrics import metric_from_data

#: Environment every worker process starts with: one thread per numerical library
#: (torch, OpenMP, BLAS), so N workers use N cores and never fight over them.
ONE_THREAD_ENV = {
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "NUMEXPR_NUM_THREADS": "1",
}
#: Statuses of a run that finished (the mission's own) and of one that did not.
RUN_STATUSES = ("SUCCESS", "FAILURE", "ABORTED")
CAMPAIGN_STATUSES = ("CRASHED", "TIMEOUT")


def keep_folder(policy: str, status: str) -> bool:
    """Whether a run folder is kept: ``all``, ``none``, or ``failed`` (not SUCCESS)."""
    return policy == "all" or (policy == "failed" and status != "SUCCESS")


def write_flight_report(policy: str, keep: str, status: str) -> bool:
    """Whether a run writes its flight report: only into a folder that is kept, and then
    always (``kept``), only if it did not succeed (``failed``) or never (``none``)."""
    if not keep_folder(keep, status):
        return False
    return policy == "kept" or (policy == "failed" and status != "SUCCESS")


def _one_torch_thread() -> None:
    torch = sys.modules.get("torch")  # only if a plug-in loaded it: never import it here
    if torch is not None:
        try:
            torch.set_num_threads(1)
        except Exception:  # pragma: no cover - a torch without threads control
            pass


def _args(payload: dict[str, Any]) -> argparse.Namespace:
    """The ``btrun run`` arguments of a row."""
    return argparse.Namespace(
        mission=payload["mission_path"],
        rig=payload.get("rig_path"),
        set=list(payload.get("sets", ())),
        seed=int(payload["seed"]),
        rate=float(payload.get("rate_hz", 50.0)),
        out=payload["run_dir"],
        max_time=None if payload.get("max_time_s") is None else float(payload["max_time_s"]),
        realtime=None,
        tick_budget=None,
        quiet=True,
        no_report=True,
        no_mcap=not payload.get("mcap", False),
        groot=None,
        groot_address=None,
        include_path=list(payload.get("include_paths", ())),
    )


def run_row(payload: dict[str, Any]) -> dict[str, Any]:
    """Fly one row and return its result: ``status``, ``reason``, ``metrics``, ``wall_s``
    (the whole row), ``run_s`` (its ``btrun run`` part: prepare, fly, finish), ``run_dir``
    (empty when the folder was not kept). An exception is a ``CRASHED`` row
    (its traceback in the folder's ``campaign_error.log``)."""
    from bt_engine.loading import default_include_paths
    from bt_engine.run_cmd import finish, fly, prepare, release

    t0 = time.perf_counter()
    _one_torch_thread()
    run_dir = payload["run_dir"]
    keep = payload.get("keep", "failed")
    shutil.rmtree(run_dir, ignore_errors=True)  # what an interrupted attempt left
    os.makedirs(run_dir, exist_ok=True)
    summary: dict[str, Any] = {}
    run_s = None
    args = _args(payload)
    with (
        open(os.path.join(run_dir, "console.log"), "w", encoding="utf-8") as console,
        contextlib.redirect_stdout(console),
        contextlib.redirect_stderr(console),
    ):
        try:
            with default_include_paths(args.include_path):
                t_run = time.perf_counter()
                run = prepare(args)
                try:
                    runner, result = fly(run)
                    args.no_report = not write_flight_report(
                        payload.get("flight_reports", "kept"), keep, result.status
                    )
                    finish(run, runner, result)
                finally:
                    if run.groot is not None:  # pragma: no cover - never set here
                        run.groot.close()
                    release(run.target, *run.hooks, written=run.summary is not None)
                run_s = time.perf_counter() - t_run
            with open(os.path.join(run_dir, "summary.json"), encoding="utf-8") as f:
                summary = json.load(f)
            status, reason = summary.get("status", "CRASHED"), summary.get("reason", "")
        except (Exception, SystemExit) as exc:  # the row's failure, not the worker's
            with open(os.path.join(run_dir, "campaign_error.log"), "w", encoding="utf-8") as f:
                f.write(traceback.format_exc())
            status, reason = "CRASHED", f"{type(exc).__name__}: {exc}".strip()
    metrics: dict[str, Any] = {}
    for name, source in payload.get("metrics", ()):
        metrics[name] = metric_from_data(name, source).evaluate(summary) if summary else None
    kept = keep_folder(keep, status)
    if not kept:
        shutil.rmtree(run_dir, ignore_errors=True)
    return {
        "key": payload["key"],
        "status": status,
        "reason": reason,
        "metrics": metrics,
        "wall_s": round(time.perf_counter() - t0, 4),
        "run_s": round(run_s, 4) if run_s is not None else None,  # btrun run's own part
        "run_dir": run_dir if kept else "",
        "pid": os.getpid(),
    }


def check_nodes(ids: list[str]) -> dict[str, Any]:
    """What a worker process here lacks to run missions made of the node IDs ``ids``:
    ``{"missing": [...]}`` (empty: nothing), or ``{"error": ...}`` if a plug-in named
    here does not load."""
    from bt_engine.plugins import PluginError, load_plugins
    from bt_engine.registry import REGISTRY

    try:
        load_plugins()
    except PluginError as exc:
        return {"error": str(exc)}
    return {"missing": [i for i in ids if i not in REGISTRY]}


def main() -> int:
    """The worker process: ``ready``, then one answer line per request line until EOF.
    ``--check-nodes JSON_IDS``: answer :func:`check_nodes` in one line and end."""
    answers = os.fdopen(os.dup(1), "w", buffering=1, encoding="utf-8")
    os.dup2(2, 1)  # stray prints (C libraries included) go to the log, not the channel
    sys.stdout = sys.stderr
    os.environ.update(ONE_THREAD_ENV)
    if sys.argv[1:2] == ["--check-nodes"]:
        answers.write(json.dumps(check_nodes(json.loads(sys.argv[2]))) + "\n")
        return 0
    from bt_engine.plugins import load_plugins

    load_plugins()  # imports the leaves (and whatever the plug-ins load) once
    answers.write(json.dumps({"ready": True, "pid": os.getpid()}) + "\n")
    for line in sys.stdin:
        if not line.strip():
            continue
        request = json.loads(line)
        if request.get("stop"):
            break
        answers.write(json.dumps({"result": run_row(request["row"])}) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
