"""Reading mission files (and campaign files and the files they list): bounded in size,
UTF-8, problems located instead of raised. :func:`read_bytes` is the bounded read itself,
:func:`read_text` decodes it, :func:`file_kind` names what a path is when it is not a
regular file.

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


def _not_regular(path: str, mode: int, what: str = "missions") -> str | None:
    """Why ``mode`` is not a regular file's, or None if it is one."""
    if stat.S_ISREG(mode):
        return None
    kind = next((name for test, name in _KINDS if test(mode)), "not a regular file")
    return f"{path} is {kind}, not a regular file; {what} are read from ordinary files"


def file_kind(path: str) -> str | None:
    """What ``path`` is when it exists but is not a regular file (symbolic links followed):
    ``"a named pipe (FIFO)"``, ``"a character device"``, ...; None for a regular file or a
    path that does not exist (or cannot be examined)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None
    if stat.S_ISREG(mode):
        return None
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def read_bytes(
    path: str,
    problems: list[Problem],
    loc: Loc | None = None,
    *,
    what: str = "missions",
    limit: int | None = None,
) -> bytes | None:
    """The bytes of ``path``, or None with a problem appended (not a regular file, too large,
    unreadable) located at ``loc`` (default: the file's start). At most ``limit`` (default
    :data:`MAX_FILE_BYTES`) + 1 bytes are read; ``what`` names the files in the message of
    a refusal (``missions are read from ordinary files``)."""
    where = loc or Loc(path, 1, 1)
    cap = MAX_FILE_BYTES if limit is None else limit
    try:
        real = os.path.realpath(path)
        st = os.stat(real)
        why = _not_regular(path, st.st_mode, what)  # before opening: a FIFO would block
        if why is not None:
            problems.append(Problem(where, why))
            return None
        if st.st_size > cap:
            problems.append(Problem(where, f"file is {st.st_size} bytes; the limit is {cap}"))
            return None
        # O_NONBLOCK: should the file be swapped for a FIFO after the check, open() still
        # returns at once, and fstat() below refuses it.
        fd = os.open(real, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
        with os.fdopen(fd, "rb") as f:
            why = _not_regular(path, os.fstat(f.fileno()).st_mode, what)
            if why is not None:
                problems.append(Problem(where, why))
                return None
            data = f.read(cap + 1)
    except OSError as exc:
        problems.append(Problem(where, f"cannot read {path}: {exc.strerror or exc}"))
        return None
    if len(data) > cap:
        problems.append(Problem(where, f"file is larger than {cap} bytes (the limit); not read"))
        return None
    return data


def read_text(
    path: str, problems: list[Problem], loc: Loc | None = None, *, what: str = "missions"
) -> str | None:
    """The text of ``path``, or None with a problem appended (not a regular file, too large,
    unreadable, not UTF-8) located at ``loc`` (default: the file's start)."""
    data = read_bytes(path, problems, loc, what=what)
    if data is None:
        return None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        problems.append(
            Problem(loc or Loc(path, 1, 1), f"file is not UTF-8 text (byte {exc.start})")
        )
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
