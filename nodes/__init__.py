"""btrun's drone leaves, registered with the engine when this package is imported.

This package is btrun's plug-in (entry point ``btrun.plugins``): importing it registers the
flight actions and vehicle conditions, and it gives the CLI the rig loader (simulator or
real drone), the safety supervisor and the flight report writer.
"""

from nodes import conditions, flight, geometry, safety  # noqa: F401  (registration)


def load_rig(path, overrides=None):
    """Load and validate a rig file (see :func:`drivers.rig.load_rig`)."""
    from drivers.rig import load_rig as _load

    return _load(path, overrides)


def make_supervisor(rig, platform, mission):
    """The safety supervisor hook of a run (see :mod:`drivers.safety`), or None."""
    if getattr(platform, "vehicle", None) is None:
        return None
    from drivers.safety import SafetySupervisor

    return SafetySupervisor.from_rig(rig, platform, mission)


def write_report(run_dir, trace, summary, mission):
    """Write the flight report of a run; return its path (None if there is nothing to plot)."""
    try:
        from nodes.report import write_report as _write
    except ImportError:  # pragma: no cover - report module not installed
        return None
    return _write(run_dir, trace, summary, mission)
