"""The simulator: one model per module (drone dynamics, firmware controller, estimator,
battery, wind, sensors, camera, world, link, platform), :mod:`.renderers` (camera renderers
by name) and :mod:`.emulators` (a software Crazyflie over CRTP/UDP, an AI-deck over CPX/TCP,
and SITL sessions that run both)."""
