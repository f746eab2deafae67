"""A gallery of thousands (issue 28): the search index against brute force, the cache of
vectors in memory, crops decoded only when needed, ``btrun gallery list --page`` and
``stats``, and the demo gallery's faster enrolment."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import children, cmdline

from perception import gallery_index as gi
from perception import gallery_math as gm
from perception.gallery import Gallery
from perception.gallery_views import png_bytes

DIM, PARTS = 64, 4


def _sides(rng: np.random.Generator, n: int, rank: int = 6) -> np.ndarray:
    """``n`` sides of unit stripes (n, 3, DIM) with structure (a few directions per stripe
    position, plus noise), as real embeddings have."""
    s = DIM // PARTS
    basis = rng.standard_normal((BLOCKS_PARTS := 3 * PARTS, rank, s))
    z = rng.standard_normal((n, BLOCKS_PARTS, rank))
    x = np.einsum("nkr,krs->nks", z, basis) + 0.3 * rng.standard_normal((n, BLOCKS_PARTS, s))
    x /= np.linalg.norm(x, axis=-1, keepdims=True) * np.sqrt(PARTS)
    return x.reshape(n, 3, DIM).astype(np.float32)


def _gallery(rows: np.ndarray, vis: np.ndarray | None = None) -> Gallery:
    g = Gallery.create(":memory:", "m", DIM)
    with g.conn:
        for i, r in enumerate(rows):
            g.conn.execute(
                "INSERT INTO entries VALUES (?, ?, ?, ?)", (f"s{i:05d}", r.tobytes(), 0.0, "")
            )
            if vis is not None:
                g.conn.execute(
                    "INSERT INTO visibility VALUES (?, ?)", (f"s{i:05d}", vis[i].tobytes())
                )
    g._invalidate()
    return g


def _brute_force(rows, vis, q, qvis, k=5):
    """Every side's exact weighted distance, sorted: the reference."""
    per_block = gm.block_distances(q, rows.astype(np.float64), qvis, vis)
    side = gm.side_distance(per_block, gm.block_weights(qvis))
    order = np.argsort(side, kind="stable")[:k]
    return [f"s{i:05d}" for i in order], side[order]


@pytest.mark.parametrize("mode", ["exact", "reduced"])
@pytest.mark.parametrize("with_vis", [False, True])
def test_the_search_index_finds_what_brute_force_finds(monkeypatch, mode, with_vis):
    rng = np.random.default_rng(3)
    n = 3000
    rows = _sides(rng, n)
    vis = rng.uniform(0.3, 1.0, (n, 3, PARTS)).astype(np.float32) if with_vis else None
    monkeypatch.setattr(gi, "REDUCED_MIN_ROWS", 0 if mode == "reduced" else 10**9)
    monkeypatch.setattr(gi, "REDUCED_DIMS", 8)  # of 16 per stripe
    g = _gallery(rows, vis)
    same_top5 = 0
    for t in range(25):
        truth = int(rng.integers(n))
        q = rows[truth] + 0.08 * rng.standard_normal((3, DIM)).astype(np.float32)
        qvis = rng.uniform(0.2, 1.0, (3, PARTS)).astype(np.float32) if with_vis else None
        m = g.match(q, visibility=qvis)
        ids, dist = _brute_force(rows, vis, q, qvis)
        # the answer and its distance always; the exact screen's whole top 5 too; the
        # reduced screen most of it
        assert m.best_id == ids[0] == f"s{truth:05d}", f"query {t}"
        assert m.distance == pytest.approx(dist[0], abs=1e-6)
        same_top5 += [r[0] for r in m.ranking] == ids
        # what the reduced screen misses are near ties among far impostors: the margin
        # (the runner-up's distance) is off by far less than its threshold (0.25)
        got = np.array([r[1] for r in m.ranking])
        assert np.all(got >= dist - 1e-9) and got[1] - dist[1] < 0.01, got - dist
        assert np.all(got - dist < 0.1), got - dist
    assert same_top5 == 25 if mode == "exact" else same_top5 >= 5
    assert g._rows[PARTS if with_vis else 1].index.reduced == (mode == "reduced")


