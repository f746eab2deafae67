"""Every run leaves a bounded record, and Groot2 peers are capped.

A mission file decides what goes on the blackboard, so nothing btrun keeps grows with it
unbounded: summary.json summarises large values as the tick log does and caps its size
(``bt_engine.summary``), the runner's in-memory trace keeps the same summaries and is
decimated past a memory budget (``bt_engine.runner.Trace``), :func:`bt_engine.run_cmd.finish`
writes summary.json whatever else fails (a reserve of file descriptors for the last write),
and the Groot2 server serves a bounded number of peers (``bt_engine.groot2``).
Lock-step runs on the simulated clock; the two subprocess runs (a descriptor hog, a
connection flood) are bounded in count and time.
"""

from __future__ import annotations

import json
import os
import resource
import socket
import subprocess
import sys
import tracemalloc

import pytest
from helpers import REPO, wait_until, wrap, xml_mission

from bt_engine import Runner
from bt_engine.ticklog import TickLog, read_log

BTRUN = [sys.executable, "-c", "from bt_engine.cli import main; raise SystemExit(main())"]

#: a script building one string of 64,512 characters in ``a`` (under MAX_STRING_LENGTH)
BIG = (
    "a := '" + "x" * 63 + "'; a := a..a..a..a..a..a..a..a; a := a..a..a..a..a..a..a..a; "
    "a := a..a..a..a..a..a..a..a; a := a..a"
)


def big_script(prefix: str, n: int = 10) -> str:
    """A Script node writing ``n`` distinct strings of ~64 kB (``<prefix>0`` ...)."""
    code = BIG + "; " + "; ".join(f"{prefix}{i} := a..'{i}'" for i in range(n))
    return f'<Script code="{code}"/>'


def run_btrun(argv: list[str], **kw) -> subprocess.CompletedProcess:
    return subprocess.run(BTRUN + argv, cwd=REPO, capture_output=True, text=True, timeout=240, **kw)


# -- 1. summary.json ---------------------------------------------------------------------------
def test_summary_json_is_bounded_and_summarises_as_the_tick_log(tmp_path, monkeypatch):
    """200 distinct blackboard strings of 64 kB (12.8 MB) and 4,000 small entries: the
    values are the tick log's notes, the entries past the values' budget (lowered here to
    50 kB) are listed by name only, and the file stays small."""
    from bt_engine import summary
    from bt_engine.cli import main

    monkeypatch.setattr(summary, "BLACKBOARD_LIMIT_BYTES", 50_000, raising=False)
    scripts = "".join(big_script(f"s{k}_") for k in range(20))
    small = "".join(
        '<Script code="' + "; ".join(f"m{k}_{i} := {i}" for i in range(400)) + '"/>'
        for k in range(10)
    )
    mission = tmp_path / "big.xml"
    mission.write_text(wrap(f"<Sequence>{scripts}{small}<Sleep msec='40'/></Sequence>"))
    out = tmp_path / "run"
    rc = main([str(mission), "--out", str(out), "-q", "--no-report", "--no-mcap"])
    assert rc == 0
    text = (out / "summary.json").read_text()
    assert len(text) < 300_000  # 12.8 MB of values before
    s = json.loads(text)
    assert s["status"] == "SUCCESS" and "errors" not in s
    bb = s["blackboard"]
    assert bb["s0_0"].startswith("<str of 64515 bytes, sha1 ") and bb["s0_0"].endswith(
        "not logged>"
    )
    _, records = read_log(str(out / "ticks.jsonl"))
    logged = {k: v for r in records for k, v in r.get("bb", {}).items()}
    assert bb["s19_9"] == logged["s19_9"]  # one implementation: the tick log's note
    omitted = s["blackboard_omitted"]
    assert omitted["names"] and "by name only" in omitted["why"]
    assert "unlisted" not in omitted and set(bb) | set(omitted["names"]) == set(logged)
    assert not set(bb) & set(omitted["names"])


def test_a_section_past_its_limit_is_a_note_and_a_raising_part_an_error(monkeypatch):
    from bt_engine import summary as summ
    from bt_engine.runner import RunResult

    class Broken:  # a resource reporting on the run whose summary raises (forged data)
        def run_summary(self) -> dict:
            raise TypeError("forged")

        def result_lines(self) -> list[str]:
            return []

    m = xml_mission(wrap("<AlwaysSuccess/>"), resources={"broken": Broken()})
    result = RunResult("SUCCESS", "done", 1, 0.02, 0.01)
    monkeypatch.setattr(summ, "SECTION_LIMIT_BYTES", 10_000, raising=False)
    s = summ.build_summary(
        result, m, mission_path="m.xml", seed=0, rate_hz=50.0, sections={"sim": ["x" * 100] * 500}
    )
    assert s["sim"].startswith("<section of ") and "not kept" in s["sim"]
    assert any(e.startswith("section broken: TypeError: forged") for e in s["errors"])
    assert s["status"] == "SUCCESS" and s["ticks"] == 1


