"""btrun console refuses what it must: paths outside the runs folder (traversal, encoded
separators, absolute paths, symbolic links out), file types it does not serve, oversized
requests, foreign hosts, decisions without the token; bad command lines are one line with
exit code 2. A small run folder made here, no flight and no browser."""

from __future__ import annotations

import http.client
import json
import os
import socket
import subprocess
import sys

import numpy as np
import pytest
from console_helpers import REPO, TOKEN, console

from nodes.console import export
from nodes.console.paths import PathRefused, RunsRoot
from nodes.inventory_log import write_inventory
from nodes.place_evidence import PlaceEvidenceError, write_place_evidence

RUN = "inventory-20261126-090000"
SECRET = "top secret outside the runs folder"


def _row(place: str, answer: str, status: str, **extra) -> dict:
    row = {"place": place, "answer": answer, "status": status, "best_id": None}
    row.update(distance=None, margin=None, blocks_seen=3, mission_time_s=10.0)
    row.update(drone="aisle", run=RUN, reason=None, **extra)
    return row


@pytest.fixture
def runs(tmp_path) -> str:
    """runs/<RUN> with two rows and a place's evidence; a secret file beside runs/."""
    (tmp_path / "secret.json").write_text(json.dumps({"secret": SECRET}))
    root = tmp_path / "runs"
    run = root / RUN
    run.mkdir(parents=True)
    (run / "ticks.jsonl").write_text('{"header": {"mission": "missions/inventory.xml"}}\n')
    rows = [
        _row("A-01-1", "=cmd|' /C calc'!A0", "identified"),
        _row("A-01-2", "unknown", "unknown"),
    ]
    write_inventory(str(run), rows, ["A-01-1", "A-01-2"])
    crop = np.full((20, 30, 3), 128, np.uint8)
    write_place_evidence(str(run), "A-01-2", [crop] * 3, [("101A", 0.81), ("102B", 0.9)])
    return str(root)


def _raw(url_port: int, method: str, path: str, body: bytes = b"", headers=None) -> tuple:
    """Send ``path`` exactly as given (no client-side normalisation)."""
    conn = http.client.HTTPConnection("127.0.0.1", url_port, timeout=10)
    conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
    for k, v in (headers or {"Host": f"127.0.0.1:{url_port}"}).items():
        conn.putheader(k, v)
    if body and "Content-Length" not in (headers or {}):
        conn.putheader("Content-Length", str(len(body)))
    conn.endheaders(body or None)
    r = conn.getresponse()
    data = r.read()
    conn.close()
    return r.status, data


@pytest.mark.parametrize(
    "path",
    [
        f"/files/{RUN}/../../secret.json",
        f"/files/{RUN}/%2e%2e/%2e%2e/secret.json",
        f"/files/{RUN}/..%2f..%2fsecret.json",
        f"/files/{RUN}/%2Fetc%2Fpasswd",
        f"/files/{RUN}//etc/passwd",
        "/files/../secret.json",
        "/files/%2e%2e/secret.json",
        f"/files/{RUN}/places/A-01-2/..%5c..%5c..%5csecret.json",
        f"/files/{RUN}/ticks.jsonl",
        f"/files/{RUN}/places/A-01-2/block_1.png%00.json",
        "/runs/..%2f..%2fetc",
        "/api/runs/..",
        "/api/runs/%2e%2e",
        "/export/../inventory.csv",
        "/static/../app.py",
        "/static/%2e%2e/app.py",
    ],
)
def test_no_path_outside_the_runs_folder_is_read(runs, path):
    with console(runs) as server:
        status, body = _raw(server.port, "GET", path)
    assert status in (400, 403, 404), (path, status)
    assert SECRET.encode() not in body and b"root:" not in body and b"import" not in body