def test_the_reduced_screen_keeps_its_candidates_for_far_queries(monkeypatch):
    """A query far from everything (never enrolled), among near ties: the reduced screen
    may name another of them, but its distance is within 0.01 of the nearest's and the
    margin within 0.03 (an eighth of the threshold), so "unknown" stays unknown (on
    vectors rougher for it than real embeddings: bench/gallery_scale.py measures those)."""
    rng = np.random.default_rng(4)
    rows = _sides(rng, 5000)
    monkeypatch.setattr(gi, "REDUCED_MIN_ROWS", 0)
    monkeypatch.setattr(gi, "REDUCED_DIMS", 8)
    g = _gallery(rows)
    for _ in range(20):
        q = _sides(rng, 1)[0]
        m = g.match(q)
        _, dist = _brute_force(rows, None, q, None)
        assert dist[0] - 1e-9 <= m.distance < dist[0] + 0.01
        assert m.margin == pytest.approx(dist[1] - dist[0], abs=0.03)
    assert g._rows[1].index.reduced


def test_vectors_in_memory_follow_enrol_remove_update_and_rollback():
    rng = np.random.default_rng(5)
    rows = _sides(rng, 30)
    g = _gallery(rows[:20])
    q = rows[25] + 0.01 * rng.standard_normal((3, DIM)).astype(np.float32)
    assert g.match(q).best_id != "new"
    g.enrol("new", rows[25])
    assert g.match(q).best_id == "new"
    assert g.remove("new")
    assert g.match(q).best_id != "new"
    # an added view moves a side's answer; rolling it back moves it back
    g.set_thresholds(gm_thresholds())
    before = g.match(q)
    view = g.add_view(before.best_id, rows[25], run="test")
    assert g.match(q).distance < 0.5 * before.distance
    g.rollback(before.best_id, view)
    assert g.match(q).distance == pytest.approx(before.distance)


def gm_thresholds():
    from perception.gallery import Thresholds

    return Thresholds(max_distance=2.0, min_margin=0.0)


def test_a_change_by_another_process_reaches_an_open_gallery(tmp_path):
    rng = np.random.default_rng(6)
    rows = _sides(rng, 12)
    path = str(tmp_path / "g.sqlite")
    with Gallery.create(path, "m", DIM) as w:
        for i in range(10):
            w.enrol(f"s{i:05d}", rows[i])
    reader = Gallery.open(path, "m")
    q = rows[11] + 0.01 * rng.standard_normal((3, DIM)).astype(np.float32)
    assert reader.match(q).best_id != "late"
    with Gallery.open(path, "m") as other:  # another connection, as another process
        other.enrol("late", rows[11])
    assert reader.match(q).best_id == "late"
    reader.close()


def test_only_the_candidates_and_the_cohort_crops_are_decoded():
    from perception.gallery_match import VERIFY_CANDIDATES
    from perception.verify import COHORT_FROM_GALLERY

    rng = np.random.default_rng(7)
    n = 300
    rows = _sides(rng, n)
    g = _gallery(rows)
    grain = lambda k: rng.integers(0, 255, (36, 64, 3), dtype=np.uint8)  # noqa: E731
    crops = {i: [grain(b) for b in range(3)] for i in range(n)}
    with g.conn:
        for i in range(n):
            for b in range(3):
                g.conn.execute(
                    "INSERT INTO crops VALUES (?, ?, ?)", (f"s{i:05d}", b, png_bytes(crops[i][b]))
                )
    g._invalidate()
    m = g.match(rows[150], crops=crops[150])
    assert m.pallet_id == "s00150" and m.texture_id == "s00150"
    decoded = g._grey._decoded
    assert len(decoded) <= VERIFY_CANDIDATES + COHORT_FROM_GALLERY
    assert len(g._grey) == n and "s00299" in g._grey  # every side is there when asked for


def test_list_pages_and_stats(tmp_path, capsys):
    from bt_engine.cli import main
    from perception.embedder import BlockEmbedder

    emb = BlockEmbedder.load(threads=1)
    path = str(tmp_path / "site.sqlite")
    rng = np.random.default_rng(8)
    with Gallery.create(path, emb.model_version, emb.dim) as g:
        g.set_thresholds(emb.thresholds)
        for p in range(1, 13):
            for side in "AB":
                e = rng.standard_normal((3, emb.dim)).astype(np.float32)
                g.enrol(f"{p}{side}", e / np.linalg.norm(e, axis=1, keepdims=True))
    assert main(["gallery", "list", path, "--page", "2", "--per-page", "10"]) == 0
    out = capsys.readouterr().out
    listed = [ln.split()[0] for ln in out.splitlines() if ln.startswith("  ")]
    assert len(listed) == 10 and listed[0] == "3A"  # sorted: 10A..12B, 1A, 1B, 2A, 2B, 3A
    assert "sides 11-20 of 24, page 2 of 3" in out and "--page 3" in out
    assert main(["gallery", "list", path]) == 0  # small: every side, as before
    assert len([ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("  ")]) == 24
    assert main(["gallery", "list", path, "--page", "4", "--per-page", "10"]) == 2
    assert "page 4 does not exist: 3 page(s)" in capsys.readouterr().err
    assert main(["gallery", "stats", path]) == 0
    out = capsys.readouterr().out
    for want in ("pallet sides:      24", "pallets:           12", "added views:       0",
                 emb.model_version, "size on disk:", "last update:", "build time:        -"):  # fmt: skip
        assert want in out, out