# -- 2 and 3. the in-memory trace --------------------------------------------------------------
def _ticking_mission(n_scripts: int, ticks: int):
    """Every tick, ``n_scripts`` scripts write 10 new strings of 64 kB each."""
    body = "".join(big_script(f"k{j}_") for j in range(n_scripts))
    xml = wrap(
        f'<Repeat num_cycles="{ticks}"><Sequence>{body}<Sleep msec="20"/></Sequence></Repeat>'
    )
    return xml_mission(xml)


def test_the_trace_keeps_the_tick_logs_summaries_not_the_values(tmp_path):
    """2.7 kB of mission wrote 640 kB a tick into the trace (2.9 GB in 63 s): now the trace,
    like the tick log, keeps a note per large value and memory stays flat."""
    from bt_engine.ticklog import summarise_value

    m = _ticking_mission(1, 60)
    log = TickLog(str(tmp_path / "t.jsonl"))
    runner = Runner(m, log=log)
    tracemalloc.start()
    try:
        runner.run()
        current, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    log.close()
    assert current < 8_000_000, current  # 60 ticks x 640 kB = 38 MB kept before
    kept = [v for r in runner.trace for v in r.get("bb", {}).values()]
    assert len(kept) >= 600 and all(len(str(v)) < 200 for v in kept)
    _, records = read_log(str(tmp_path / "t.jsonl"))
    assert [r.get("bb") for r in records] == [r.get("bb") for r in runner.trace]
    last = [r for r in runner.trace if "bb" in r][-1]
    assert last["bb"]["k0_3"] == summarise_value(m.scope.get("k0_3"))
    assert runner.last_record is runner.trace[-1]  # summarised too


@pytest.mark.parametrize("keep_trace", [True, False])
def test_a_tick_does_not_hold_the_previous_ticks_values(keep_trace):
    """The 1.36 MB mission's MemoryError in flight: the previous tick's record (kept in the
    trace and as ``last_record``) held every value the scripts had just replaced, so each
    tick needed twice the blackboard. Now the peak is the blackboard plus small change."""
    live = 4 * 10 * 64_500
    tracemalloc.start()
    try:
        m = _ticking_mission(4, 40)
        runner = Runner(m)
        runner.keep_trace = keep_trace
        for _ in range(3):
            runner.step()
        base, _ = tracemalloc.get_traced_memory()
        assert base > live
        tracemalloc.reset_peak()
        for _ in range(10):
            runner.step()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak - base < live // 2, (peak - base, live)


def _vehicle(i: int) -> dict:
    x = 0.001 * i
    return {"x": x, "y": 0.0, "z": 1.0, "yaw": 0.0, "state": "flying", "vbat": 4.0}


def test_the_trace_is_decimated_past_its_budget_and_the_report_still_reads_it():
    from bt_engine.runner import Trace, record_cost
    from nodes.report.metrics import action_spans, telemetry_arrays

    limit = 2_000_000
    trace = Trace(limit_bytes=limit)
    for i in range(1, 30_001):
        rec = {"tick": i, "t": i * 0.02, "status": "RUNNING", "vehicle": _vehicle(i)}
        if i % 1000 == 1:
            rec["changed"] = {"M/a": "RUNNING"}
        if i % 1000 == 500:
            rec["changed"] = {"M/a": "SUCCESS"}
            rec["messages"] = ["x" * 20_000]  # summarised to a note
        trace.append(rec)
        assert trace.cost <= limit
    assert trace.stride > 1 and not trace.thin_events
    assert len(trace) < 30_000 // 2
    assert trace[-1]["tick"] == 30_000  # the newest record is always kept
    assert trace.cost == sum(record_cost(r) for r in trace)
    ticks = [r["tick"] for r in trace]
    assert ticks == sorted(ticks)
    tel = telemetry_arrays(trace)
    assert tel is not None and tel["t"][-1] == pytest.approx(600.0)
    spans = action_spans(trace, ["M/a"])
    assert len(spans) == 30 and all(s[3] == "SUCCESS" for s in spans)  # every event kept
    assert spans[0][1] == pytest.approx(0.02) and spans[0][2] == pytest.approx(10.0)
    assert all(m.startswith("<str of 20002 bytes") for r in trace for m in r.get("messages", ()))


