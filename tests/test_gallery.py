"""The pallet gallery: matching rule, unknown answers, versions, damage and atomic writes."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from helpers import wait_until

from perception.gallery import Gallery, GalleryError, Thresholds, block_distances

DIM = 8


def unit(rng, n=3):
    v = rng.normal(size=(n, DIM)).astype(np.float32)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.fixture
def gallery(tmp_path):
    rng = np.random.default_rng(0)
    g = Gallery.create(str(tmp_path / "g.sqlite"), "test-v1", DIM)
    for ident in ("1A", "1B", "2A", "2B"):
        g.enrol(ident, unit(rng), crops_png=[b"png0", b"png1", b"png2"], source="test")
    yield g
    g.close()


def test_mean_of_three_block_distances_wins(gallery):
    ids, mat = gallery.matrix()
    q = mat[ids.index("2A")] + 0.01
    m = gallery.match(q)
    assert m.pallet_id == "2A" and m.known
    per = block_distances(q, mat)
    assert m.distance == pytest.approx(per[ids.index("2A")].mean(), rel=1e-6)
    assert m.ranking[0][0] == "2A" and len(m.ranking) == 4
    assert m.runner_up_id == m.ranking[1][0]
    assert m.margin == pytest.approx(m.ranking[1][1] - m.ranking[0][1])


def test_unknown_when_distance_or_margin_fails(gallery):
    ids, mat = gallery.matrix()
    far = unit(np.random.default_rng(9))
    m = gallery.match(far, thresholds=Thresholds(max_distance=0.5, min_margin=0.0))
    assert m.pallet_id == "unknown" and not m.known and "above the threshold" in m.reason
    between = (mat[0] + mat[1]) / 2
    m = gallery.match(between, thresholds=Thresholds(max_distance=10, min_margin=0.05))
    assert m.pallet_id == "unknown" and "margin" in m.reason
    gallery.set_thresholds(Thresholds(10.0, 0.05))
    again = Gallery.open(gallery.path, "test-v1")
    assert again.thresholds == Thresholds(10.0, 0.05)


def test_list_remove_and_crops(gallery):
    assert gallery.identities() == ["1A", "1B", "2A", "2B"]
    assert gallery.entries()[0]["crops"] == 3
    assert gallery.crops("1B") == [b"png0", b"png1", b"png2"]
    assert gallery.remove("1B") and not gallery.remove("1B")
    assert "1B" not in gallery.matrix()[0]


def test_other_model_version_is_refused(gallery):
    with pytest.raises(GalleryError, match="written by model 'test-v1'.*re-enrol"):
        Gallery.open(gallery.path, "other-v2")


def test_bad_input_is_refused(tmp_path, gallery):
    with pytest.raises(GalleryError, match="shape"):
        gallery.enrol("9A", np.zeros((2, DIM)))
    with pytest.raises(GalleryError, match="NaN"):
        gallery.enrol("9A", np.full((3, DIM), np.nan))
    with pytest.raises(GalleryError, match="no gallery file"):
        Gallery.open(str(tmp_path / "missing.sqlite"))
    empty = Gallery.create(str(tmp_path / "e.sqlite"), "test-v1", DIM)
    with pytest.raises(GalleryError, match="empty"):
        empty.match(np.zeros((3, DIM)))


def test_damaged_file_is_detected(tmp_path, gallery):
    gallery.close()
    data = bytearray(open(gallery.path, "rb").read())
    for i in range(200, len(data), 97):
        data[i] ^= 0xFF
    bad = tmp_path / "bad.sqlite"
    bad.write_bytes(bytes(data))
    with pytest.raises(GalleryError, match="damaged|not a readable gallery"):
        Gallery.open(str(bad))
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"this is not sqlite" * 100)
    with pytest.raises(GalleryError, match="not a readable gallery"):
        Gallery.open(str(junk))


ENROLLER = textwrap.dedent(
    """
    import sys, numpy as np
    from perception.gallery import Gallery
    g = Gallery.open(sys.argv[1], "test-v1")
    rng = np.random.default_rng(int(sys.argv[2]))
    i = 0
    while True:
        i += 1
        g.enrol(f"k{sys.argv[2]}-{i}", rng.normal(size=(3, 8)).astype("float32"),
                crops_png=[bytes(20000), bytes(20000), bytes(20000)])
        print(i, flush=True)
    """
)


def test_killed_enrolment_leaves_the_gallery_intact(tmp_path, gallery):
    """SIGKILL an enrolling process at random moments: the file stays valid and every entry
    present is complete (its three crops are there)."""
    gallery.close()
    script = tmp_path / "enrol.py"
    script.write_text(ENROLLER)
    env = dict(os.environ, PYTHONPATH=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    rnd = random.Random(1)
    for run in range(6):
        p = subprocess.Popen(
            [sys.executable, str(script), gallery.path, str(run)], stdout=subprocess.PIPE, env=env
        )

        def enrolling(p=p) -> bool:  # it printed that it enrolled its second entry
            line = p.stdout.readline()
            return bool(line) and int(line) >= 2

        try:
            wait_until(enrolling, 20.0, f"enrolling process {run} to enrol 2 entries", 0.0)
            time.sleep(rnd.uniform(0.0, 0.05))  # then kill it at a random moment
        finally:
            p.send_signal(signal.SIGKILL)
            p.wait(timeout=10)
        g = Gallery.open(gallery.path, "test-v1")
        for entry in g.entries():
            assert entry["crops"] in (0, 3), entry
            if entry["identity"].startswith("k"):
                assert entry["crops"] == 3
        assert {"1A", "1B", "2A", "2B"} <= set(g.identities())
        g.close()


def test_ten_thousand_entries_match_quickly(tmp_path):
    rng = np.random.default_rng(1)
    g = Gallery.create(str(tmp_path / "big.sqlite"), "v", 256)
    embs = rng.normal(size=(10_000, 3, 256)).astype(np.float32)
    with g.conn:
        g.conn.executemany(
            "INSERT INTO entries VALUES (?, ?, ?, '')",
            [(f"p{i:05d}", embs[i].tobytes(), 0.0) for i in range(10_000)],
        )
    g._cache = None
    m = g.match(embs[1234] + 0.001)
    assert m.pallet_id == "p01234" and len(g) == 10_000
