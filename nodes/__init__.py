"""btrun's drone leaves: importing this package registers every leaf with the engine.

The package only imports its leaf modules; the plug-in object the engine talks to (rig
loading, safety hook, report, extra commands) is :data:`nodes.plugin.PLUGIN`.
"""

from nodes import (  # noqa: F401  (registration)
    conditions,
    energy,
    flight,
    geometry,
    inventory,
    landing_pads,
    perception,
    reactive_scan,
    safety,
    scan_face,
    sweep,
    sweep_energy,
    sweep_plan,
)