def test_events_every_tick_are_decimated_too():
    """Records that all carry events (3,000 status changes a tick, as a wide tree whose
    leaves flip every tick): the events are decimated too and the trace stays bounded."""
    from bt_engine.runner import Trace

    paths = [f"Main/Parallel/leaf[{i}]" for i in range(3000)]
    trace = Trace(limit_bytes=5_000_000)
    for tick in range(1, 301):
        status = "SUCCESS" if tick % 2 else "FAILURE"
        trace.append({"tick": tick, "t": tick * 0.02, "changed": dict.fromkeys(paths, status)})
        assert trace.cost <= 5_000_000
    assert trace.thin_events and len(trace) < 30
    assert trace[-1]["tick"] == 300 and len(trace[-1]["changed"]) == 3000


def test_a_normal_flight_keeps_every_tick():
    """The budget fits a 20-minute flight at 50 Hz with room to spare: the report and the
    motion table see every tick of a normal mission."""
    import nodes  # noqa: F401  (registers the drone leaves)
    from bt_engine import Mission, SimClock
    from bt_engine.runner import TRACE_LIMIT_BYTES, record_cost
    from drivers.rig.factory import make_platform
    from drivers.rig.loader import load_rig

    clock = SimClock()
    platform = make_platform(load_rig(None), clock, seed=0)
    path = os.path.join(REPO, "missions", "yaw_test.xml")
    m = Mission.from_file(path, clock=clock, vehicle=platform.vehicle)
    runner = Runner(m, hooks=[platform], telemetry=platform.telemetry_row)
    result = runner.run(max_time_s=120)
    assert result.status == "SUCCESS"
    assert runner.trace.stride == 1 and len(runner.trace) == result.ticks
    per_tick = runner.trace.cost / len(runner.trace)
    assert per_tick * 20 * 60 * 50 < TRACE_LIMIT_BYTES / 2
    # the estimate follows the memory the records really take (their own objects)
    real = sum(_deep_size(r) for r in runner.trace) / len(runner.trace)
    assert 0.8 * real < per_tick < 2 * real, (per_tick, real)
    assert record_cost(runner.trace[-1]) < 2 * real


def _deep_size(obj: object) -> int:
    size = sys.getsizeof(obj)
    if isinstance(obj, dict):
        size += sum(_deep_size(v) for v in obj.values())  # keys: shared strings
    elif isinstance(obj, (list, tuple)):
        size += sum(_deep_size(v) for v in obj)
    return size


# -- 4. finish() always writes summary.json ----------------------------------------------------
def test_finish_writes_the_summary_when_sections_and_the_report_raise(
    tmp_path, monkeypatch, capsys
):
    from bt_engine import run_cmd
    from bt_engine.cli import main

    def no_memory(*a, **k):
        raise MemoryError

    def forged(*a, **k):
        raise TypeError("unsupported operand type(s) for -: 'str' and 'float'")

    def no_fds(*a, **k):
        raise OSError(24, "Too many open files")

    monkeypatch.setattr(run_cmd, "write_report", no_memory)
    monkeypatch.setattr(run_cmd, "run_sections", forged)
    from nodes.plugin import RigTarget

    monkeypatch.setattr(RigTarget, "run_summary", no_fds)
    mission = os.path.join(REPO, "missions", "yaw_test.xml")
    out = tmp_path / "run"
    rc = main([mission, "--out", str(out), "--no-mcap"])
    captured = capsys.readouterr()
    assert rc == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "SUCCESS" and s["ticks"] > 0 and "blackboard" in s
    errors = "\n".join(s["errors"])
    assert "report: MemoryError" in errors
    assert "plug-in sections: TypeError: unsupported operand" in errors
    assert "run target's sections: OSError: [Errno 24] Too many open files" in errors
    assert "Traceback" not in captured.err + captured.out
    assert "btrun: report: MemoryError" in captured.err


HOG = """
import os, sys
from bt_engine import run_cmd

held = []
make_runner = run_cmd.make_runner


class Hog:
    def after_tick(self, t):
        if t >= 0.5 and not held:  # a leaking leaf: every descriptor of the process taken
            try:
                while len(held) < 100_000:
                    held.append(os.open(os.devnull, os.O_RDONLY))
            except OSError:
                pass


def hogging_runner(run):
    runner = make_runner(run)
    runner.hooks.append(Hog())
    return runner


run_cmd.make_runner = hogging_runner
from bt_engine.cli import main
raise SystemExit(main())
"""


def test_finish_writes_the_summary_when_descriptors_run_out(tmp_path):
    """A leak takes every file descriptor in flight: the report cannot be written, but
    summary.json is (from the reserve of descriptors), names what failed, and no traceback
    is printed."""
    out = tmp_path / "run"
    mission = os.path.join(REPO, "missions", "yaw_test.xml")
    proc = subprocess.run(
        [sys.executable, "-c", HOG, mission, "--out", str(out), "--no-mcap"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=240,
        preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_NOFILE, (256, 256)),
    )
    assert "Traceback" not in proc.stderr + proc.stdout, proc.stderr[-3000:]
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "SUCCESS" and s["ticks"] > 0, s
    assert any("Too many open files" in e for e in s["errors"]), s["errors"]
    assert proc.returncode == 0, proc.stderr[-2000:]


