"""The site store: every run's inventory rows (and, on PostgreSQL, the galleries) in one
database, SQLite by default or PostgreSQL for a site with several ground stations.

Imports nothing of btrun (the bottom layer beside ``bt_engine``): ``nodes`` records into it
and runs its commands, ``perception.gallery`` reaches PostgreSQL through :mod:`store.db`.
See ``docs/store.md``.
"""

from store.db import StoreError, parse_url, redact
from store.inventory import InventoryStore, default_url, disabled, open_store

__all__ = [
    "InventoryStore",
    "StoreError",
    "default_url",
    "disabled",
    "open_store",
    "parse_url",
    "redact",
]
