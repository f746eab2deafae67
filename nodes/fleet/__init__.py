"""``btrun fleet``: several drones, each with its own mission instance, in one run.

* :mod:`nodes.fleet.spec` - the fleet file (``fleets/*.yaml``): located validation of the
  drones, pads, URIs and start poses;
* :mod:`nodes.fleet.plan` - splitting the places between the drones;
* :mod:`nodes.fleet.run` - building every drone's run on one clock, flying them in
  lock-step (:class:`bt_engine.fleet.FleetRunner`) with the airspace and the separation
  guard (:mod:`drivers.safety.airspace`), the merged inventory, summary and report.

See docs/fleets.md.
"""