def test_a_pool_override_names_another_demo_gallery():
    from nodes.gallery.enrol_scan import look_overrides

    keep = look_overrides(
        {"pallet_pool.count": "2000", "pallet_look.wood": "grey", "scan_slot.y_m": "1"}
    )
    assert keep == {"pallet_pool.count": "2000", "pallet_look.wood": "grey"}


def test_a_not_enrolled_override_leaves_those_pallets_out_of_the_demo_gallery():
    """``--set world.stock.not_enrolled=[...]`` names pallets the gallery must not know:
    the demo gallery is another one (its own cache file) and does not enrol them. (It used
    to keep the world file's gallery, which knew them: every such place answered with the
    pallet's identity counted as a wrong answer.)"""
    from drivers.sim.world import load_world
    from nodes.gallery.demo import demo_gallery_path
    from nodes.gallery.enrol_scan import look_overrides

    class Model:
        model_version = "m1"

    world = "worlds/site.yaml"
    more = '["1121","1122","1123","1124","1125","1126","1127","1128","1129","1130","1131"]'
    sets = {"stock.not_enrolled": more, "stock.not_enrolled_places": "11"}
    assert look_overrides(sets) == sets
    assert demo_gallery_path(world, Model, Model, {}) != demo_gallery_path(
        world, Model, Model, {}, sets
    )
    # the other stock keys are there for the world's checks only: the same gallery
    assert demo_gallery_path(world, Model, Model, {}) == demo_gallery_path(
        world, Model, Model, {}, {"stock.empty_places": "30", "stock.not_enrolled_places": "4"}
    )
    enrolled = load_world(world, look_overrides(sets)).enrolled_identities()
    assert "1121A" not in enrolled and "1130B" not in enrolled
    assert "1120A" in enrolled and "1131A" not in enrolled
    assert "1121A" in load_world(world).enrolled_identities()


@pytest.mark.slow
def test_the_faster_enrolment_identifies_whole_scans_of_its_sides(tmp_path):
    """The demo gallery enrolled from a few views per side (two worker processes) answers
    a whole enrolment scan flown at another seed for each of its sides."""
    from drivers.rig.loader import load_rig
    from nodes.gallery.demo import build_gallery
    from nodes.gallery.enrol_scan import scan_blocks, scan_frames
    from nodes.perception_session import PerceptionSession

    s = PerceptionSession(load_rig("rigs/aisle.yaml"), log=lambda m: None)
    det, emb = s.detector(), s.embedder()
    world = s.world_path()
    sides = ["101A", "101B", "102A", "103B"]
    path = str(tmp_path / "demo.sqlite")
    lines: list[str] = []
    build_gallery(path, world, sides, det, emb, s.camera, log=lines.append, workers=2)
    assert lines[-1].startswith("  4 sides enrolled in")
    with Gallery.open(path, emb.model_version) as g:
        assert g.identities() == sorted(sides)
        for i, side in enumerate(sides):
            crops = scan_blocks(scan_frames(world, side, s.camera, 7000 + i), det, s.factors)
            d = emb.describe(crops)
            assert g.match(d.vectors, visibility=d.visibility, crops=crops).pallet_id == side


def test_gallery_commands_take_world_settings(capsys):
    from bt_engine.cli import main

    code = main(["gallery", "stats", "demo", "--rig", "rigs/aisle.yaml", "--set", "world.pallet_pool.count=many"])  # fmt: skip
    assert code == 2
    assert "pallet_pool.count: expected an integer" in capsys.readouterr().err


def test_a_demo_gallery_whose_world_fails_its_checks_is_reported_not_raised(monkeypatch):
    """A world the demo gallery cannot be built from (its checks fail) is a perception
    error, which PerceptionReady's preflight reports before anything flies, not an
    exception out of the first tick (as a world broken by partial overrides once was)."""
    from drivers.rig.loader import load_rig
    from drivers.settings import ConfigError, SettingProblem
    from nodes.gallery import demo
    from nodes.perception_session import PerceptionError, PerceptionSession

    def broken(*args, **kwargs):
        raise ConfigError([SettingProblem("--set", 0, 0, "world: 124 places to fill")])

    monkeypatch.setattr(demo, "ensure_demo_gallery", broken)

    class Model:
        model_version = "m1"

    session = PerceptionSession(load_rig("rigs/aisle.yaml"), log=lambda m: None)
    with pytest.raises(PerceptionError, match="demo gallery: --set world: 124 places to fill"):
        session.gallery("demo", Model, detector=Model)


