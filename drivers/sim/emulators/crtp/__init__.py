"""A protocol-faithful software Crazyflie answering CRTP over UDP (cflib ``udp://`` links).

One module per CRTP port, like cflib: :mod:`.link_port` (15), :mod:`.platform_port` (13), :mod:`.log`
(5), :mod:`.param` (2), :mod:`.mem` (4), :mod:`.setpoints` (7 and 3), :mod:`.high_level`
(8), :mod:`.localization` (6), :mod:`.supervisor` (9); :mod:`.server` is the UDP server
stepping the simulated drone (:mod:`drivers.sim.drone`) in real time. Run it alone with
``btrun sim serve crazyflie --port 19850``; see docs/hardware.md.
"""

from drivers.sim.emulators.crtp.mocap import EmulatorMocap
from drivers.sim.emulators.crtp.server import CrtpEmulator
from drivers.sim.emulators.crtp.state import EmulatedCrazyflie, build_sim_drone

__all__ = ["CrtpEmulator", "EmulatedCrazyflie", "EmulatorMocap", "build_sim_drone"]
