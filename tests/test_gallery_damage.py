"""Damaged galleries get a one-line explanation and exit 2, nothing is written, and a gallery
being created is never left half-made."""

from __future__ import annotations

import hashlib
import os
import sqlite3

import numpy as np
import pytest

from bt_engine.cli import main
from perception.gallery import Gallery, GalleryError

DIM = 8


def _gallery(path) -> str:
    g = Gallery.create(str(path), model_version="test-v1", dim=DIM)
    g.enrol("1A", np.ones((3, DIM), np.float32))
    g.enrol("2B", np.zeros((3, DIM), np.float32))
    g.close()
    return str(path)


def _sha(path: str) -> str:
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def _damage(path: str, sql: str, *args) -> None:
    conn = sqlite3.connect(path)
    with conn:
        conn.execute(sql, args)
    conn.close()


DAMAGE = {
    "wrong dimension": ("UPDATE meta SET value = '16' WHERE key = 'dim'", (), "expected 192"),
    "short blob": (
        "UPDATE entries SET embeddings = ? WHERE identity = '2B'",
        (b"\x00" * 10,),
        "holds 10 bytes",
    ),
    "garbage threshold": (
        "INSERT OR REPLACE INTO meta VALUES ('max_distance', 'banana')",
        (),
        "max_distance",
    ),
    "negative threshold": (
        "INSERT OR REPLACE INTO meta VALUES ('min_margin', '-3')",
        (),
        "min_margin",
    ),
    "missing table": ("DROP TABLE crops", (), "table crops missing"),
    "bad dim": ("UPDATE meta SET value = '-4' WHERE key = 'dim'", (), "embedding size -4"),
}


@pytest.mark.parametrize("case", sorted(DAMAGE))
def test_a_damaged_gallery_is_explained_in_one_line(tmp_path, capsys, case: str) -> None:
    path = _gallery(tmp_path / "g.sqlite")
    sql, args, expect = DAMAGE[case]
    _damage(path, sql, *args)
    before = _sha(path)
    with pytest.raises(GalleryError, match=expect.replace("(", r"\(")):
        Gallery.open(path)
    assert main(["gallery", "list", path]) == 2
    err = capsys.readouterr().err
    assert expect in err and "Traceback" not in err and err.count("\n") <= 2, err
    assert _sha(path) == before, "nothing may be written to a damaged gallery"


def test_a_read_only_gallery_refuses_writes_with_a_clear_error(tmp_path) -> None:
    path = _gallery(tmp_path / "g.sqlite")
    before = _sha(path)
    conn = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    g = Gallery(conn, path, "test-v1", DIM)
    with pytest.raises(GalleryError, match="cannot enrol 3C .*read-only"):
        g.enrol("3C", np.ones((3, DIM), np.float32))
    with pytest.raises(GalleryError, match="cannot remove 1A"):
        g.remove("1A")
    conn.close()
    assert _sha(path) == before


def test_creating_a_gallery_is_atomic(tmp_path, monkeypatch) -> None:
    path = str(tmp_path / "new.sqlite")
    import perception.gallery as gallery_mod

    def killed(*_a, **_k):  # the process dies while the schema is being written
        raise KeyboardInterrupt

    monkeypatch.setattr(gallery_mod, "write_schema", killed)
    with pytest.raises(KeyboardInterrupt):
        Gallery.create(path, model_version="test-v1", dim=DIM)
    monkeypatch.undo()
    assert not os.path.exists(path), "a half-made gallery must not exist under its name"
    g = Gallery.create(path, model_version="test-v1", dim=DIM)  # and creating works after
    assert len(g) == 0
    g.close()


def test_creating_in_a_missing_folder_is_a_clear_error(tmp_path) -> None:
    with pytest.raises(GalleryError, match="cannot create the gallery"):
        Gallery.create(str(tmp_path / "no" / "such" / "g.sqlite"), "test-v1", DIM)
