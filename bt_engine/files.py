"""Reading mission files: bounded in size, UTF-8, problems located instead of raised."""

from __future__ import annotations

import os

from bt_engine.spec import Loc, Problem

#: The largest mission (or included) file read, in bytes.
MAX_FILE_BYTES = 5_000_000


def read_text(path: str, problems: list[Problem], loc: Loc | None = None) -> str | None:
    """The text of ``path``, or None with a problem appended (too large, unreadable, not
    UTF-8) located at ``loc`` (default: the file's start)."""
    where = loc or Loc(path, 1, 1)
    try:
        size = os.path.getsize(path)
        if size > MAX_FILE_BYTES:
            problems.append(Problem(where, f"file is {size} bytes; the limit is {MAX_FILE_BYTES}"))
            return None
        with open(path, "rb") as f:
            data = f.read()
    except OSError as exc:
        problems.append(Problem(where, f"cannot read {path}: {exc.strerror or exc}"))
        return None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        problems.append(Problem(where, f"file is not UTF-8 text (byte {exc.start})"))
        return None
