"""The flight report of a run (``report.html`` and its plots), one module per concern.

* :mod:`nodes.report.metrics` - telemetry columns, per-motion tracking metrics, action spans;
* :mod:`nodes.report.plots` - the matplotlib figures (PNG files in the run folder);
* :mod:`nodes.report.perception` - the perception section (frames, crops, rankings);
* :mod:`nodes.report.html` - :func:`write_report`, which writes ``report.html``.

The submodules import each other directly, never this package; it only re-exports the entry
points callers use.
"""

from nodes.report.html import write_report
from nodes.report.metrics import motion_metrics, telemetry_arrays

__all__ = ["motion_metrics", "telemetry_arrays", "write_report"]