def test_a_rack_standing_on_the_enrolment_slot_is_left_out_of_the_enrolment_scan(tmp_path):
    """The canonical slot is a fixed spot on the floor (9.30, 0.0). A world with a third
    aisle put rack E's steel there: the enrolled pallet stood inside it, its blocks hidden
    from the scan line, and 142 of 234 places were answered right. A rack overlapping the
    enrolled pallet is left out of the enrolment scan (its own demo gallery); the shipped
    worlds keep every rack, and their galleries are the same."""
    import copy

    import yaml

    from drivers.sim.world import load_world
    from nodes.gallery.demo import demo_gallery_path
    from nodes.gallery.enrol_scan import canonical_world_data, clear_racks

    class Model:
        model_version = "m1"

    for world in ("worlds/site.yaml", "worlds/aisle.yaml"):
        data = load_world(world).data
        assert clear_racks(data["racks"], data["pallet_geometry"]) == data["racks"]
    with open("worlds/site.yaml", encoding="utf-8") as f:
        site = yaml.safe_load(f)
    third = copy.deepcopy(site["racks"][2])  # (shared lists would be YAML aliases)
    third.update(name="E", origin_m=[10.0, -8.4])  # faces +x: its steel at x 9..10
    site["racks"].append(third)
    site["stock"]["empty_places"] = 46  # 180 places, 124 filled with enrolled pallets
    path = tmp_path / "site3.yaml"
    path.write_text(yaml.safe_dump(site))
    data = load_world(str(path)).data
    kept = canonical_world_data(data, "1001A")["racks"]
    assert [r["name"] for r in kept] == ["A", "B", "C", "D"]
    moved = dict(third, origin_m=[12.0, -8.4])  # x 11..12: clear of the slot, kept
    assert clear_racks([moved], data["pallet_geometry"]) == [moved]
    # another gallery than the same world without rack E (which enrols as the site)
    site["racks"].pop()
    plain = tmp_path / "plain.yaml"
    plain.write_text(yaml.safe_dump(site))
    assert demo_gallery_path(str(path), Model, Model, {}) != demo_gallery_path(
        str(plain), Model, Model, {}
    )


_KILLED_BUILD = """
import os, sys
from drivers.rig.loader import load_rig
from nodes.gallery.demo import _enrolled_sides
from nodes.perception_session import PerceptionSession

s = PerceptionSession(load_rig("rigs/site.yaml"), log=lambda m: None)
sides = [f"{1001 + i // 2}{'AB'[i % 2]}" for i in range(400)]
for _ in _enrolled_sides(s.world_path(), sides, s.detector(), s.embedder(), s.camera, None, 2):
    print("enrolling", flush=True)  # the workers are running: kill me now
    os.read(0, 1)  # and wait for it (stdin never gives a byte)
"""


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(__import__("os"), "pidfd_open"), reason="Linux pidfds")
def test_a_killed_build_leaves_no_worker_behind():
    """A btrun killed outright (SIGKILL) while building a demo gallery over two worker
    processes takes its workers with it: they used to wait forever on their task queue,
    each holding the models and the world."""
    import os
    import select
    import signal
    import subprocess
    import sys

    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    proc = subprocess.Popen(
        [sys.executable, "-c", _KILLED_BUILD],
        cwd=repo,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
    )
    fds: list[int] = []
    try:
        assert select.select([proc.stdout], [], [], 120)[0], "the build did not start"
        assert proc.stdout.readline() == b"enrolling\n"  # type: ignore[union-attr]
        workers = {p for p in children(proc.pid) if "spawn_main" in cmdline(p)}
        assert len(workers) == 2, "the build did not run on two workers"
        fds = [os.pidfd_open(p) for p in workers]  # readable once the process has ended
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        ended: set[int] = set()
        while len(ended) < len(fds):
            ready = select.select([f for f in fds if f not in ended], [], [], 30)[0]
            assert ready, "a build worker outlived its parent"
            ended.update(ready)
    finally:
        if proc.poll() is None:
            proc.kill()
        for fd in fds:  # without the fix: not left running after the test
            try:
                signal.pidfd_send_signal(fd, signal.SIGKILL)
            except ProcessLookupError:
                pass
            os.close(fd)
