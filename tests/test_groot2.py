"""Groot2 live monitoring (``bt_engine.groot2``) against BehaviorTree.CPP's own Groot2Publisher.

The same XML runs in BT.CPP (behaviortreepy, its ``Groot2Publisher`` on one port) and in
btrun (Mission + Runner on a SimClock, ``Groot2Server`` on another); a ZeroMQ client written
here from BT.CPP's ``groot2_protocol.h`` queries both and the replies are compared field by
field: reply headers, the FULLTREE XML (structure, attributes, UIDs), the STATUS buffer after
the same ticks, the BLACKBOARD dump (MessagePack, decoded here) and the error replies.
Every mission in missions/ is compared too (FULLTREE and STATUS), its drone leaves replaced
by dummies of the same ID, kind and ports in both engines
(``test_every_mission_equals_btcpp_publisher``).
Everything is on 127.0.0.1, with free ports and bounded waits.
"""

from __future__ import annotations

import dataclasses
import glob
import os
import socket
import struct
import xml.etree.ElementTree as ET

import pytest
from helpers import REPO, wait_until, wrap, xml_mission

zmq = pytest.importorskip("zmq")
msgpack = pytest.importorskip("msgpack")

from bt_engine import Runner  # noqa: E402
from bt_engine.groot2 import Groot2Server  # noqa: E402

TIMEOUT_MS = 2000

XML = """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <Sequence name="seq">
      <SetBlackboard name="sb" output_key="a" value="42"/>
      <Script name="sc" code="b := 3.5; n := 7; s := 'hi'"/>
      <Fallback name="fb">
        <AlwaysFailure name="af"/>
        <SubTree ID="Sub" name="sub" x="{n}"/>
      </Fallback>
      <SubTree ID="Sub"/>
      <Parallel name="par"><AlwaysSuccess name="pa"/></Parallel>
      <Repeat name="rep" num_cycles="2"><AlwaysSuccess name="ra"/></Repeat>
      <Sleep name="sl" msec="100000"/>
    </Sequence>
  </BehaviorTree>
  <BehaviorTree ID="Sub">
    <Sequence name="ss">
      <Script name="ssc" code="loc := 5; x := 8" _skipIf="false"/>
      <SubTree ID="Leaf" _autoremap="true"/>
    </Sequence>
  </BehaviorTree>
  <BehaviorTree ID="Leaf"><AlwaysSuccess name="leaf"/></BehaviorTree>
</root>
"""
BLACKBOARDS = b"Main;sub;Sub::8;sub/Leaf::6;nope"


# -- a Groot2 client written from groot2_protocol.h -----------------------------------------
def header(kind: bytes, request_id: int = 0x1234ABCD, protocol: int = 2) -> bytes:
    return struct.pack("<BcI", protocol, kind, request_id)


class Client:
    """A REQ client; a reply that does not come within TIMEOUT_MS fails the test."""

    def __init__(self, ctx, port: int) -> None:
        self.sock = ctx.socket(zmq.REQ)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.RCVTIMEO, TIMEOUT_MS)
        self.sock.setsockopt(zmq.SNDTIMEO, TIMEOUT_MS)
        self.sock.connect(f"tcp://127.0.0.1:{port}")

    def ask(self, *parts: bytes) -> list[bytes]:
        self.sock.send_multipart(list(parts))
        return self.sock.recv_multipart()

    def request(self, kind: bytes, *extra: bytes) -> list[bytes]:
        return self.ask(header(kind), *extra)

    def close(self) -> None:
        self.sock.close(0)


def check_reply_header(part: bytes, kind: bytes, request_id: int = 0x1234ABCD) -> bytes:
    assert len(part) == 22
    protocol, k, rid = struct.unpack("<BcI", part[:6])
    assert (protocol, k, rid) == (2, kind, request_id)
    return part[6:]  # the tree UUID


def msgpack_decode(data: bytes):
    """Decode a MessagePack payload (the msgpack package; trailing bytes are refused)."""
    return msgpack.unpackb(data, raw=False, strict_map_key=True)


def normal(value):
    """Blackboard values as both engines may type them: numbers by value (bools as 0/1)."""
    if isinstance(value, dict):
        return {k: normal(v) for k, v in value.items()}
    if isinstance(value, list):
        return [normal(v) for v in value]
    if isinstance(value, (bool, int, float)):
        return round(float(value), 6)
    return value


