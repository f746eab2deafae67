"""Reading mission files (and campaign files and the files they list): bounded in size,
UTF-8, problems located instead of raised. :func:`read_bytes` is the bounded read itself,
:func:`read_text` decodes it, :func:`file_kind` names what a path is when it is not a
regular file, :func:`open_regular` opens one for a caller that reads it line by line (a tick
log).

Only regular files are read: a named pipe would block the reader forever and a device such
as ``/dev/zero`` never ends, so both are refused before they are opened (symbolic links are
resolved first), and no more than :data:`MAX_FILE_BYTES` + 1 bytes are ever read.
"""

from __future__ import annotations

import os
import stat
from typing import BinaryIO

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


class NotRegularFile(Exception):
    """A path that is not a regular file (a FIFO, a device, a folder): the message says what
    it is."""


def open_regular(path: str, what: str = "missions") -> BinaryIO:
    """Open ``path`` (symbolic links followed) for reading in binary if it is a regular file:
    checked before opening (a FIFO would block the open) and again on the open file (it is
    opened with ``O_NONBLOCK``: a file swapped for a FIFO in between is refused too). Raises
    :class:`NotRegularFile` (``what`` names the files in the message) or ``OSError``.
    Nothing is read: the caller bounds what it reads."""
    real = os.path.realpath(path)
    why = _not_regular(path, os.stat(real).st_mode, what)
    if why is not None:
        raise NotRegularFile(why)
    fd = os.open(real, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
    f = os.fdopen(fd, "rb")
    why = _not_regular(path, os.fstat(f.fileno()).st_mode, what)
    if why is not None:
        f.close()
        raise NotRegularFile(why)
    return f


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
        with open_regular(path, what) as f:
            size = os.fstat(f.fileno()).st_size
            if size > cap:
                problems.append(Problem(where, f"file is {size} bytes; the limit is {cap}"))
                return None
            data = f.read(cap + 1)
    except NotRegularFile as exc:
        problems.append(Problem(where, str(exc)))
        return None
    except (OSError, ValueError) as exc:  # ValueError: a path holding a NUL byte
        problems.append(
            Problem(where, f"cannot read {path}: {getattr(exc, 'strerror', None) or exc}")
        )
        return None
    if len(data) > cap:
        problems.append(Problem(where, f"file is larger than {cap} bytes (the limit); not read"))
        return None
    return data


def read_text(
    path: str,
    problems: list[Problem],
    loc: Loc | None = None,
    *,
    what: str = "missions",
    limit: int | None = None,
) -> str | None:
    """The text of ``path``, or None with a problem appended (not a regular file, too large,
    unreadable, not UTF-8) located at ``loc`` (default: the file's start); ``what`` and
    ``limit`` as for :func:`read_bytes`."""
    data = read_bytes(path, problems, loc, what=what, limit=limit)
    if data is None:
        return None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        problems.append(
            Problem(loc or Loc(path, 1, 1), f"file is not UTF-8 text (byte {exc.start})")
        )
        return None


def write_output(path: str, text: str) -> str | None:
    """Write a command's output file ``path`` (a Groot2 palette, a converted mission, a dot
    file); return why it could not be written (None: written). Only a regular file (or a
    new one) is written: a FIFO would block the command, a device or folder is no output."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        return f"cannot write {path}: {exc.strerror or exc}"
    if st is not None and not stat.S_ISREG(st.st_mode):
        kind = "a folder" if stat.S_ISDIR(st.st_mode) else "not a regular file"
        return f"cannot write {path}: {kind}"
    try:
        with open(path, "w", encoding="utf-8") as f:
            f.write(text)
    except OSError as exc:
        return f"cannot write {path}: {exc.strerror or exc}"
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
