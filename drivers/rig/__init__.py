"""Rig files and the platform factory (the top floor of drivers/): :mod:`.schema` (every
setting), :mod:`.loader` (validate, override), :mod:`.factory` (rig -> platform),
:mod:`.paths` (repository paths), :mod:`.serve` (the emulators alone), :mod:`.harness`
(a lock-step platform for tests and scripts)."""