def test_symbolic_links_out_of_the_runs_folder_are_refused(runs, tmp_path):
    os.symlink(tmp_path / "secret.json", os.path.join(runs, RUN, "leak.json"))
    os.symlink(tmp_path, os.path.join(runs, "escape"))
    os.symlink("/etc", os.path.join(runs, RUN, "places", "etc"))
    with console(runs) as server:
        assert _raw(server.port, "GET", f"/files/{RUN}/leak.json")[0] == 403
        assert _raw(server.port, "GET", "/files/escape/secret.json")[0] == 403
        assert _raw(server.port, "GET", "/api/runs/escape")[0] == 403
        assert _raw(server.port, "GET", f"/files/{RUN}/places/etc/passwd")[0] in (403, 404)
        status, body = _raw(server.port, "GET", "/api/runs")
        assert status == 200 and [r["name"] for r in json.loads(body)["runs"]] == [RUN]
        # what is inside is served
        status, body = _raw(server.port, "GET", f"/files/{RUN}/places/A-01-2/block_1.png")
        assert status == 200 and body.startswith(b"\x89PNG")


def test_the_path_checks_themselves(tmp_path):
    root = RunsRoot(str(tmp_path))
    (tmp_path / "r").mkdir()
    for bad in ("..", ".", "", "a/b", "/etc", "a\\b", "x\x00"):
        with pytest.raises(PathRefused):
            root.run_dir(bad)
    for bad in ("../x.json", "a//b.json", "/abs.json", "a\\..\\b.json", "./x.json"):
        with pytest.raises(PathRefused):
            root.file("r", bad)
    with pytest.raises(PlaceEvidenceError):
        write_place_evidence(str(tmp_path / "r"), "../../x", None, None)
    assert not (tmp_path / "x").exists()


def test_oversized_and_foreign_requests_are_refused(runs):
    with console(runs) as server:
        port = server.port
        review = f"/api/runs/{RUN}/review"
        big = b"{" + b" " * 100_000 + b"}"
        headers = {"Host": f"127.0.0.1:{port}", "X-Console-Token": TOKEN}
        assert _raw(port, "POST", review, big, headers)[0] == 413
        # announced small, sent chunked without a length: counted as it arrives
        chunked = {**headers, "Transfer-Encoding": "chunked"}
        payload = b"".join(b"%x\r\n%s\r\n" % (8192, b"x" * 8192) for _ in range(4)) + b"0\r\n\r\n"
        assert _raw(port, "POST", review, payload, {**chunked, "Content-Length": "x"})[0] in (
            400,
            413,
        )
        status, _ = _raw(port, "POST", review, payload, chunked)
        assert status == 413
        assert _raw(port, "GET", "/" + "a" * 3000)[0] in (400, 414)
        assert _raw(port, "DELETE", f"/api/runs/{RUN}")[0] == 405
        evil = {"Host": "evil.example:80"}
        assert _raw(port, "GET", "/api/runs", headers=evil)[0] == 400


