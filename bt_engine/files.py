"""Reading mission files: bounded in size, UTF-8, problems located instead of raised.

Only regular files are read: a named pipe would block the reader forever and a device such
as ``/dev/zero`` never ends, so both are refused before they are opened (symbolic links are
resolved first), and no more than :data:`MAX_FILE_BYTES` + 1 bytes are ever read.
"""

from __future__ import annotations

import os
import stat

from bt_engine.spec import Loc, Problem

#: The largest mission (or included) file read, in bytes.
MAX_FILE_BYTES = 5_000_000

_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def _not_regular(path: str, mode: int) -> str | None:
    """Why ``mode`` is not a regular file's, or None if it is one."""
    if stat.S_ISREG(mode):
        return None
    kind = next((name for test, name in _KINDS if test(mode)), "not a regular file")
    return f"{path} is {kind}, not a regular file; missions are read from ordinary files"


def read_text(path: str, problems: list[Problem], loc: Loc | None = None) -> str | None:
    """The text of ``path``, or None with a problem appended (not a regular file, too large,
    unreadable, not UTF-8) located at ``loc`` (default: the file's start)."""
    where = loc or Loc(path, 1, 1)
    try:
        real = os.path.realpath(path)
        st = os.stat(real)
        why = _not_regular(path, st.st_mode)  # before opening: a FIFO would block
        if why is not None:
            problems.append(Problem(where, why))
            return None
        if st.st_size > MAX_FILE_BYTES:
            problems.append(
                Problem(where, f"file is {st.st_size} bytes; the limit is {MAX_FILE_BYTES}")
            )
            return None
        # O_NONBLOCK: should the file be swapped for a FIFO after the check, open() still
        # returns at once, and fstat() below refuses it.
        fd = os.open(real, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
        with os.fdopen(fd, "rb") as f:
            why = _not_regular(path, os.fstat(f.fileno()).st_mode)
            if why is not None:
                problems.append(Problem(where, why))
                return None
            data = f.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        problems.append(Problem(where, f"cannot read {path}: {exc.strerror or exc}"))
        return None
    if len(data) > MAX_FILE_BYTES:
        problems.append(
            Problem(where, f"file is larger than {MAX_FILE_BYTES} bytes (the limit); not read")
        )
        return None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        problems.append(Problem(where, f"file is not UTF-8 text (byte {exc.start})"))
        return None


def atomic_write_text(path: str, text: str) -> None:
    """Write ``text`` to ``path`` so that a crash at any moment leaves either the old file or
    the new one, whole: a temporary file beside it, flushed to disk, then renamed over it
    (and the folder entry flushed too)."""
    folder = os.path.dirname(os.path.abspath(path))
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # pragma: no cover - a platform without directory handles
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
