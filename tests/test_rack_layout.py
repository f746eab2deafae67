"""A world's racks and pads checked where they stand: each problem said at its key in the
world file, before anything flies. These had all passed `btrun validate WORLD`."""

from __future__ import annotations

import os

import pytest
from helpers import REPO

from bt_engine.cli import main

SITE = open(os.path.join(REPO, "worlds", "site.yaml"), encoding="utf-8").read()


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        (
            "{name: C, origin_m: [5.0, -8.4]",
            "{name: C, origin_m: [3.5, -8.4]",
            "rack C stands in rack B: their footprints overlap",
        ),
        (
            "{name: pad-1, position_m: [1.0, -10.0]}",
            "{name: pad-1, position_m: [3.5, 0.0]}",
            "pad pad-1 at (3.50, 0.00) stands on rack B (or within 0.15 m of it)",
        ),
        (
            "{name: A, origin_m: [0.0, -8.4]",
            "{name: A-1, origin_m: [0.0, -8.4]",
            "rack name 'A-1': expected a letter, then up to 15 letters or digits",
        ),
        (
            "depth_m: 1.0, height_m: 2.6, setback_m: 0.05}",
            "depth_m: 1.0, height_m: 1.5, setback_m: 0.05}",
            "rack A: level 1.8 m with its 0.144 m pallet reaches above the rack's top",
        ),
    ],
    ids=["racks-overlap", "pad-on-rack", "rack-name", "level-above-top"],
)
def test_a_layout_problem_is_located_in_the_world_file(tmp_path, capsys, old, new, expected):
    assert old in SITE, old
    path = tmp_path / "site.yaml"
    path.write_text(SITE.replace(old, new, 1), encoding="utf-8")
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    line = next(
        n for n, text in enumerate(SITE.replace(old, new, 1).splitlines(), 1) if new in text
    )
    assert err.startswith(f"{path}:{line}:"), err
    assert expected in err, err


def test_the_shipped_worlds_have_no_layout_problem(capsys):
    for name in ("site", "aisle", "warehouse", "warehouse_weathered"):
        assert main(["validate", os.path.join(REPO, "worlds", f"{name}.yaml")]) == 0, name
