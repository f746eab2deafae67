"""``btrun replay`` of a ``run.mcap`` whose bytes changed on disk: a chunk that fails its
checksum inside a complete file had been replayed without a word (its ticks silently
missing, ``--tick`` in the gap showing a made-up time and status) and ``--repair`` had
called the file complete."""

from __future__ import annotations

import os
import shutil

from helpers import REPO

from bt_engine.cli import main

SQUARE = os.path.join(REPO, "missions", "square.xml")


def _chunk_offsets(path: str) -> list[int]:
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    return sorted(c.chunk_start_offset for c in summary.chunk_indexes)


def test_a_damaged_chunk_is_said_and_its_ticks_are_not_made_up(tmp_path, capsys) -> None:
    run = tmp_path / "run"
    assert main([SQUARE, "--out", str(run), "-q", "--no-report"]) == 0
    damaged = tmp_path / "damaged"
    damaged.mkdir()
    shutil.copy(run / "run.mcap", damaged / "run.mcap")
    chunks = _chunk_offsets(str(damaged / "run.mcap"))
    assert len(chunks) >= 3, chunks
    data = bytearray((damaged / "run.mcap").read_bytes())
    middle = chunks[len(chunks) // 2]
    data[middle + 200 : middle + 204] = b"\xff\xff\xff\xff"  # inside the chunk's records
    (damaged / "run.mcap").write_bytes(bytes(data))
    capsys.readouterr()
    assert main(["replay", str(damaged / "run.mcap"), "--all"]) == 0
    err = capsys.readouterr().err
    assert "warning: ticks " in err and " are missing (a damaged or edited file)" in err, err
    gap = err.split("warning: ticks ", 1)[1].split(" ", 1)[0]
    first = int(gap.split("..")[0])
    assert main(["replay", str(damaged / "run.mcap"), "--tick", str(first)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"tick {first}  (not in the log: the tree as the ticks before it")
    assert main(["replay", "--repair", str(damaged)]) == 0
    said = capsys.readouterr().out
    assert "but a record does not read back (byte " in said and "CRCValidationError" in said
    assert "the file is left as it is" in said
    assert not (damaged / "run.mcap.orig").exists()  # nothing rewritten
    assert main(["replay", "--repair", str(run)]) == 0
    assert "nothing to repair" in capsys.readouterr().out  # an intact one
