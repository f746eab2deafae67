"""Per-tick cost of the Groot2 monitor (``btrun --groot``): the runner at 50 Hz, with and without
a Groot2 client attached, in the same run.

The mission is the worst case for the monitor: a ``ReactiveSequence`` re-ticks every node
every tick (``--nodes`` nodes: groups of ``Sequence[AlwaysSuccess x m, Script]`` and a
``Sleep`` that stays RUNNING), so every node changes status twice per tick and the status
buffer is rewritten each time. The runner ticks on a SimClock paced to 50 Hz by sleeping
between ticks, alternating blocks of ``--block`` ticks:

* off: no Groot2 hook, the client idle;
* on: the :class:`~bt_engine.groot2.Groot2Server` is a runner hook and a client (another
  thread, as Groot2 does) subscribes to the publisher and asks for STATUS every tick and for
  the blackboard every 5th tick.

One tick's cost is the wall time of ``Runner.step()`` (tick + hooks + record); the ratio of
the means (and medians) on/off is printed (target: < 5 % extra). It prints figures; it is
not a test::

    .venv/bin/python bench/groot2_overhead.py             # 20 s
    .venv/bin/python bench/groot2_overhead.py --seconds 2 # quick look
"""

from __future__ import annotations

import argparse
import os
import statistics
import struct
import sys
import threading
import time

if __package__ in (None, ""):
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import zmq

from bt_engine import Mission, Runner, SimClock
from bt_engine.groot2 import Groot2Server
from bt_engine.loading import load_xml

RATE_HZ = 50.0


def mission_xml(nodes: int, group: int = 8) -> str:
    """A ReactiveSequence over about ``nodes`` nodes, all ticked every tick."""
    groups = max(1, (nodes - 2) // (group + 2))
    body = []
    for g in range(groups):
        leaves = "".join(f'<AlwaysSuccess name="ok{g}_{i}"/>' for i in range(group))
        body.append(
            f'<Sequence name="g{g}">{leaves}<Script name="w{g}" code="v{g} := v{g} + 1"/></Sequence>'
        )
    body.append('<Sleep name="hold" msec="100000000"/>')
    return (
        '<root BTCPP_format="4" main_tree_to_execute="Main"><BehaviorTree ID="Main">'
        f'<ReactiveSequence name="root">{"".join(body)}</ReactiveSequence>'
        "</BehaviorTree></root>"
    )


class Client(threading.Thread):
    """A Groot2-like client: STATUS every tick period, BLACKBOARD every 5th, SUB on PUB."""

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        self.port = port
        self.active = threading.Event()
        self.stop = threading.Event()
        self.replies = 0

    def run(self) -> None:
        ctx = zmq.Context()
        req = ctx.socket(zmq.REQ)
        sub = ctx.socket(zmq.SUB)
        for s in (req, sub):
            s.setsockopt(zmq.LINGER, 0)
        req.setsockopt(zmq.RCVTIMEO, 2000)
        req.connect(f"tcp://127.0.0.1:{self.port}")
        sub.connect(f"tcp://127.0.0.1:{self.port + 1}")
        sub.setsockopt(zmq.SUBSCRIBE, b"")
        n = 0
        try:
            while not self.stop.is_set():
                if not self.active.wait(0.05):
                    continue
                n += 1
                kind = b"B" if n % 5 == 0 else b"S"
                parts = [struct.pack("<BcI", 2, kind, n)]
                if kind == b"B":
                    parts.append(b"Main")
                req.send_multipart(parts)
                req.recv_multipart()
                self.replies += 1
                time.sleep(1.0 / RATE_HZ)
        finally:
            req.close(0)
            sub.close(0)
            ctx.term()


def measure(seconds: float, nodes: int, block: int) -> dict[str, list[float]]:
    xml = mission_xml(nodes)
    groups = xml.count("<Sequence ")
    mission = Mission(
        load_xml("bench.xml", text=xml),
        clock=SimClock(),
        blackboard={f"v{g}": 0 for g in range(groups)},
    )
    runner = Runner(mission, RATE_HZ)
    runner.keep_trace = False
    server = Groot2Server(mission, port=0)
    client = Client(server.port)
    client.start()
    times: dict[str, list[float]] = {"off": [], "on": []}
    period = 1.0 / RATE_HZ
    ticks = int(seconds * RATE_HZ)
    next_t = time.perf_counter()
    try:
        for i in range(ticks):
            on = (i // block) % 2 == 1
            if on and server not in runner.hooks:
                runner.hooks.append(server)
                client.active.set()
            elif not on and server in runner.hooks:
                runner.hooks.remove(server)
                client.active.clear()
            t0 = time.perf_counter()
            runner.step()
            times["on" if on else "off"].append(time.perf_counter() - t0)
            next_t += period
            delay = next_t - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
    finally:
        client.stop.set()
        client.active.set()
        client.join(5)
        server.close()
    print(
        f"mission: {len(mission.nodes)} nodes, all ticked every tick; {ticks} ticks at "
        f"{RATE_HZ:g} Hz; client replies {client.replies}"
    )
    return times


def main(argv: list[str] | None = None) -> float:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="wall time of the run")
    ap.add_argument("--nodes", type=int, default=200, help="size of the mission tree")
    ap.add_argument("--block", type=int, default=25, help="ticks per on/off block")
    args = ap.parse_args(argv)
    times = measure(args.seconds, args.nodes, args.block)
    rows = {}
    for label in ("off", "on"):
        t = times[label]
        rows[label] = (statistics.mean(t), statistics.median(t))
        print(
            f"  monitor {label:<3}: mean {rows[label][0] * 1e6:8.1f} us  "
            f"median {rows[label][1] * 1e6:8.1f} us  ({len(t)} ticks)"
        )
    ratio_mean = rows["on"][0] / rows["off"][0] - 1.0
    ratio_median = rows["on"][1] / rows["off"][1] - 1.0
    print(
        f"Groot2 overhead per tick: {ratio_mean * 100:+.1f} % (mean), "
        f"{ratio_median * 100:+.1f} % (median); target < 5 %"
    )
    return ratio_mean


if __name__ == "__main__":
    main()
