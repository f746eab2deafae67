"""``btrun console``: the operator console, a web page over the runs folder.

:mod:`~nodes.console.cli` (the command), :mod:`~nodes.console.app` (the Starlette
application), :mod:`~nodes.console.paths` (the only way into the disk),
:mod:`~nodes.console.runs` (what a run folder holds), :mod:`~nodes.console.live` (a running
run as events), :mod:`~nodes.console.review` (decisions and the gallery),
:mod:`~nodes.console.export` (CSV / XLSX for a WMS); ``static/`` holds every asset.
"""
