"""One drone, one mission: a lock per link address, held while a link to it is open.

A second ``btrun`` started on a drone that another one is flying had connected, taken the
drone over and fought the first over it: the first, having lost its telemetry, sent its
landing and then "motors off" to a drone the second was flying (it fell). The lock is an
``flock`` on a file named after the drone the link's URI reaches (:func:`link_identity`: a
Crazyflie's radio channel and address, whatever the dongle, data rate or the address's
case) in the system's temporary folder: the kernel releases it when the holder ends,
however it ends, so it never goes stale. The holder's pid, start time and URI are written
in it for the refusal's message. It covers one host: two computers with a radio each must
be kept apart by the operators.
"""

from __future__ import annotations

import binascii
import contextlib
import fcntl
import hashlib
import os
import tempfile
import time


class LinkInUse(ConnectionError):
    """The link's address is held by another process of this host."""


#: What cflib's radio driver (``cflib.crtp.radiodriver.RadioDriver.parse_uri``) takes for a
#: ``radio://`` URI that leaves them out: channel 2, address E7E7E7E7E7.
RADIO_DEFAULT_CHANNEL = 2
RADIO_DEFAULT_ADDRESS = 0xE7E7E7E7E7


def link_identity(uri: str) -> str:
    """The drone at the other end of ``uri``, as one text: two URIs with one identity reach
    one drone, however they are spelled.

    ``radio://DONGLE/CHANNEL/RATE/ADDRESS`` is read as cflib reads it: the channel a decimal
    number (2 when left out), the address up to 10 hex digits in any case, padded with zeros
    on the left (E7E7E7E7E7 when left out): ``radio channel 80, address E7E7E7E701``. That
    pair is the drone in the air: the dongle is left out (two dongles on one channel and
    address reach the same Crazyflie), and so is the data rate (a Crazyflie answers on one
    rate: two rates on one channel and address are one drone, or a mistake), as are a query
    (``?rate_limit=``) and anything after the address. Same address, other channel: another
    drone. Any other URI (``usb://``, ``udp://``, a ``radio://`` cflib could not read) is its
    text without surrounding spaces, its scheme and host in lower case."""
    text = uri.strip()
    scheme, sep, rest = text.partition("://")
    if not sep:
        return text
    scheme = scheme.lower()
    if scheme == "radio":
        radio = _radio_identity(rest)
        if radio is not None:
            return radio
    host, slash, path = rest.partition("/")
    return f"{scheme}://{host.lower()}{slash}{path}"


def _radio_identity(rest: str) -> str | None:
    """``radio channel C, address A`` of a radio URI's part after ``radio://`` (None: not
    one cflib reads)."""
    path = rest.partition("/")[2].partition("?")[0].partition("#")[0]
    parts = path.strip("/").split("/")
    try:
        channel = int(parts[0]) if parts[0] else RADIO_DEFAULT_CHANNEL
        address = RADIO_DEFAULT_ADDRESS
        if len(parts) > 2:
            raw = binascii.unhexlify(f"{parts[2]:0>10}")  # as cflib pads and reads it
            if len(raw) != 5:
                return None
            address = int.from_bytes(raw, "big")
    except (ValueError, binascii.Error):
        return None
    return f"radio channel {channel}, address {address:010X}"


def lock_path(uri: str) -> str:
    """The lock file of ``uri``: of its drone (:func:`link_identity`), so two spellings of
    one Crazyflie's address (``E7E7E7E701``, ``e7e7e7e701``; ``radio://0/80/2M`` and
    ``radio://0/80/2M/E7E7E7E7E7``; another dongle) share one lock."""
    digest = hashlib.sha1(link_identity(uri).encode("utf-8")).hexdigest()[:16]
    return os.path.join(tempfile.gettempdir(), "btrun-links", f"{digest}.lock")


class LinkLock:
    """Hold ``uri``'s lock from :meth:`acquire` to :meth:`release` (or the process's end)."""

    def __init__(self, uri: str) -> None:
        self.uri = uri
        self.path = lock_path(uri)
        self._fd: int | None = None

    def acquire(self) -> LinkLock:
        """Take the lock or raise :class:`LinkInUse` naming who holds it."""
        os.makedirs(os.path.dirname(self.path), exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_holder(fd)
            os.close(fd)
            raise LinkInUse(
                f"{self.uri}: in use by another btrun ({holder}): one drone flies one mission "
                "at a time; wait for it to land, or stop it"
            ) from None
        except OSError:
            os.close(fd)
            raise
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)
            stamp = time.strftime("%Y-%m-%d %H:%M:%S")
            held = f"pid {os.getpid()}, since {stamp}, on {self.uri.strip()}"[:190]
            os.pwrite(fd, f"{held}\n".encode("utf-8", "replace"), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        """Let the address go (idempotent)."""
        fd, self._fd = self._fd, None
        if fd is not None:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)
            with contextlib.suppress(OSError):
                os.close(fd)  # closing the last descriptor releases the flock


def _read_holder(fd: int) -> str:
    try:
        text = os.pread(fd, 200, 0).decode("utf-8", "replace").strip()
    except OSError:
        text = ""
    return text or "a process of this host"