def test_a_decision_needs_the_token(runs):
    decision = json.dumps(
        {"place": "A-01-2", "decision": "leave_unknown", "reviewer": "x", "reason": "r"}
    ).encode()
    with console(runs) as server:
        port, path = server.port, f"/api/runs/{RUN}/review"
        host = {"Host": f"127.0.0.1:{port}", "Content-Type": "application/json"}
        assert _raw(port, "POST", path, decision, host)[0] == 403
        wrong = {**host, "X-Console-Token": TOKEN + "x"}
        assert _raw(port, "POST", path, decision, wrong)[0] == 403
        assert not os.path.exists(os.path.join(runs, RUN, "review.json"))
        # another site's page posting with the token (a leaked URL): refused by its origin
        evil = {**host, "X-Console-Token": TOKEN, "Origin": "http://evil.example"}
        assert _raw(port, "POST", path, decision, evil)[0] == 403
        fetch = {**host, "X-Console-Token": TOKEN, "Sec-Fetch-Site": "cross-site"}
        assert _raw(port, "POST", path, decision, fetch)[0] == 403
        assert not os.path.exists(os.path.join(runs, RUN, "review.json"))
        own = {**host, "X-Console-Token": TOKEN, "Origin": f"http://127.0.0.1:{port}"}
        status, body = _raw(port, "POST", path, decision, own)
        assert status == 200 and json.loads(body)["decision"]["answer"] == "unknown"
        # a form post with the token as a field works too; a settled place may be decided
        # again, naming the decision it replaces (not one made meanwhile it never saw)
        form = {"Host": host["Host"], "Content-Type": "application/x-www-form-urlencoded"}
        body = f"token={TOKEN}&place=A-01-2&decision=leave_unknown&reviewer=y".encode()
        status, said = _raw(port, "POST", path, body, form)
        assert status == 409 and b"was decided by x at" in said, said
        assert _raw(port, "POST", path, body + b"&replaces=1", form)[0] == 200
        # not an exception, unknown place, bad decision
        for bad, code in (
            ({"place": "A-01-1", "decision": "leave_unknown", "reviewer": "x"}, 409),
            ({"place": "Z-09-9", "decision": "leave_unknown", "reviewer": "x"}, 404),
            ({"place": "A-01-2", "decision": "delete", "reviewer": "x"}, 400),
            ({"place": "A-01-2", "decision": "leave_unknown"}, 400),
        ):
            tok = {**host, "X-Console-Token": TOKEN}
            assert _raw(port, "POST", path, json.dumps(bad).encode(), tok)[0] == code, bad
    review = json.load(open(os.path.join(runs, RUN, "review.json")))
    assert [d["reviewer"] for d in review["decisions"]] == ["x", "y"]
    assert open(os.path.join(runs, RUN, "review.csv")).read().count("\n") == 2  # latest only


def test_exports_defuse_spreadsheet_formulas(runs):
    with console(runs) as server:
        status, body = _raw(server.port, "GET", f"/export/{RUN}/inventory.csv")
        assert status == 200
        assert b"'=cmd|" in body and b"\r\nA-01-1," in body
        status, body = _raw(server.port, "GET", f"/export/{RUN}/discrepancies.csv")
        lines = body.decode().splitlines()
        assert status == 200 and lines[0] == ",".join(export.DISCREPANCY_COLUMNS)
        assert [line.split(",")[0] for line in lines[1:]] == ["A-01-2"]
        assert _raw(server.port, "GET", f"/export/{RUN}/inventory.exe")[0] == 404


def _btrun(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "btrun_launcher", *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_bad_command_lines_are_one_line_and_exit_2(tmp_path):
    r = _btrun("console", "--runs", str(tmp_path / "nope"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines() == [
        f"btrun console: --runs {tmp_path / 'nope'}: no such folder (fly a run first, or give "
        "--runs DIR)"
    ]
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen(1)
    port = busy.getsockname()[1]
    try:
        r = _btrun("console", "--runs", str(tmp_path), "--port", str(port))
    finally:
        busy.close()
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip() == (
        f"btrun console: --port {port}: cannot listen on 127.0.0.1:{port}: in use"
    )


def test_an_expected_stocks_discrepancies_are_counted_queued_and_exported(runs):
    doc = {
        "format": "btrun-discrepancies-1",
        "rows": [
            {"place": "A-01-1", "expected": "101", "found": "102", "category": "mismatch"},
            {"place": "A-01-2", "expected": "103", "found": "unknown", "category": "unverified"},
        ],
    }
    with open(os.path.join(runs, RUN, "discrepancies.json"), "w") as f:
        json.dump(doc, f)
    with console(runs) as server:
        status, body = _raw(server.port, "GET", "/api/runs")
        run = json.loads(body)["runs"][0]
        assert run["discrepancies"] == {"mismatch": 1, "unverified": 1}
        assert run["exceptions"] == 2  # both are in the review queue
        status, body = _raw(server.port, "GET", f"/export/{RUN}/discrepancies.csv")
    lines = body.decode().splitlines()[1:]
    assert [(x.split(",")[0], x.split(",")[5], x.split(",")[6]) for x in lines] == [
        ("A-01-1", "101", "mismatch"),
        ("A-01-2", "103", "unverified"),
    ]