def tree_shape(xml: str) -> tuple[list, dict]:
    """(every BehaviorTree as (ID, _fullpath, nested node tuples), TreeNodesModel by ID)."""
    root = ET.fromstring(xml)
    assert root.tag == "root" and root.get("BTCPP_format") == "4"

    def node(el):
        return (el.tag, dict(el.attrib), [node(c) for c in el])

    trees = [
        (t.get("ID"), t.get("_fullpath"), [node(c) for c in t]) for t in root.iter("BehaviorTree")
    ]
    models = {}
    for m in root.iter("TreeNodesModel"):
        for el in m:
            models[el.get("ID")] = (el.tag, sorted(p.get("name") for p in el if "port" in p.tag))
    return trees, models


def uids_of(trees: list) -> list[int]:
    out: list[int] = []

    def walk(n):
        out.append(int(n[1]["_uid"]))
        for c in n[2]:
            walk(c)

    for _, _, nodes in trees:
        for n in nodes:
            walk(n)
    return out


def status_pairs(buf: bytes) -> list[tuple[int, int]]:
    assert len(buf) % 3 == 0
    return [(struct.unpack("<H", buf[i : i + 2])[0], buf[i + 2]) for i in range(0, len(buf), 3)]


def free_port_pair() -> int:
    """A port p with p and p + 1 free on 127.0.0.1 (BT.CPP needs an explicit port)."""
    for _ in range(50):
        with socket.socket() as a:
            a.bind(("127.0.0.1", 0))
            p = a.getsockname()[1]
            if p >= 65535:
                continue
            with socket.socket() as b:
                try:
                    b.bind(("127.0.0.1", p + 1))
                except OSError:
                    continue
        return p
    raise RuntimeError("no free port pair")


@pytest.fixture
def ctx():
    c = zmq.Context()
    yield c
    c.term()


@pytest.fixture
def btcpp():
    """behaviortreepy with its Groot2Publisher, or a clean skip."""
    bt = pytest.importorskip("behaviortreepy")
    if not getattr(bt, "GROOT2_AVAILABLE", False) or not hasattr(bt, "Groot2Publisher"):
        pytest.skip("behaviortreepy was built without Groot2 support")
    return bt


# -- the differential test -------------------------------------------------------------------
def test_replies_equal_btcpp_publisher(ctx, btcpp):
    tree = btcpp.BehaviorTreeFactory().create_tree_from_text(XML)
    bt_port = free_port_pair()
    publisher = btcpp.Groot2Publisher(tree, bt_port)
    mission = xml_mission(XML)
    runner = Runner(mission, 50.0)
    server = Groot2Server(mission, port=0)
    runner.hooks.append(server)
    assert server.address == "127.0.0.1" and server.publisher_port == server.port + 1
    theirs, ours = Client(ctx, bt_port), Client(ctx, server.port)
    try:
        # the tree, before any tick
        t_reply, o_reply = theirs.request(b"T"), ours.request(b"T")
        assert len(t_reply) == len(o_reply) == 2
        check_reply_header(t_reply[0], b"T")
        uuid = check_reply_header(o_reply[0], b"T")
        t_trees, t_models = tree_shape(t_reply[1].decode())
        o_trees, o_models = tree_shape(o_reply[1].decode())
        assert o_trees == t_trees  # IDs, _fullpath, tags, names, _uid, ports, conditions
        assert sorted(uids_of(o_trees)) == list(range(1, len(mission.nodes) + 1))
        used = {tag for _, _, nodes in t_trees for tag in _tags(nodes)} - {"SubTree"}
        for tag in used:
            assert o_models[tag] == t_models[tag], tag
        # the status buffer, before and after the same ticks
        for tick in range(4):
            if tick:
                assert tree.tick_once().name == runner.step().value
            t_reply, o_reply = theirs.request(b"S"), ours.request(b"S")
            check_reply_header(t_reply[0], b"S")
            assert check_reply_header(o_reply[0], b"S") == uuid  # one UUID per tree
            assert status_pairs(o_reply[1]) == status_pairs(t_reply[1]), f"after tick {tick}"
        # the blackboards
        t_reply, o_reply = theirs.request(b"B", BLACKBOARDS), ours.request(b"B", BLACKBOARDS)
        check_reply_header(t_reply[0], b"B")
        check_reply_header(o_reply[0], b"B")
        t_bb, o_bb = msgpack_decode(t_reply[1]), msgpack_decode(o_reply[1])
        assert set(o_bb) == set(t_bb) and "Main" in o_bb
        assert normal(o_bb) == normal(t_bb)
        # the same answer to the same odd requests
        odd = [
            [b"abc"],  # truncated header
            [header(b"S") + b"\x00"],  # one byte too long
            [header(b"Z")],  # unknown request type
            [header(b"N")],  # BREAKPOINT_REACHED is sent by the executor, never asked
            [header(b"B")],  # BLACKBOARD without its second part
            [header(b"D")],  # HOOKS_DUMP: no hooks
            [header(b"A")],  # REMOVE_ALL_HOOKS
            [header(b"X")],  # DISABLE_ALL_HOOKS
            [header(b"S", protocol=9)],  # BT.CPP answers with its own protocol id
        ]
        for parts in odd:
            t_reply, o_reply = theirs.ask(*parts), ours.ask(*parts)
            assert [p[:6] for p in o_reply] == [p[:6] for p in t_reply], parts
            assert [len(p) for p in o_reply] == [len(p) for p in t_reply], parts
    finally:
        theirs.close()
        ours.close()
        server.close()
        del publisher


