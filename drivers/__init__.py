"""Everything between a leaf and a drone, by layer (see docs/architecture.md).

* :mod:`drivers.vehicle` - the Vehicle API: all a leaf may touch.
* :mod:`drivers.safety` - fault monitor, policies and recovery flight over the Vehicle API.
* :mod:`drivers.crazyflie` - real hardware: cflib link, motion capture, AI-deck stream.
* :mod:`drivers.sim` - the simulated drone, sensors, world, renderers and emulators.
* :mod:`drivers.rig` - rig files and the platform factory: the only place that knows every
  platform.
* :mod:`drivers.settings` - the small typed-settings language of rig and world files;
  :mod:`drivers.settings_yaml` reads and checks such files with located problems.
"""
