"""``btrun gallery``: enrol, list, remove, export, evaluate, demo; errors are one line, exit 2."""

from __future__ import annotations

import json
import os
import shutil

import cv2
import numpy as np
import pytest
from helpers import REPO

from bt_engine.cli import main


@pytest.mark.slow
def test_enrol_list_evaluate_export_remove(tmp_path, capsys):
    g = str(tmp_path / "p.sqlite")
    assert main(["gallery", "enrol", g, "2B", "--world-side", "2B"]) == 0
    assert main(["gallery", "enrol", g, "4A", "--world-side", "4A"]) == 0
    out = capsys.readouterr().out
    assert "enrolled 4A" in out and "(2 pallet sides)" in out
    assert main(["gallery", "list", g]) == 0
    out = capsys.readouterr().out
    assert "2 pallet sides" in out and "2B" in out and "rendered scan of 2B" in out
    assert main(["gallery", "evaluate", g]) == 0
    assert "closest pair" in capsys.readouterr().out
    out_dir = tmp_path / "export"
    assert main(["gallery", "export", g, str(out_dir)]) == 0
    meta = json.loads((out_dir / "entries.json").read_text())
    assert meta["identities"] == ["2B", "4A"]
    emb = np.load(out_dir / "embeddings.npy")
    assert emb.shape[:2] == (2, 3) and np.all(np.isfinite(emb))
    crop = cv2.imread(str(out_dir / "2B_block_1.png"))
    assert crop is not None and crop.shape[2] == 3
    # enrol the exported crops under a new name: the same pallet, so it matches 2B exactly
    crops = [str(out_dir / f"2B_block_{i}.png") for i in (1, 2, 3)]
    assert main(["gallery", "enrol", g, "2B-copy", "--crops", *crops]) == 0
    # a run folder's last whole scan (the report writes scan_<n>_block_<i>.png; --run looked
    # for block_<i>.png, which runs no longer write, and always failed)
    scans = tmp_path / "run" / "perception"
    scans.mkdir(parents=True)
    for i in (1, 2, 3):
        shutil.copy(out_dir / f"2B_block_{i}.png", scans / f"scan_2_block_{i}.png")
    shutil.copy(out_dir / "4A_block_1.png", scans / "scan_3_block_1.png")  # cut short
    assert main(["gallery", "enrol", g, "2B-run", "--run", str(tmp_path / "run")]) == 0
    assert "(4 pallet sides)" in capsys.readouterr().out
    assert main(["gallery", "remove", g, "4A"]) == 0
    assert "3 pallet sides left" in capsys.readouterr().out  # 2B, 2B-copy, 2B-run remain
    assert main(["gallery", "list", g]) == 0
    out = capsys.readouterr().out
    assert "4A" not in out and "2B-copy" in out


def test_errors_are_one_line_with_exit_code_2(tmp_path, capsys):
    assert main(["gallery", "list", str(tmp_path / "missing.sqlite")]) == 2
    assert "no such gallery file" in capsys.readouterr().err
    bad = tmp_path / "bad.sqlite"
    bad.write_bytes(os.urandom(4096))
    assert main(["gallery", "list", str(bad)]) == 2
    out = capsys.readouterr().err
    assert "bad.sqlite" in out and ("not a readable" in out or "damaged" in out)
    assert main(["gallery", "enrol", "demo", "9A", "--world-side", "3A"]) == 2
    assert "demo gallery is generated" in capsys.readouterr().err
    g = str(tmp_path / "g.sqlite")
    assert main(["gallery", "enrol", g, "1A", "--crops", "a.png", "b.png", "c.png"]) == 2
    assert "a.png: not a readable image" in capsys.readouterr().err
    assert main(["gallery", "remove", g, "nobody"]) == 2
    assert "nobody is not enrolled" in capsys.readouterr().err


@pytest.mark.slow
def test_demo_gallery_has_the_ten_reference_sides(capsys):
    assert main(["gallery", "demo", "--rig", os.path.join(REPO, "rigs", "sim.yaml")]) == 0
    out = capsys.readouterr().out
    assert "10 pallet sides" in out
    for side in ("1A", "3B", "5B"):
        assert side in out


@pytest.mark.slow
def test_a_pallet_side_not_in_the_gallery_is_unknown(tmp_path, capsys):
    g = str(tmp_path / "g.sqlite")
    for side in ("1A", "3B"):
        assert main(["gallery", "enrol", g, side, "--world-side", side]) == 0
    out = str(tmp_path / "run")
    rc = main(
        [
            "run",
            os.path.join(REPO, "missions", "pallet_scan.xml"),
            "--quiet",
            "--no-report",
            "--out",
            out,
            "--set",
            f"gallery={g}",
            "--set",
            "world.scan_pallet=4B",
        ]
    )
    assert rc == 0  # the mission succeeds: "unknown" is an answer, not a failure
    printed = capsys.readouterr().out
    assert "pallet: unknown (distance " in printed and "closest " in printed
    with open(os.path.join(out, "summary.json")) as f:
        bb = json.load(f)["blackboard"]
    assert bb["pallet_id"] == "unknown" and bb["match_ranking"][0][0] in ("1A", "3B")


def test_history_and_rollback(tmp_path, capsys):
    """A gallery of the shipped embedder with one side and a view added after a confident
    scan: history lists both with the run and figures, rollback undoes the view, a second
    rollback is a one-line error."""
    from perception.embedder import BlockEmbedder
    from perception.gallery import Gallery

    emb = BlockEmbedder.load(threads=1)
    path = str(tmp_path / "h.sqlite")
    rng = np.random.default_rng(0)
    sides = {}
    with Gallery.create(path, emb.model_version, emb.dim) as g:
        g.set_thresholds(emb.thresholds)
        for ident in ("7A", "7B", "8A"):
            v = rng.normal(size=(3, emb.dim)).astype(np.float32)
            sides[ident] = v / np.linalg.norm(v, axis=1, keepdims=True)
            g.enrol(ident, sides[ident], source="test")
        scan = sides["7A"] + 0.01 * rng.normal(size=(3, emb.dim)).astype(np.float32)
        scan /= np.linalg.norm(scan, axis=1, keepdims=True)
        assert g.update(g.match(scan), scan, run="scan-1 t=40.0 s").update
    assert main(["gallery", "history", path, "7A"]) == 0
    out = capsys.readouterr().out
    assert "enrol" in out and "add view 1" in out and "run scan-1 t=40.0 s" in out
    assert "distance 0.3" in out and "margin 1.0" in out and "active added views of 7A: 1" in out
    assert main(["gallery", "list", path]) == 0
    assert "+1 views" in capsys.readouterr().out
    assert main(["gallery", "rollback", path, "7A"]) == 0
    assert "rolled back view 1 of 7A" in capsys.readouterr().out
    assert main(["gallery", "rollback", path, "7A"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "7A has no added view to roll back" in err
    assert main(["gallery", "history", path]) == 0
    assert "rollback view 1" in capsys.readouterr().out
