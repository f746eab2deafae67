"""The runs folder as the console's only window on the disk.

Every path the console reads comes from a URL, so every one goes through :class:`RunsRoot`:
a run is one folder name directly under the root, a file is a list of plain name components
under a run, and both are resolved with :func:`os.path.realpath` and must stay inside the
root's real path. ``..``, ``.``, empty components, absolute paths, backslashes, NUL bytes
and symbolic links that lead out of the root are refused; only regular files of the types a
page shows are served, up to :data:`MAX_FILE_BYTES`.
"""

from __future__ import annotations

import os
import re
import stat

#: a run or drone folder name, a file name component: letters and digits of any script,
#: ``_``, ``.``, ``-``, ``+`` and spaces inside (``btrun run --out "aisle 3"``); never a
#: separator, NUL or a name of dots only
NAME = re.compile(r"\w[\w .+-]{0,127}")
#: file types a page may load from a run folder (crops, reports, rows), and their media types
MEDIA_TYPES = {
    ".png": "image/png",
    ".jpg": "image/jpeg",
    ".jpeg": "image/jpeg",
    ".csv": "text/csv; charset=utf-8",
    ".json": "application/json",
    ".html": "text/html; charset=utf-8",
}
#: the largest file served from a run folder, bytes
MAX_FILE_BYTES = 32_000_000
#: the deepest file under a run (``drones/cf1/places/A-01-1/block_1.png`` has 5 parts)
MAX_DEPTH = 6


class PathRefused(Exception):
    """A name or path the console will not read (``status``: the HTTP status to answer)."""

    def __init__(self, message: str, status: int = 404) -> None:
        super().__init__(message)
        self.status = status


def check_name(name: str, what: str = "run") -> str:
    """``name`` if it is one plain folder or file name (no separator, not ``.``/``..``),
    else :class:`PathRefused` (400)."""
    if not isinstance(name, str) or not NAME.fullmatch(name) or ".." in name:
        raise PathRefused(f"{what} name {name!r:.80} refused", 400)
    return name


def inside(root: str, path: str) -> bool:
    """Whether the real path ``path`` is ``root`` or below it (both real paths)."""
    return path == root or path.startswith(root.rstrip(os.sep) + os.sep)


def plain(path: str) -> bool:
    """Whether ``path``, built under a run folder's real path, is reached without a symbolic
    link on the way: the console reads a run's own files only so, so that none leads out of
    the runs folder (btrun writes no links in a run folder)."""
    return os.path.realpath(path) == os.path.abspath(path)


class RunsRoot:
    """The runs folder (real path) and the checked ways into it."""

    def __init__(self, root: str) -> None:
        self.given = root
        self.root = os.path.realpath(root)

    def run_dir(self, name: str) -> str:
        """The real path of run ``name`` (a folder directly under the root, or a link to one
        inside it); :class:`PathRefused` otherwise."""
        check_name(name)
        real = os.path.realpath(os.path.join(self.root, name))
        if not inside(self.root, real) or real == self.root:
            raise PathRefused(f"run {name!r} leads outside the runs folder", 403)
        if not os.path.isdir(real):
            raise PathRefused(f"no run {name!r}")
        return real

    def sub_dir(self, run_dir: str, parts: list[str]) -> str:
        """A folder under ``run_dir`` (``["drones", "cf1"]``), checked like a file."""
        for p in parts:
            check_name(p, "folder")
        real = os.path.realpath(os.path.join(run_dir, *parts))
        if not inside(self.root, real) or not inside(run_dir, real):
            raise PathRefused("folder leads outside the run", 403)
        return real

    def file(self, name: str, rel: str) -> tuple[str, str]:
        """The real path and media type of file ``rel`` (``/``-separated) of run ``name``;
        :class:`PathRefused` for anything but a regular file of a served type inside the run,
        no larger than :data:`MAX_FILE_BYTES`."""
        run = self.run_dir(name)
        if not isinstance(rel, str) or "\\" in rel or "\x00" in rel or rel.startswith("/"):
            raise PathRefused("file path refused", 400)
        parts = rel.split("/")
        if len(parts) > MAX_DEPTH:
            raise PathRefused("file path too deep", 400)
        for p in parts:
            check_name(p, "file")
        media = MEDIA_TYPES.get(os.path.splitext(parts[-1])[1].lower())
        if media is None:
            raise PathRefused("file type not served", 404)
        real = os.path.realpath(os.path.join(run, *parts))
        if not inside(self.root, real) or not inside(run, real):
            raise PathRefused("file leads outside the run", 403)
        try:
            st = os.stat(real)
        except OSError:
            raise PathRefused("no such file") from None
        if not stat.S_ISREG(st.st_mode):
            raise PathRefused("not a regular file", 404)
        if st.st_size > MAX_FILE_BYTES:
            raise PathRefused("file too large to serve", 413)
        return real, media
