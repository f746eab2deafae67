"""One drone, one mission: a lock per link address, held while a link to it is open.

A second ``btrun`` started on a drone that another one is flying had connected, taken the
drone over and fought the first over it: the first, having lost its telemetry, sent its
landing and then "motors off" to a drone the second was flying (it fell). The lock is an
``flock`` on a file named after the link's URI in the system's temporary folder: the kernel
releases it when the holder ends, however it ends, so it never goes stale. The holder's pid
and start time are written in it for the refusal's message. It covers one host: two
computers with a radio each must be kept apart by the operators.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import tempfile
import time


class LinkInUse(ConnectionError):
    """The link's address is held by another process of this host."""


def lock_path(uri: str) -> str:
    """The lock file of ``uri`` (its address as written, without surrounding spaces)."""
    digest = hashlib.sha1(uri.strip().encode("utf-8")).hexdigest()[:16]
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
            os.pwrite(fd, f"pid {os.getpid()}, since {stamp}\n".encode(), 0)
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
