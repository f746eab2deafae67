"""The guard: a process beside the mission process that owns what must outlive it.

:mod:`drivers.guard.server` is the process (the cflib link of a real or SITL Crazyflie, the
landing when the mission process hangs, crashes or is killed, the final ``summary.json``);
:mod:`drivers.guard.client` is the mission process's side of it (a
:class:`~drivers.vehicle.interfaces.Link` that forwards to the guard, and the heartbeat).
"""
