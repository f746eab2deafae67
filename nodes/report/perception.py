"""The perception part of the flight report: frames with detections, crops, ranking table.

Written by :func:`nodes.report.html.write_report` when the run had perception leaves, into the
run folder's ``perception/`` directory:

* ``frame_<index>.png``: the frames each committed crop came from, with every detection
  drawn (score above the box; green: the committed block, yellow: other detections);
* ``scan_<n>_block_1.png`` .. ``_3.png``: the crops of each scan (the last one is what
  ``btrun gallery enrol --run`` enrols);
* ``query_1.png`` ..: the crops an identification used;

and the HTML section: the scans (blocks found, frames seen, frame-to-decision latency) and,
per identification, the answer with its distance and margin and the ranking table with the
per-block distances (like the reference study's table of mean scores).
"""

from __future__ import annotations

import html
import os
from typing import Any

import numpy as np


def _save(path: str, image: np.ndarray) -> None:
    import cv2

    cv2.imwrite(path, image)


def _annotated(frame: Any) -> np.ndarray:
    import cv2

    img = frame.image.copy()
    for x1, y1, x2, y2, score in frame.boxes:
        committed = (x1, y1, x2, y2) in frame.committed_boxes
        colour = (60, 200, 60) if committed else (0, 210, 255)
        p1, p2 = (int(round(x1)), int(round(y1))), (int(round(x2)), int(round(y2)))
        cv2.rectangle(img, p1, p2, colour, 1)
        cv2.putText(
            img, f"{score:.2f}", (p1[0], max(p1[1] - 3, 8)), cv2.FONT_HERSHEY_SIMPLEX, 0.3, colour
        )
    h, w = img.shape[:2]
    cv2.line(img, (w // 2, 0), (w // 2, h - 1), (200, 200, 200), 1)  # the sequencer's centre
    return cv2.resize(img, (w * 2, h * 2), interpolation=cv2.INTER_NEAREST)


def _crop_cell(run_dir: str, name: str, crop: np.ndarray) -> str:
    _save(os.path.join(run_dir, "perception", name), crop)
    return (
        f'<img src="perception/{name}" alt="{name}" style="height:96px;image-rendering:pixelated">'
    )


def perception_section(run_dir: str, mission: Any) -> str:
    """Write the perception images into ``run_dir/perception`` and return the HTML section
    ("" when the run had no perception session)."""
    ctx = getattr(mission, "ctx", None)
    session = getattr(ctx, "resources", {}).get("perception") if ctx is not None else None
    if session is None:
        return ""
    esc = html.escape
    os.makedirs(os.path.join(run_dir, "perception"), exist_ok=True)
    out = ["<h2>Perception</h2>"]
    s = session.summary()
    lat = s.get("frame_to_decision_ms")
    out.append(
        f"<p>{s['frames_processed']} frames processed, {s['detections']} detections; "
        + (
            f"frame-to-decision latency p50 {lat['p50']:.1f} ms, p95 {lat['p95']:.1f} ms. "
            if lat
            else ""
        )
        + "Scans: "
        + (", ".join(f"{n} of 3 blocks" for n in s["blocks"]) or "none")
        + ".</p>"
    )
    for n, sc in enumerate(session.scans, 1):
        if not sc.count:
            continue
        cells = "".join(
            _crop_cell(run_dir, f"scan_{n}_block_{i + 1}.png", c) + f" block {i + 1}&nbsp;&nbsp;"
            for i, c in enumerate(sc.crops)
        )
        into = f" into {{{esc(sc.key)}}}" if sc.key else ""
        out.append(
            f"<h3>Scan {n}{into} at {sc.t_s:.1f} s: {sc.count} of 3 blocks committed</h3>"
            f"<p>{cells}</p>"
        )
    if session.key_frames:
        out.append("<h3>Frames the crops came from</h3>")
        for kf in session.key_frames:
            name = f"frame_{kf.index:05d}.png"
            _save(os.path.join(run_dir, "perception", name), _annotated(kf))
            blocks = ", ".join(str(b) for b in kf.committed)
            out.append(
                f'<figure><img src="perception/{name}" alt="{name}">'
                f"<figcaption>frame {kf.index} at {kf.t_s:.2f} s: block {esc(blocks)}; "
                f"{len(kf.boxes)} detections</figcaption></figure>"
            )
    for n, rec in enumerate(session.identifications, 1):
        key = rec.get("key") or ""
        title = f"{{{esc(key)}}}" if key else f"{n}"
        if "failed" in rec:
            out.append(
                f"<h3>Identification {title}: failed</h3>"
                f"<p>{esc(rec.get('node', ''))}: {esc(rec['failed'])}</p>"
            )
            continue
        known = rec["known"]
        verdict = esc(rec["pallet_id"]) + ("" if known else f" ({esc(rec['reason'])})")
        cells = "".join(
            _crop_cell(run_dir, f"query_{n}_{i + 1}.png", c) for i, c in enumerate(rec["crops"])
        )
        rows = "".join(
            f"<tr><td>{k}</td><td class=l>{esc(ident)}</td><td>{d:.3f}</td>"
            + "".join(f"<td>{b:.3f}</td>" for b in blocks)
            + "</tr>"
            for k, (ident, d, blocks) in enumerate(rec["ranking"], 1)
        )
        out += [
            f"<h3>Identification {title}: {verdict}</h3>",
            f"<p>{cells}</p>",
            f"<p>best distance {rec['distance']:.3f}, margin to the runner-up "
            f"{rec['margin']:.3f}; thresholds: unknown above {rec['thresholds'][0]:.3f} "
            f"or below a margin of {rec['thresholds'][1]:.3f}.</p>",
            "<table><tr><th>rank</th><th class=l>pallet side</th><th>mean distance</th>"
            "<th>block 1</th><th>block 2</th><th>block 3</th></tr>" + rows + "</table>",
        ]
    return "\n".join(out)
