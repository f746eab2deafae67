"""A gallery that keeps up: occlusion-aware matching, confident-only updates, bounded views,
history, rollback, schema upgrade (synthetic vectors: fast)."""

from __future__ import annotations

import os
import sqlite3
import stat

import numpy as np
import pytest

from perception.gallery import Gallery, GalleryError, Thresholds, UpdateRule, block_distances
from perception.gallery_update import decide

PARTS, STRIPE = 4, 8
DIM = PARTS * STRIPE
TH = Thresholds(max_distance=0.6, min_margin=0.1)


def side(rng: np.random.Generator) -> np.ndarray:
    """Three blocks of PCB-like rows: PARTS unit stripes, concatenated, / sqrt(PARTS)."""
    v = rng.normal(size=(3, PARTS, STRIPE))
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    return (v.reshape(3, DIM) / np.sqrt(PARTS)).astype(np.float32)


def towards(a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:
    """Stripe-wise interpolation from side a (t=0) to side b (t=1), stripes renormalised."""
    v = ((1 - t) * a + t * b).reshape(3, PARTS, STRIPE).astype(np.float64)
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    return (v.reshape(3, DIM) / np.sqrt(PARTS)).astype(np.float32)


@pytest.fixture
def g(tmp_path):
    rng = np.random.default_rng(3)
    gal = Gallery.create(str(tmp_path / "g.sqlite"), "test-v1", DIM)
    gal.set_thresholds(TH)
    gal.sides = {}
    for ident in ("1A", "1B", "2A", "2B", "3A"):
        gal.sides[ident] = side(rng)
        gal.enrol(ident, gal.sides[ident], visibility=np.ones((3, PARTS), np.float32))
    yield gal
    gal.close()


def test_hidden_stripes_do_not_count(g):
    """The top stripe of every block is covered (replaced by another side's): with the
    query's visibility saying so, the distance to the true side is ~0 and the answer is
    confident; without it, the same query is far from everything."""
    rng = np.random.default_rng(9)
    q = g.sides["2A"].reshape(3, PARTS, STRIPE).copy()
    q[:, 0] = side(rng).reshape(3, PARTS, STRIPE)[:, 0]  # a strap over stripe 0
    q = q.reshape(3, DIM)
    vis = np.ones((3, PARTS), np.float32)
    vis[:, 0] = 0.0
    blind = g.match(q)
    aware = g.match(q, visibility=vis)
    assert aware.pallet_id == "2A" and aware.distance < 0.05
    assert aware.distance < blind.distance / 5
    per = block_distances(q, g.matrix()[1], vis, np.ones((5, 3, PARTS)))
    assert per[g.identities().index("2A")].max() < 0.05


def test_all_visible_is_the_plain_distance(g):
    rng = np.random.default_rng(5)
    q = side(rng)
    ids, mat = g.matrix()
    plain = block_distances(q, mat)
    weighted = block_distances(q, mat, np.ones((3, PARTS)), np.ones((len(ids), 3, PARTS)))
    assert np.allclose(plain, weighted, atol=1e-5)
    a, b = g.match(q), g.match(q, visibility=np.ones((3, PARTS), np.float32))
    assert a.best_id == b.best_id and a.distance == pytest.approx(b.distance, abs=1e-5)


def test_only_confident_answers_update(g):
    near = towards(g.sides["1B"], g.sides["3A"], 0.08)
    m = g.match(near)
    assert m.pallet_id == "1B"
    # an "unknown" answer never updates, whatever its distance
    unsure = g.match(near, thresholds=Thresholds(0.6, 5.0))
    assert not unsure.known and not g.update(unsure, near).update
    # just inside the thresholds is not confident enough
    edge = Thresholds(max_distance=m.distance * 1.1, min_margin=0.1)
    d = g.update(g.match(near, thresholds=edge), near, thresholds=edge)
    assert not d.update and "for an update" in d.reason
    # well inside: added, and in the history with the run and the figures
    d = g.update(m, near, run="run-1")
    assert d.update, d.reason
    (view,) = g.views("1B")
    assert view["run"] == "run-1" and view["distance"] == pytest.approx(m.distance)
    last = g.history("1B")[-1]
    assert last["action"] == "add view" and last["view"] == view["view_id"]
    assert last["margin"] == pytest.approx(m.margin)
    # the same view again teaches nothing
    again = g.match(near)
    assert again.distance < 0.01 and not g.update(again, near).update


def test_views_are_bounded_and_rollback_restores(g):
    rule = UpdateRule(max_views=2)
    ids = []
    for k in range(4):
        q = towards(g.sides["2B"], g.sides["1A"], 0.05 + 0.04 * k)
        assert g.update(g.match(q), q, rule=rule, run=f"scan {k}").update
        ids.append(g.views("2B")[-1]["view_id"])
    active = [v["view_id"] for v in g.views("2B")]
    assert active == ids[-2:]
    evicted = [e for e in g.history("2B") if e["action"] == "evict view"]
    assert [e["view"] for e in evicted] == ids[:2]
    assert g.rollback("2B") == ids[-1]
    # the view the rolled-back one evicted is back
    assert [v["view_id"] for v in g.views("2B")] == [ids[1], ids[2]]
    assert g.history("2B")[-1]["action"] == "rollback"
    with pytest.raises(GalleryError, match="no active view 999"):
        g.rollback("2B", 999)
    with pytest.raises(GalleryError, match="not enrolled"):
        g.rollback("9Z")
    assert g.rollback("2B") == ids[2]  # undone in order: the view it evicted is back too
    assert [v["view_id"] for v in g.views("2B")] == [ids[0], ids[1]]
    g.rollback("2B")
    g.rollback("2B")
    with pytest.raises(GalleryError, match="no added view"):
        g.rollback("2B")


def test_closest_view_counts_block_by_block(g):
    aged = towards(g.sides["3A"], g.sides["2A"], 0.12)
    assert g.update(g.match(aged), aged).update
    more = towards(g.sides["3A"], g.sides["2A"], 0.2)
    m = g.match(more)
    enrol_only = block_distances(more, g.matrix()[1][[g.identities().index("3A")]]).mean()
    assert m.pallet_id == "3A" and m.distance < enrol_only


def test_a_pallet_drifting_towards_another_is_never_absorbed(g):
    """Scans that creep, step by step, from 1A towards a pallet that was never enrolled:
    each step is close to the previous view, but the gallery never follows further than
    its anchor to 1A's enrolment allows, so the other pallet is never answered as 1A."""
    other = side(np.random.default_rng(77))
    answers = []
    for k in range(1, 21):
        q = towards(g.sides["1A"], other, k / 20)
        m = g.match(q)
        g.update(m, q, run=f"step {k}")
        answers.append(m.pallet_id)
    assert answers[-1] == "unknown" and answers[-3:] == ["unknown"] * 3
    final = g.match(other)
    assert final.pallet_id == "unknown"


def test_update_rule_is_checked():
    with pytest.raises(ValueError):
        UpdateRule(distance_fraction=1.5)
    with pytest.raises(ValueError):
        UpdateRule(max_views=0)

    class M:
        known, pallet_id, reason, distance, margin = True, "1A", "", 0.1, 0.5
        ranking = [("1A", 0.1, (0.1, 0.1, 0.1))]

    assert decide(M, TH, UpdateRule(), 0.2).update
    assert not decide(M, TH, UpdateRule(), 0.9).update  # too far from the enrolment view
    assert not decide(M, Thresholds(), UpdateRule(), 0.1).update  # no threshold: never


def test_schema_1_gallery_is_upgraded_and_read_only_one_is_refused(tmp_path):
    old = tmp_path / "old.sqlite"
    conn = sqlite3.connect(old)
    conn.executescript(
        """
        CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
        CREATE TABLE entries (identity TEXT PRIMARY KEY, embeddings BLOB NOT NULL,
            created REAL NOT NULL, source TEXT NOT NULL DEFAULT '');
        CREATE TABLE crops (identity TEXT NOT NULL REFERENCES entries(identity)
            ON DELETE CASCADE, block INTEGER NOT NULL, png BLOB NOT NULL,
            PRIMARY KEY (identity, block));
        """
    )
    meta = [("schema_version", "1"), ("model_version", "m1"), ("dim", str(DIM))]
    conn.executemany("INSERT INTO meta VALUES (?, ?)", meta)
    v = side(np.random.default_rng(1))
    conn.execute("INSERT INTO entries VALUES ('7A', ?, 5.0, 'old')", (v.tobytes(),))
    conn.commit()
    conn.close()
    ro = tmp_path / "ro.sqlite"
    ro.write_bytes(old.read_bytes())
    os.chmod(ro, stat.S_IRUSR)
    g = Gallery.open(str(old), "m1")
    assert g.identities() == ["7A"] and g.match(v).pallet_id == "7A"
    assert [(e["action"], e["note"]) for e in g.history("7A")] == [
        ("enrol", "upgraded from gallery schema 1")
    ]
    g.close()
    assert Gallery.open(str(old), "m1").history()[0]["time"] == 5.0  # upgraded once
    if os.geteuid() != 0:  # root writes read-only files anyway
        with pytest.raises(GalleryError, match="schema 1 must be upgraded.*copy it"):
            Gallery.open(str(ro), "m1")


def test_remove_and_re_enrol_are_in_the_history(g):
    q = towards(g.sides["1A"], g.sides["2A"], 0.1)
    g.update(g.match(q), q)
    g.enrol("1A", g.sides["1A"])  # re-enrol: a fresh start, views dropped
    assert g.views("1A") == []
    g.remove("1A")
    assert [e["action"] for e in g.history("1A")] == ["enrol", "add view", "re-enrol", "remove"]