def _tags(nodes):
    for tag, _, children in nodes:
        yield tag
        yield from _tags(children)


# -- robustness ------------------------------------------------------------------------------
def test_garbage_gets_error_replies_while_the_mission_ticks(ctx):
    body = """
    <Repeat num_cycles="-1">
      <Sequence name="loop">
        <Script name="count" code="ticks := ticks + 1"/>
        <Sleep name="nap" msec="40"/>
      </Sequence>
    </Repeat>"""
    mission = xml_mission(wrap(body), blackboard={"ticks": 0})
    reference = xml_mission(wrap(body), blackboard={"ticks": 0})
    runner, ref_runner = Runner(mission, 50.0), Runner(reference, 50.0)
    with Groot2Server(mission, port=0) as server:
        runner.hooks.append(server)
        client = Client(ctx, server.port)
        dealer = ctx.socket(zmq.DEALER)  # sends any frames, no REQ envelope rules
        dealer.setsockopt(zmq.LINGER, 0)
        dealer.setsockopt(zmq.RCVTIMEO, TIMEOUT_MS)
        dealer.connect(f"tcp://127.0.0.1:{server.port}")
        raw = socket.create_connection(("127.0.0.1", server.port), timeout=2)
        try:
            raw.sendall(b"GET / HTTP/1.0\r\n\r\n" + bytes(range(256)))  # not even ZMTP
            bad = [
                ([b"\xff" * 40], b"wrong request header"),
                ([b"\x02S"], b"wrong request header"),  # truncated header
                ([b""], b"wrong request header"),
                ([header(b"?")], b"Request not recognized"),
                ([header(b"I"), b'{"uid": 1}'], b"Request not recognized"),  # no breakpoints
                ([header(b"U"), b"{}"], b"Request not recognized"),
                ([header(b"r"), b"start"], b"Request not recognized"),  # no recording
                ([header(b"B"), b"a", b"b"], b"must be 2 parts message"),
                ([header(b"S"), b"x", b"x", b"x", b"x", b"x"], b"too many message parts"),
            ]
            for parts, why in bad:
                runner.step()
                ref_runner.step()
                assert client.ask(*parts) == [b"error", why], parts
                dealer.send_multipart([b"", *parts])
                assert dealer.recv_multipart() == [b"", b"error", why]
            dealer.send_multipart([b"", header(b"S"), b"z" * 100_000])  # over the frame limit
            runner.step()
            ref_runner.step()
            reply = client.request(b"S")  # still serving
            check_reply_header(reply[0], b"S")
            assert len(reply[1]) == 3 * len(mission.nodes)
            wait_until(lambda: server.requests >= 2 * len(bad) + 1, 5, "the server's count")
        finally:
            raw.close()
            dealer.close(0)
            client.close()
    assert server.errors == 2 * len(bad)
    assert mission.ticks == reference.ticks == len(bad) + 1
    assert mission.blackboard["ticks"] == reference.blackboard["ticks"] > 1
    assert [r.get("changed") for r in runner.trace] == [r.get("changed") for r in ref_runner.trace]


def test_status_codes_and_blackboard_values():
    body = """
    <Sequence name="s">
      <Script name="w" code="f := 0.1; big := 70000; neg := -3; t := true; txt := 'é'"/>
      <Sleep name="z" msec="1000"/>
    </Sequence>"""
    mission = xml_mission(wrap(body))
    with Groot2Server(mission, port=0) as server:
        runner = Runner(mission, 50.0, hooks=[server])
        pairs = dict(status_pairs(server.status_buffer()))
        assert pairs == {1: 0, 2: 0, 3: 0}
        runner.step()
        pairs = dict(status_pairs(server.status_buffer()))
        assert pairs == {1: 1, 2: 2, 3: 1}  # RUNNING, SUCCESS, RUNNING
        mission.halt()
        server.shutdown("test")
        assert dict(status_pairs(server.status_buffer())) == {
            1: 11,
            2: 12,
            3: 11,
        }  # IDLE after X: 10 + X
        bb = msgpack_decode(msgpack.packb(server.blackboards("Main;Main;unknown")))
        assert bb == {"Main": {"big": 70000, "f": 0.1, "neg": -3, "t": True, "txt": "é"}}
        assert not server.connected


