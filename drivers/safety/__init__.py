"""The safety supervisor over the Vehicle API and a clock: :mod:`.policies` (faults,
actions, settings), :mod:`.monitor` (pure fault logic), :mod:`.supervisor` (observing and the
recovery flight). The runner hook that plugs it into a mission is ``nodes.safety_hook``."""
