"""The guard's wire: one JSON array per message over a Unix ``SOCK_SEQPACKET`` socket pair.

A sequenced-packet socket keeps message boundaries and order, needs no framing, and tells
the other side at once when a process dies (the kernel closes its end: ``recv`` returns
``b""``), which is the fastest possible crash detection. Each message is a JSON array whose
first element is its kind (one letter or a short word); see :mod:`drivers.guard.server`
for the kinds.
"""

from __future__ import annotations

import json
import socket
from typing import Any

#: The largest message either side sends (a health or stats reply; set-points are ~80 B).
MAX_MESSAGE_BYTES = 65_536


def socket_pair() -> tuple[socket.socket, socket.socket]:
    """A connected pair of ``AF_UNIX``/``SOCK_SEQPACKET`` sockets (mission side, guard side)."""
    return socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)


def encode(message: list[Any]) -> bytes:
    """``message`` as compact JSON bytes (non-finite floats become null: a guard never sees
    NaN as a set-point)."""
    return json.dumps(_finite(message), separators=(",", ":"), allow_nan=False).encode()


def decode(data: bytes) -> list[Any] | None:
    """The message in ``data``, or None if it is not a JSON array (ignored by the reader)."""
    try:
        msg = json.loads(data)
    except (ValueError, UnicodeDecodeError):
        return None
    return msg if isinstance(msg, list) and msg and isinstance(msg[0], str) else None


def _finite(value: Any) -> Any:
    if isinstance(value, float):
        return value if value == value and abs(value) != float("inf") else None
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _finite(v) for k, v in value.items()}
    return value
