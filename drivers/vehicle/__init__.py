"""The Vehicle API: everything a leaf may touch.

:mod:`.vehicle` (the :class:`~drivers.vehicle.vehicle.Vehicle`), :mod:`.config` (its
settings), :mod:`.types`, :mod:`.interfaces` (link, pose source and camera protocols the
platforms implement), :mod:`.platform` (the platform protocol the runner drives),
:mod:`.progress`, :mod:`.health`, :mod:`.battery`, :mod:`.angles`, :mod:`.trajectory`
(reference generation) and :mod:`.faults` (fault injection). Imports no platform.
"""