def _ask_blackboards(ctx, server: Groot2Server, names: bytes) -> bytes:
    """The BLACKBOARD payload for ``names``, asked over the protocol as Groot2 asks."""
    client = Client(ctx, server.port)
    try:
        reply = client.request(b"B", names)
    finally:
        client.close()
    assert len(reply) == 2, reply
    check_reply_header(reply[0], b"B")
    return reply[1]


def test_blackboard_payload_is_what_the_msgpack_package_writes(ctx):
    """The BLACKBOARD payload is encoded by the maintained ``msgpack`` package (no encoder
    of btrun's own): byte for byte ``msgpack.packb`` of the JSON object, which Groot2 (and
    BT.CPP's nlohmann ``from_msgpack``) decodes to the same values as BT.CPP's own reply
    (``test_replies_equal_btcpp_publisher``)."""
    code = "b := 3.5; f := 0.1; n := 7; big := 70000; neg := -3; t := true; s := 'hi'; u := 'é'"
    mission = xml_mission(wrap(f'<Script name="w" code="{code}"/>'))
    with Groot2Server(mission, port=0) as server:
        Runner(mission, 50.0, hooks=[server]).step()
        payload = _ask_blackboards(ctx, server, b"Main;nope")
    expected = {
        "Main": {
            "b": 3.5,
            "big": 70000,
            "f": 0.1,
            "n": 7,
            "neg": -3,
            "s": "hi",
            "t": True,
            "u": "é",
        }
    }
    assert payload == msgpack.packb(expected)
    assert msgpack_decode(payload) == expected


def test_msgpack_is_a_declared_dependency():
    """A fresh ``pip install -e .`` installs the MessagePack library groot2_protocol.py imports."""
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    with open(os.path.join(REPO, "pyproject.toml"), "rb") as f:
        deps = tomllib.load(f)["project"]["dependencies"]
    names = [d.split(";")[0].strip() for d in deps]
    assert any(
        n == "msgpack" or n.startswith(("msgpack>", "msgpack=", "msgpack<", "msgpack~"))
        for n in names
    ), names


@dataclasses.dataclass
class _BlockScan:
    """A plug-in's result object without ``as_dict`` (Groot2 gets its repr)."""

    blocks: int
    crops: list


class _BrokenAsDict:
    def as_dict(self) -> dict:
        raise ValueError("no figures yet")

    def __repr__(self) -> str:
        return "BrokenAsDict(pending)"


class _Unprintable:
    def __repr__(self) -> str:
        raise RuntimeError("no repr")


def _face():
    from perception.face import FaceEstimate

    return FaceEstimate(
        facing_rad=0.5,
        face_offset_m=2.0,
        z_m=0.4,
        first_s=-0.3,
        last_s=0.3,
        blocks_seen=3,
        sightings=9,
        hypotheses=1,
        centre_s=0.0,
        yaw_from_blocks=True,
    )


def test_blackboard_objects_are_sent_readable(ctx):
    """Objects on the blackboard (LocatePallet's ``face``, DetectBlocks' ``block_scan``) are
    not null in Groot2's blackboard view: an object with ``as_dict()`` is sent as that dict,
    another as its repr (as summary.json keeps it), a long repr as the tick log's bounded
    note, and an object whose ``as_dict`` or repr raises still gets a readable line."""
    from bt_engine.node import SUCCESS, NodeStatus, SyncActionNode
    from bt_engine.ports import output_port
    from bt_engine.registry import REGISTRY
    from bt_engine.ticklog import VALUE_LIMIT_BYTES

    face = _face()

    class PutFace(SyncActionNode):
        """Test leaf: writes a face estimate object to its output port."""

        bt_id = "PutFace"
        category = "test"
        ports = (output_port("face", description="the face estimate"),)

        def tick_impl(self) -> NodeStatus:
            self.set_output("face", face)
            return SUCCESS

    registry = REGISTRY.copy()
    registry.register(PutFace)
    scan = _BlockScan(blocks=3, crops=["b1", "b2", "b3"])
    huge = _BlockScan(blocks=1, crops=["x" * 100] * 1000)
    body = """
    <Sequence name="s">
      <PutFace name="locate" face="{face}"/>
      <SubTree ID="Sub" name="scan"/>
    </Sequence>"""
    sub = """  <BehaviorTree ID="Sub"><PutFace name="inner" face="{own_face}"/></BehaviorTree>\n"""
    mission = xml_mission(
        wrap(body, sub),
        registry=registry,
        blackboard={
            "block_scan": scan,
            "huge": huge,
            "broken": _BrokenAsDict(),
            "nested": {"scan": scan, "faces": [face]},
        },
    )
    with Groot2Server(mission, port=0) as server:
        Runner(mission, 50.0, hooks=[server]).step()
        # set after the tick: the runner's own record of the blackboard calls repr too
        mission.blackboard["unprintable"] = _Unprintable()
        names = ";".join(s.fullpath or s.tree_id for s in server.subtrees).encode()
        bb = msgpack_decode(_ask_blackboards(ctx, server, names))
    main = bb["Main"]
    assert main["face"] == face.as_dict()
    assert main["face"]["blocks_seen"] == 3 and main["face"]["yaw_from_blocks"] is True
    assert main["block_scan"] == repr(scan) == "_BlockScan(blocks=3, crops=['b1', 'b2', 'b3'])"
    assert main["nested"] == {"scan": repr(scan), "faces": [face.as_dict()]}
    assert main["broken"] == "BrokenAsDict(pending)"
    assert isinstance(main["unprintable"], str) and "_Unprintable" in main["unprintable"]
    note = main["huge"]
    assert isinstance(note, str) and len(note) < 200 and "not logged" in note
    assert len(repr(huge)) > VALUE_LIMIT_BYTES
    assert bb["scan"] == {"own_face": face.as_dict()}  # a SubTree's own blackboard


