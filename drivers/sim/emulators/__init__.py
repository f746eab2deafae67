"""Devices on loopback for the real drivers: :mod:`.crtp` (a software Crazyflie answering
CRTP over UDP), :mod:`.aideck` (the AI-deck image stream over CPX/TCP) and :mod:`.sitl`
(both, stepping one simulated drone in real time)."""
