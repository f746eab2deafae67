"""Where the repository's own files are: its root, the default rig and the default world.

The one place that knows the checkout's layout; everything else asks here.
"""

from __future__ import annotations

import os

#: The repository (or installed source tree) root: the folder holding ``rigs/`` and ``worlds/``.
REPO_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
#: The rig a run uses when none is given: the built-in lock-step simulator.
DEFAULT_RIG = os.path.join(REPO_ROOT, "rigs", "sim.yaml")
#: The world of the default rig: the warehouse with the five pallets of [study]
#: (docs/references.md).
DEFAULT_WORLD = os.path.join(REPO_ROOT, "worlds", "warehouse.yaml")