def test_loopback_by_default_and_port_in_use(ctx):
    mission = xml_mission(wrap('<AlwaysSuccess name="ok"/>'))
    with Groot2Server(mission, port=0) as first:
        assert first.address == "127.0.0.1"
        from bt_engine.groot2 import Groot2Error

        with pytest.raises(Groot2Error, match="cannot bind"):
            Groot2Server(mission, port=first.port)
        client = Client(ctx, first.port)
        check_reply_header(client.request(b"S")[0], b"S")
        assert first.connected  # a request is Groot2's heartbeat
        client.close()


# -- every shipped mission -------------------------------------------------------------------
MISSIONS = sorted(
    glob.glob(os.path.join(REPO, "missions", "*.xml"))
    + glob.glob(os.path.join(REPO, "missions", "*.yaml"))
)


@pytest.mark.parametrize("path", MISSIONS, ids=os.path.basename)
def test_fulltree_of_every_mission(path, ctx):
    import nodes  # noqa: F401  (registers the drone leaves)
    from bt_engine import Mission, SimClock

    mission = Mission.from_file(path, clock=SimClock())
    with Groot2Server(mission, port=0) as server:
        client = Client(ctx, server.port)
        try:
            xml = client.request(b"T")[1].decode()
            status = client.request(b"S")[1]
        finally:
            client.close()
    trees, models = tree_shape(xml)
    n = len(mission.nodes)
    assert trees[0][1] == "" and trees[0][0] == mission.spec.main_tree_id()
    assert sorted(uids_of(trees)) == list(range(1, n + 1))
    paths = {full for _, full, _ in trees}
    assert len(paths) == len(trees)  # one BehaviorTree per SubTree instance

    def check(node):
        tag, attrs, children = node
        if tag == "SubTree":
            assert attrs["_fullpath"] in paths and not children
        else:
            assert tag in models and attrs.get("name")
        for c in children:
            check(c)

    for _, _, nodes_ in trees:
        assert len(nodes_) == 1
        check(nodes_[0])
    pairs = status_pairs(status)
    assert sorted(uid for uid, _ in pairs) == list(range(1, n + 1))
    assert {code for _, code in pairs} == {0}


