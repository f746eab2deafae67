"""``btrun campaign``: fly missions x rigs x worlds x seeds x settings x faults, at scale.

A campaign file (YAML, ``docs/campaigns.md``) names what to fly and what to measure. The
engine here knows no drone: each run is an in-process ``btrun run`` (the plug-in contract
and :mod:`bt_engine.run_cmd`) in a worker process, on a local pool or a Dask cluster.

Modules, in the order a campaign goes through them:

* :mod:`~bt_engine.campaign.spec` - the file's keys, read with located problems
  (:mod:`~bt_engine.campaign.yaml_reader`: YAML values with their places;
  :mod:`~bt_engine.campaign.model`: the campaign, its draws and fault cases, its limits);
* :mod:`~bt_engine.campaign.rows` - the rows (one per run), seeded draws, row keys;
* :mod:`~bt_engine.campaign.check` - missions and settings checked with the plug-in;
* :mod:`~bt_engine.campaign.pool` and :mod:`~bt_engine.campaign.worker` - where runs execute;
* :mod:`~bt_engine.campaign.metrics` - values read from each run's ``summary.json``;
* :mod:`~bt_engine.campaign.results` - per-row records, ``results.parquet``/``.csv`` (plain
  column names; ``columns.csv`` maps them back);
* :mod:`~bt_engine.campaign.report` - ``report.html`` and the terminal summary table;
* :mod:`~bt_engine.campaign.execution` - :func:`run_campaign`, which ties them together;
* :mod:`~bt_engine.campaign.command` - the ``btrun campaign`` command line.
"""

from __future__ import annotations

from typing import Any

#: name -> module of the public API (imported on first use: ``python -m
#: bt_engine.campaign.worker`` must not import the rest of the package first)
_API = {
    "Campaign": "spec",
    "load_campaign": "spec",
    "CampaignRun": "execution",
    "run_campaign": "execution",
    "comparable": "results",
    "read_results": "results",
}
__all__ = sorted(_API)


def __getattr__(name: str) -> Any:
    if name not in _API:
        raise AttributeError(f"module 'bt_engine.campaign' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(f"bt_engine.campaign.{_API[name]}"), name)
