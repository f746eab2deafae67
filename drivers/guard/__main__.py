"""``python -m drivers.guard --fd N``: the guard process (see :mod:`drivers.guard.server`)."""

from drivers.guard.server import main

raise SystemExit(main())