# -- 5. Groot2 peers ---------------------------------------------------------------------------
def _raise_own_fd_limit(n: int) -> None:
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < n:
        resource.setrlimit(resource.RLIMIT_NOFILE, (min(n, hard), hard))


def test_groot2_serves_at_most_max_peers_and_idle_ones_make_room():
    """Raw TCP connections past ``max_peers`` are shut down as soon as they are accepted;
    a Groot2 client connected before the flood is served throughout; idle connections are
    closed after the handshake time, so a new client gets in."""
    import selectors

    zmq = pytest.importorskip("zmq")
    from test_groot2 import Client

    from bt_engine.groot2 import FULLTREE, Groot2Server

    m = xml_mission(wrap('<Sleep msec="100000"/>'))
    ctx = zmq.Context()
    sel = selectors.DefaultSelector()
    with Groot2Server(m, port=0, max_peers=4) as server:
        try:
            first = Client(ctx, server.port)
            assert first.request(FULLTREE)[1].startswith(b"<root")
            wait_until(lambda: server.peers == 1, 10, "the first client counted")
            for i in range(40):
                s = socket.socket()
                s.setblocking(False)
                s.connect_ex(("127.0.0.1", server.port + i % 2))
                sel.register(s, selectors.EVENT_READ)
            assert first.request(FULLTREE)[1].startswith(b"<root")  # still served
            most = [0]

            def flood_closed() -> bool:  # each flood socket sees the server close it
                most[0] = max(most[0], server.peers)
                for key, _ in sel.select(0):
                    try:
                        data = key.fileobj.recv(4096)  # ZeroMQ's greeting, or the end
                    except OSError:
                        data = b""
                    if not data:
                        sel.unregister(key.fileobj)
                        key.fileobj.close()
                return not sel.get_map()

            wait_until(flood_closed, 30, "every flood connection closed by the server")
            assert most[0] <= 8 and server.refused >= 40 - 7
            wait_until(lambda: server.peers == 1, 10, "the idle connections gone")
            assert first.request(FULLTREE)[1].startswith(b"<root")
            late = Client(ctx, server.port)
            assert late.request(FULLTREE)[1].startswith(b"<root")
            late.sock.close(0)
            first.sock.close(0)
        finally:
            for key in list(sel.get_map().values()):
                key.fileobj.close()
    ctx.term()


def _free_port_pair() -> int:
    for _ in range(50):
        with socket.socket() as a:
            a.bind(("127.0.0.1", 0))
            port = a.getsockname()[1]
            with socket.socket() as b:
                try:
                    b.bind(("127.0.0.1", port + 1))
                except OSError:
                    continue
                return port
    raise AssertionError("no free pair of ports")


def test_groot2_connection_flood_leaves_the_flight_and_its_summary_alone(tmp_path):
    """600 idle TCP connections to ``--groot`` under a limit of 256 descriptors (1,100 under
    1,024 in the report): btrun keeps flying, writes its report and summary.json."""
    import selectors

    _raise_own_fd_limit(2048)
    port = _free_port_pair()
    mission = tmp_path / "hover.xml"
    mission.write_text(
        wrap(
            '<Sequence><TakeOff height="0.5" speed="0.5"/><Hover duration="3"/>'
            '<Land speed="0.5"/></Sequence>'
        )
    )
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [*BTRUN, str(mission), "--groot", str(port), "--realtime", "--out", str(out), "--no-mcap"],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_NOFILE, (256, 256)),
    )
    flood: list[socket.socket] = []
    try:
        assert proc.stdout is not None
        sel = selectors.DefaultSelector()
        sel.register(proc.stdout, selectors.EVENT_READ)
        head = ""
        while "Groot2 monitor on" not in head:
            assert sel.select(60), "btrun did not start its Groot2 server"
            line = proc.stdout.readline()
            assert line, head
            head += line
        for i in range(600):
            s = socket.socket()
            s.setblocking(False)
            s.connect_ex(("127.0.0.1", port + i % 2))
            flood.append(s)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        for s in flood:
            s.close()
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, stdout + stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "SUCCESS" and "errors" not in s, s.get("errors")
    assert s.get("report") == "report.html"
    assert "Traceback" not in stderr


def test_a_value_whose_repr_raises_is_recorded_not_fatal() -> None:
    """A plug-in object that cannot say what it is must not end a run in its record."""
    from bt_engine.ticklog import summarise_value, to_jsonable

    class Broken:
        def __repr__(self) -> str:
            raise RuntimeError("no repr")

    assert to_jsonable(Broken()) == "<Broken: repr failed: RuntimeError>"
    assert "repr failed" in str(summarise_value({"face": Broken()}))