# -- the command line ------------------------------------------------------------------------
def test_cli_groot_option(tmp_path, capsys):
    from bt_engine.cli import _parser, main

    parse = _parser().parse_args
    assert parse(["run", "m.xml"]).groot is None
    assert parse(["run", "m.xml", "--groot"]).groot == 1667
    assert parse(["run", "m.xml", "--groot", "2000"]).groot == 2000
    assert parse(["run", "m.xml", "--groot"]).groot_address == "127.0.0.1"
    mission = tmp_path / "m.xml"
    mission.write_text(wrap('<Sleep name="nap" msec="100"/>'))
    rc = main([str(mission), "--groot", "0", "--out", str(tmp_path / "run"), "--no-report"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "Groot2 monitor on 127.0.0.1:" in out and "SUCCESS" in out


# -- every shipped mission against BT.CPP's publisher ----------------------------------------
MAX_MISSION_TICKS = 80  # every dummy action takes two ticks; the longest mission needs ~40


def _drone_models() -> dict:
    """btrun's drone leaves (the actions and conditions BT.CPP does not know), by ID."""
    import nodes  # noqa: F401  (registers the drone leaves)
    from bt_engine.registry import ACTION, CONDITION, REGISTRY

    return {
        m.id: m
        for m in REGISTRY.models()
        if m.kind in (ACTION, CONDITION) and m.category != "built-in"
    }


def _dummy_registry(drone: dict, condition_ok: bool):
    """btrun's registry with every drone leaf replaced by a dummy of the same ID, kind and
    ports: an action is RUNNING on its first tick and SUCCESS on the next, a condition
    returns ``condition_ok``. The same dummies are registered in BT.CPP (see
    :func:`_btcpp_factory`), so both engines tick the same tree the same way."""
    from bt_engine import RUNNING, SUCCESS, ConditionNode, StatefulActionNode
    from bt_engine.registry import ACTION, REGISTRY

    class DummyAction(StatefulActionNode):
        def on_start(self):
            return RUNNING

        def on_running(self):
            return SUCCESS

    class DummyCondition(ConditionNode):
        def check(self) -> bool:
            return condition_ok

    reg = REGISTRY.copy()
    for m in drone.values():
        base = DummyAction if m.kind == ACTION else DummyCondition
        attrs = {
            "bt_id": m.id,
            "ports": tuple(m.ports.values()),
            "category": m.category,
            "__doc__": m.description,
        }
        reg.register(type(f"Dummy{m.id}", (base,), attrs), replace=True)
    return reg


def _btcpp_factory(bt, used: dict, condition_ok: bool):
    """A BT.CPP factory with the drone leaves in ``used`` registered as the same dummies.

    behaviortreepy's ``register_simple_*`` cannot declare ports, so these have none (see
    :class:`_BtcppMission`)."""
    from bt_engine.registry import ACTION

    factory = bt.BehaviorTreeFactory()
    cond = bt.NodeStatus.SUCCESS if condition_ok else bt.NodeStatus.FAILURE
    for tag, kind in sorted(used.items()):
        if kind == ACTION:
            factory.register_simple_stateful_action(
                tag,
                lambda _n: bt.NodeStatus.RUNNING,
                lambda _n: bt.NodeStatus.SUCCESS,
                lambda _n: None,
            )
        else:
            factory.register_simple_condition(tag, lambda _n: cond)
    return factory


class _BtcppMission:
    """A mission file rewritten for BT.CPP (with its includes, same relative layout)."""

    def __init__(self, path: str, out_dir: str, drone: dict) -> None:
        from bt_engine.registry import REGISTRY

        self.registry = REGISTRY
        self.drone = drone
        self.base = os.path.dirname(os.path.abspath(path))
        self.out_dir = out_dir
        self.used: dict[str, str] = {}  # drone leaf ID -> kind
        #: per BehaviorTree ID, its nodes in pre-order: (tag, port attributes taken out)
        self.sources: dict[str, list[tuple[str, dict[str, str]]]] = {}
        #: BehaviorTree IDs renamed for BT.CPP (see :meth:`_tree_renames`), new -> original
        self.renamed: dict[str, str] = {}
        files = self._closure(os.path.abspath(path))
        renames = self._tree_renames(files)
        self.renamed = {new: old for old, new in renames.items()}
        for src, root in files.items():
            self._rewrite(root, renames)
            dst = os.path.join(out_dir, os.path.relpath(src, self.base))
            os.makedirs(os.path.dirname(dst), exist_ok=True)
            ET.ElementTree(root).write(dst, encoding="unicode")
        self.main = os.path.join(out_dir, os.path.basename(path))
        main_root = files[os.path.abspath(path)]
        trees = [t.get("ID") for t in main_root.findall("BehaviorTree")]
        self.main_tree = main_root.get("main_tree_to_execute") or trees[0]

    def _closure(self, path: str, seen: dict | None = None) -> dict[str, ET.Element]:
        seen = {} if seen is None else seen
        root = ET.parse(path).getroot()
        seen[path] = root
        for inc in root.findall("include"):
            child = os.path.normpath(os.path.join(os.path.dirname(path), inc.get("path")))
            assert child.startswith(self.base + os.sep), child  # same layout in out_dir
            if child not in seen:
                self._closure(child, seen)
        return seen

    def _tree_renames(self, files: dict) -> dict[str, str]:
        """BT.CPP refuses a BehaviorTree whose ID is the name of a registered node ("must not
        use the name of a registered Node"); btrun accepts it (enroll_pallet.xml's tree
        EnrollPallet shares its name with the EnrollPallet action). Such trees get another
        ID in BT.CPP's copy, and BT.CPP's replies are mapped back before comparing."""
        ids = {t.get("ID") for root in files.values() for t in root.findall("BehaviorTree")}
        return {i: f"{i}__tree" for i in sorted(ids) if i in self.drone}

    def _rewrite(self, root: ET.Element, renames: dict[str, str]) -> None:
        if root.get("main_tree_to_execute") in renames:
            root.set("main_tree_to_execute", renames[root.get("main_tree_to_execute")])
        for el in root.iter():
            if el.tag in ("BehaviorTree", "SubTree") and el.get("ID") in renames:
                el.set("ID", renames[el.get("ID")])  # (also the SubTree models)
        for tree in root.findall("BehaviorTree"):
            tree_id = self.renamed.get(tree.get("ID"), tree.get("ID"))
            assert tree_id not in self.sources, f"BehaviorTree {tree_id} defined twice"
            self.sources[tree_id] = [self._node(el) for el in list(tree.iter())[1:]]

    def _node(self, el: ET.Element) -> tuple[str, dict[str, str]]:
        tag = el.tag
        if tag in ("Action", "Condition", "Control", "Decorator") and el.get("ID"):
            tag = el.get("ID")  # the explicit v3 form <Action ID="GoTo"/>
        model = self.registry.get(tag)
        assert model is not None, tag
        if tag != model.id:  # an alias btrun accepts, e.g. SequenceStar (not in BT.CPP 4)
            if el.tag == tag:
                el.tag = model.id
            else:
                el.set("ID", model.id)
            tag = model.id
        ports: dict[str, str] = {}
        if tag in self.drone:
            # BT.CPP rejects an attribute its node does not declare, and the dummies declare
            # no port: the ports go (name, ID and the _skipIf-like attributes stay)
            self.used[tag] = self.drone[tag].kind
            for key in list(el.attrib):
                if key not in ("name", "ID") and not key.startswith("_"):
                    ports[key] = el.attrib.pop(key)
        return tag, ports


def _models_with_defaults(xml: str) -> dict[str, tuple[str, dict[str, tuple[str, str | None]]]]:
    """TreeNodesModel by ID: (kind, {port: (direction, default or None)})."""
    out = {}
    for m in ET.fromstring(xml).iter("TreeNodesModel"):
        for el in m:
            ports = {
                p.get("name"): (p.tag.replace("_port", ""), p.get("default"))
                for p in el
                if p.tag.endswith("_port")
            }
            out[el.get("ID")] = (el.tag, ports)
    return out


@pytest.fixture(scope="module")
def drone_models():
    return _drone_models()


@pytest.mark.parametrize("condition_ok", [True, False], ids=["conditions_ok", "conditions_fail"])
@pytest.mark.parametrize("path", MISSIONS, ids=os.path.basename)
def test_every_mission_equals_btcpp_publisher(
    path, condition_ok, ctx, btcpp, drone_models, tmp_path
):
    """Each shipped mission in BT.CPP's Groot2Publisher and in btrun's Groot2Server.

    The drone leaves are unknown to BT.CPP: both engines get dummies of the same ID and kind
    (actions RUNNING then SUCCESS, conditions all SUCCESS or all FAILURE), btrun's with the
    real ports. BT.CPP loads the mission file itself, includes and all (a YAML mission is
    converted to XML first), with the drone leaves' port attributes taken out (behaviortreepy
    cannot declare ports). Compared:

    - FULLTREE: every BehaviorTree instance (ID, ``_fullpath``, order), every node's tag,
      name, ``_uid`` and attributes. Drone leaves: BT.CPP reports no ports for them, so their
      port attributes in btrun's reply are checked against what BT.CPP writes for a declared
      port instead: the XML value, else the port's default (the ``default`` of the node's
      model in the same reply) for an input without a value, nothing for an output without
      one. TreeNodesModel: built-in nodes equal; drone leaves of the same kind, btrun's with
      exactly the registry's ports.
    - STATUS: the buffer before any tick and after every tick until the root finishes
      (the same root status each tick), one UUID for all of btrun's replies.
    """
    from bt_engine import Mission, SimClock
    from bt_engine.loading import convert_file

    src = path
    if path.endswith(".yaml"):
        src = str(tmp_path / "yaml" / (os.path.basename(path)[:-5] + ".xml"))
        os.makedirs(os.path.dirname(src))
        assert convert_file(path, src) == []
    peer = _BtcppMission(src, str(tmp_path / "btcpp"), drone_models)
    factory = _btcpp_factory(btcpp, peer.used, condition_ok)
    # (behaviortreepy's register_behavior_tree_from_file does not take a path: unusable)
    tree = factory.create_tree_from_file(peer.main)
    # A queue loop over an entry that only a drone leaf fills (the dummies write nothing):
    # both engines start with the same two-item queue in it.
    queues = _loop_queue_entries(peer.main)
    for key in queues:
        tree.root_blackboard().set_string(key, "q1;q2")
    mission = Mission.from_file(
        path,
        clock=SimClock(),
        registry=_dummy_registry(drone_models, condition_ok),
        blackboard={key: "q1;q2" for key in queues},
    )
    runner = Runner(mission, 50.0)
    bt_port = free_port_pair()
    publisher = btcpp.Groot2Publisher(tree, bt_port)
    server = Groot2Server(mission, port=0)
    runner.hooks.append(server)
    theirs, ours = Client(ctx, bt_port), Client(ctx, server.port)
    try:
        t_xml, o_xml = theirs.request(b"T")[1].decode(), ours.request(b"T")[1].decode()
        _compare_fulltree(t_xml, o_xml, peer, len(mission.nodes))
        uuid = None
        for tick in range(MAX_MISSION_TICKS + 1):
            if tick:
                root = tree.tick_once().name
                assert runner.step().value == root, f"tick {tick}"
            t_reply, o_reply = theirs.request(b"S"), ours.request(b"S")
            check_reply_header(t_reply[0], b"S")
            o_uuid = check_reply_header(o_reply[0], b"S")
            assert uuid in (None, o_uuid)
            uuid = o_uuid
            assert status_pairs(o_reply[1]) == status_pairs(t_reply[1]), f"after tick {tick}"
            if tick and root != "RUNNING":
                break
        else:
            pytest.fail(f"still RUNNING after {MAX_MISSION_TICKS} ticks")
    finally:
        theirs.close()
        ours.close()
        server.close()
        del publisher


def _loop_queue_entries(main_file: str) -> list[str]:
    """Blackboard entries the main tree's queue loops (LoopString, ...) read their queue from."""
    root = ET.parse(main_file).getroot()
    main = root.get("main_tree_to_execute")
    out = []
    for tree in root.findall("BehaviorTree"):
        if main and tree.get("ID") != main:
            continue
        for el in tree.iter():
            queue = el.get("queue", "")
            if el.tag.startswith("Loop") and queue.startswith("{") and queue.endswith("}"):
                out.append(queue[1:-1])
    return out


def _compare_fulltree(t_xml: str, o_xml: str, peer: _BtcppMission, n_nodes: int) -> None:
    t_trees, t_models = tree_shape(t_xml)
    o_trees, _ = tree_shape(o_xml)
    t_full, o_full = _models_with_defaults(t_xml), _models_with_defaults(o_xml)
    assert sorted(uids_of(o_trees)) == list(range(1, n_nodes + 1))

    def unrename(node):
        tag, attrs, children = node
        if tag == "SubTree" and attrs.get("ID") in peer.renamed:
            attrs = {**attrs, "ID": peer.renamed[attrs["ID"]]}
        return (tag, attrs, [unrename(c) for c in children])

    t_trees = [(peer.renamed.get(i, i), full, [unrename(n) for n in ns]) for i, full, ns in t_trees]
    assert [(i, full) for i, full, _ in o_trees] == [(i, full) for i, full, _ in t_trees]
    assert t_trees[0][0] == peer.renamed.get(peer.main_tree, peer.main_tree)
    for (tree_id, full, o_nodes), (_, _, t_nodes) in zip(o_trees, t_trees, strict=True):
        # a BehaviorTree instance lists the nodes of its definition in document order
        triples = zip(_preorder(o_nodes), _preorder(t_nodes), peer.sources[tree_id], strict=True)
        for (o_tag, o_attrs), (t_tag, t_attrs), (src_tag, src_ports) in triples:
            where = f"{tree_id} {full!r} uid {t_attrs.get('_uid')}"
            assert o_tag == t_tag == src_tag, where
            if o_tag not in peer.drone:
                assert o_attrs == t_attrs, where
                continue
            model = o_full[o_tag][1]
            expected = dict(src_ports)
            for port, (direction, default) in model.items():
                if port not in expected and direction != "output" and default is not None:
                    expected[port] = default
            o_ports = {k: v for k, v in o_attrs.items() if k in model}
            assert o_ports == expected, where
            assert {k: v for k, v in o_attrs.items() if k not in model} == t_attrs, where
    used = {tag for _, _, nodes_ in t_trees for tag, _ in _preorder(nodes_)} - {"SubTree"}
    for tag in used:
        if tag in peer.drone:
            m = peer.drone[tag]
            assert t_full[tag] == (m.kind, {}), tag  # a port-less dummy
            assert o_full[tag][0] == m.kind, tag
            assert set(o_full[tag][1]) == set(m.ports), tag
            assert {p: d for p, (d, _) in o_full[tag][1].items()} == {
                p.name: p.direction for p in m.ports.values()
            }, tag
        else:
            assert tree_shape(o_xml)[1][tag] == t_models[tag], tag


def _preorder(nodes_):
    for tag, attrs, children in nodes_:
        yield tag, attrs
        yield from _preorder(children)
