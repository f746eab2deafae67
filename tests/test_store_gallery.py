"""Galleries in PostgreSQL (perception/gallery_pg.py): the same Gallery class on a real
server started by the tests: enrol, list, match, views, history, rollback, remove, and a
second connection (another ground station) seeing the changes."""

from __future__ import annotations

import numpy as np
import pytest

from perception.gallery import Gallery, GalleryError, Thresholds
from perception.gallery_match import Match
from perception.gallery_pg import gallery_url, split_gallery_url
from perception.gallery_update import UpdateRule


@pytest.fixture
def pg_gallery(postgresql_server, request) -> str:
    url = postgresql_server.database("g_" + request.node.name[:40].lower())
    return gallery_url(url, "pallets")


def _vectors(seed: int, dim: int = 8) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(3, dim)).astype(np.float32)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_gallery_names() -> None:
    assert split_gallery_url("postgresql://h/db#Aisle-2")[2] == "gallery_aisle_2"
    with pytest.raises(GalleryError, match="name the gallery after '#'"):
        split_gallery_url("postgresql://u:pw@h/db")


def test_enrol_match_views_history_rollback_in_postgresql(pg_gallery) -> None:
    with pytest.raises(GalleryError, match="no such gallery in the store"):
        Gallery.open(pg_gallery)
    g = Gallery.create(pg_gallery, "model-x", 8)
    g.set_thresholds(Thresholds(0.9, 0.05))
    g.set_thresholds(Thresholds(0.8, 0.05))  # replaces (ON CONFLICT), no duplicate key
    for k, ident in enumerate(("1A", "2B", "3A")):
        g.enrol(ident, _vectors(k), [b"png-%d" % b for b in range(3)], source="test")
    with pytest.raises(GalleryError, match="already exists"):
        Gallery.create(pg_gallery, "model-x", 8)
    assert g.identities() == ["1A", "2B", "3A"] and len(g) == 3
    assert [e["crops"] for e in g.entries()] == [3, 3, 3]
    assert g.crops("2B") == [b"png-0", b"png-1", b"png-2"]
    m = g.match(_vectors(1) + 0.01)
    assert m.pallet_id == "2B" and m.known
    # a confident answer adds a view (lastrowid through RETURNING), bounded and reversible
    confident = Match(
        "2B", "2B", 0.05, "1A", 1.0, 0.95, True, "", [("2B", 0.05, (0.05, 0.05, 0.05))]
    )
    rule = UpdateRule(min_novelty=0.0, max_views=1)
    assert g.update(confident, _vectors(1) + 0.02, rule=rule).update
    assert g.update(confident, _vectors(1) + 0.03, rule=rule).update
    views = g.views("2B", active_only=False)
    assert [v["active"] for v in views] == [0, 1] and views[0]["evicted_by"] == views[1]["view_id"]
    assert g.rollback("2B") == views[1]["view_id"]
    assert [v["active"] for v in g.views("2B", active_only=False)] == [1, 0]
    actions = [e["action"] for e in g.history("2B")]
    assert actions == ["enrol", "add view", "add view", "evict view", "rollback"]
    # another ground station's connection sees the same gallery
    other = Gallery.open(pg_gallery, "model-x")
    assert other.thresholds.max_distance == 0.8 and other.identities() == g.identities()
    assert other.match(_vectors(2)).pallet_id == "3A"
    assert g.remove("1A") and not g.remove("1A")
    assert other.match(_vectors(2)).pallet_id == "3A" and "1A" not in other.identities()
    with pytest.raises(GalleryError, match="embeddings of different models"):
        Gallery.open(pg_gallery, "model-y")
    g.close()
    other.close()


@pytest.mark.slow
def test_btrun_gallery_and_a_mission_on_a_postgresql_gallery(postgresql_server, tmp_path, capsys):
    """``btrun gallery ... --store postgresql://...`` enrols rendered scans into a gallery in
    PostgreSQL; a mission identifies the scan pallet against it (gallery=URL#NAME), texture
    verification included."""
    import json
    import os

    from helpers import REPO

    from bt_engine.cli import main

    url = postgresql_server.database("gallery_cli")
    for side in ("3A", "4A", "2B"):
        assert (
            main(["gallery", "enrol", "pallets", side, "--world-side", side, "--store", url]) == 0
        )
    assert main(["gallery", "list", "pallets", "--store", url]) == 0
    out = capsys.readouterr().out
    assert "3 pallet sides" in out and "rendered scan of 3A" in out and "postgres@" in out
    assert main(["gallery", "history", "pallets", "3A", "--store", url]) == 0
    assert "enrol" in capsys.readouterr().out
    assert main(["gallery", "list", "nothing", "--store", url]) == 2
    assert "no such gallery in the store" in capsys.readouterr().err
    run = str(tmp_path / "scan")
    args = [os.path.join(REPO, "missions", "pallet_scan.xml"), "--out", run, "-q"]
    args += ["--set", f"gallery={url}#pallets", "--no-report", "--no-mcap", "--store", "none"]
    assert main(args) == 0
    with open(os.path.join(run, "summary.json")) as f:
        summary = json.load(f)
    assert "3A" in json.dumps(summary.get("perception", {}))
