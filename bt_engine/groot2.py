"""Groot2 live monitoring: BehaviorTree.CPP's Groot2 protocol over ZeroMQ (``btrun --groot``).

:class:`Groot2Server` is a runner hook: after every tick it updates the status buffer; a
background thread answers Groot2's requests on a ZeroMQ REP socket (``tcp://127.0.0.1:1667``
by default) and binds the publisher socket on the next port, as BehaviorTree.CPP's
``Groot2Publisher`` does (see docs/references.md: BehaviorTree.CPP ``groot2_protocol.h``
and ``groot2_publisher.cpp``; docs/monitoring.md for the user's side).

The wire format, the FULLTREE XML and the BLACKBOARD payload are in
:mod:`bt_engine.groot2_protocol`.

Peers are capped (a flood of idle TCP connections must not take btrun's file descriptors):
each port serves at most ``max_peers`` connections at once (:data:`MAX_PEERS`); a socket
monitor counts them (ZMQ_EVENT_ACCEPTED / ZMQ_EVENT_DISCONNECTED, whose value is the
connection's descriptor) and the server thread shuts an excess connection down as soon as it
is accepted (libzmq then closes it). A connection that has not finished ZeroMQ's handshake
within :data:`HANDSHAKE_MS` is closed by libzmq (ZMQ_HANDSHAKE_IVL), and a peer that stops
answering ZMTP heartbeats within :data:`HEARTBEAT_TIMEOUT_MS`, so idle connections free their
place for Groot2. libzmq has no option to refuse connections past a count, and unbinding the
port would drop the connected peers too.

Breakpoints and hook replacement are not implemented: HOOK_INSERT, HOOK_REMOVE,
BREAKPOINT_UNLOCK, TOGGLE_RECORDING and GET_TRANSITIONS are refused as BehaviorTree.CPP
refuses an unknown request; HOOKS_DUMP answers ``[]`` and REMOVE_ALL_HOOKS /
DISABLE_ALL_HOOKS are acknowledged (there are never hooks to remove).
"""

from __future__ import annotations

import socket
import struct
import threading
import time
import uuid
from typing import Any

import zmq

from bt_engine.groot2_protocol import (
    BLACKBOARD,
    DISABLE_ALL_HOOKS,
    FULLTREE,
    HOOKS_DUMP,
    IDLE_FROM,
    MAX_ITEMS,
    PROTOCOL_ID,
    REMOVE_ALL_HOOKS,
    REQUEST_HEADER_SIZE,
    STATUS,
    STATUS_CODE,
    Groot2Error,
    _to_json,
    describe_tree,
    encode_blackboards,
)
from bt_engine.mission import Mission
from bt_engine.node import IDLE, BTNode, NodeStatus

#: the default request port (the publisher binds the next one), as BehaviorTree.CPP
DEFAULT_PORT = 1667
#: a status's byte in the status buffer, and IDLE's after it (STATUS_CODE, IDLE_FROM)
_CODE = {st: STATUS_CODE[st.value] for st in NodeStatus}
_IDLE_AFTER = {st: IDLE_FROM + STATUS_CODE[st.value] for st in NodeStatus}

#: bounds on what one request may cost
MAX_FRAME_BYTES = 64 * 1024
MAX_PARTS = 4
MAX_BLACKBOARDS = 256
POLL_MS = 100
MAX_PENDING = 100_000  # queued status changes before the tick's thread folds them itself
#: TCP connections served at once on each of the two ports (Groot2 opens one on each)
MAX_PEERS = 8
#: a connection that has not completed ZeroMQ's handshake within this time is closed (ms)
HANDSHAKE_MS = 2000
#: ZMTP heartbeats: a PING every HEARTBEAT_IVL_MS; no answer within the timeout drops the peer
HEARTBEAT_IVL_MS, HEARTBEAT_TIMEOUT_MS = 2000, 10_000
#: connections the kernel queues before the server accepts them (ZMQ_BACKLOG)
BACKLOG = 16
_PEER_EVENTS = zmq.EVENT_ACCEPTED | zmq.EVENT_DISCONNECTED


# -- the server ------------------------------------------------------------------------------
class Groot2Server:
    """Serve a running mission to Groot2; use it as a runner hook (``after_tick``).

    Args:
        mission: the built mission.
        port: the request port (the publisher binds ``port + 1``); 0 picks a free pair.
        address: the interface to bind (default loopback only).
        max_heartbeat_delay_s: how long after its last request a client counts as connected.
        max_peers: TCP connections served at once on each port; more are shut down as soon
            as they are accepted (:attr:`refused` counts them).

    Raises:
        Groot2Error: if the ports cannot be bound.
    """

    def __init__(
        self,
        mission: Mission,
        port: int = DEFAULT_PORT,
        address: str = "127.0.0.1",
        max_heartbeat_delay_s: float = 5.0,
        max_peers: int = MAX_PEERS,
    ) -> None:
        self.mission = mission
        self.address = address
        self.max_heartbeat_delay_s = max_heartbeat_delay_s
        self.max_peers = max_peers
        #: connections shut down because ``max_peers`` were already served on their port
        self.refused = 0
        #: descriptors of the connections served now, per monitored socket
        self._peers: list[set[int]] = []
        self._monitors: list[zmq.Socket] = []
        self.tree_xml, self.subtrees = describe_tree(mission)
        self._scopes = {s.fullpath or s.tree_id: s.scope for s in self.subtrees}
        order = [n for s in self.subtrees for n in s.nodes]
        self._buffer = bytearray(3 * len(order))
        self._offset: dict[BTNode, int] = {}
        for i, node in enumerate(order):
            self._buffer[3 * i : 3 * i + 2] = struct.pack("<H", (node.uid + 1) & 0xFFFF)
            self._offset[node] = 3 * i + 2
        self._lock = threading.Lock()
        self._pending: list[tuple[BTNode, NodeStatus, NodeStatus]] = []
        self.tree_uuid = uuid.uuid4().bytes
        self.requests = 0
        self.errors = 0
        self.last_request: float | None = None
        self._stop = threading.Event()
        self._ctx = zmq.Context()
        self._server, self._publisher, self.port = self._bind(port)
        self.publisher_port = self.port + 1
        self.update()
        self._thread = threading.Thread(target=self._loop, name="groot2-server", daemon=True)
        self._thread.start()

    # -- sockets ---------------------------------------------------------------------------
    def _bind(self, port: int) -> tuple[zmq.Socket, zmq.Socket, int]:
        tries = 50 if port == 0 else 1
        last: Exception | None = None
        for _ in range(tries):
            server = self._ctx.socket(zmq.REP)
            publisher = self._ctx.socket(zmq.PUB)
            monitors: list[zmq.Socket] = []
            for s in (server, publisher):
                s.setsockopt(zmq.LINGER, 0)
                s.setsockopt(zmq.SNDTIMEO, 1000)
                s.setsockopt(zmq.MAXMSGSIZE, MAX_FRAME_BYTES)
                s.setsockopt(zmq.HANDSHAKE_IVL, HANDSHAKE_MS)
                s.setsockopt(zmq.HEARTBEAT_IVL, HEARTBEAT_IVL_MS)
                s.setsockopt(zmq.HEARTBEAT_TIMEOUT, HEARTBEAT_TIMEOUT_MS)
                s.setsockopt(zmq.BACKLOG, BACKLOG)
                monitors.append(s.get_monitor_socket(_PEER_EVENTS))  # before any peer
            try:
                if port == 0:
                    p = server.bind_to_random_port(f"tcp://{self.address}")
                else:
                    server.bind(f"tcp://{self.address}:{port}")
                    p = port
                publisher.bind(f"tcp://{self.address}:{p + 1}")
                self._monitors = monitors
                self._peers = [set() for _ in monitors]
                return server, publisher, p
            except zmq.ZMQError as exc:
                last = exc
                for s, mon in zip((server, publisher), monitors, strict=True):
                    s.disable_monitor()
                    mon.close(0)
                    s.close(0)
        self._ctx.term()
        raise Groot2Error(
            f"cannot bind Groot2 ports {port or 'any'} and the next one on {self.address}: {last}"
        )

    # -- runner hook -----------------------------------------------------------------------
    def after_tick(self, t_s: float) -> None:  # noqa: ARG002
        self.update()

    def shutdown(self, reason: str) -> None:  # noqa: ARG002
        self.update()  # the halted tree (the server stays up until close())

    def update(self) -> None:
        """Queue this tick's status changes for the status buffer.

        The tick's thread only copies references (one C-level ``extend``); the server thread
        folds them into the buffer when a client asks for STATUS, or every POLL_MS.
        """
        changes = getattr(self.mission, "_changes", None)
        if changes is None:  # no change list: read every node
            changes = [(n, n.bt_status, n.bt_status) for n in self.mission.nodes]
        with self._lock:
            self._pending.extend(changes)
            if len(self._pending) > MAX_PENDING:  # nobody folds (no client): stay bounded
                self._fold_locked()

    def _fold_locked(self) -> None:
        buf, offset, code, idle_after = self._buffer, self._offset, _CODE, _IDLE_AFTER
        for n, old, new in self._pending:
            i = offset.get(n)
            if i is None:
                continue
            if new is IDLE:
                if old is not IDLE:
                    buf[i] = idle_after[old]
            else:
                buf[i] = code[new]
        self._pending.clear()

    def status_buffer(self) -> bytes:
        """The STATUS payload now."""
        with self._lock:
            if self._pending:
                self._fold_locked()
            return bytes(self._buffer)

    @property
    def connected(self) -> bool:
        """True if a client sent a request within ``max_heartbeat_delay_s`` (its heartbeat)."""
        last = self.last_request
        return last is not None and time.monotonic() - last < self.max_heartbeat_delay_s

    def blackboards(self, names: str) -> dict[str, Any]:
        """The named blackboards (``Main;sub``) as a JSON object; unknown names are left out,
        an empty blackboard is null (as BehaviorTree.CPP's ``ExportBlackboardToJSON``)."""
        out: dict[str, Any] = {}
        budget = [MAX_ITEMS]
        for name in names.split(";")[:MAX_BLACKBOARDS]:
            scope = self._scopes.get(name)
            if scope is None or name in out:
                continue
            entries = {}
            for key, value in scope.local_items():
                if budget[0] <= 0:
                    break
                entries[key] = _to_json(value, 0, budget)
            out[name] = dict(sorted(entries.items())) or None
        return out

    # -- peers -----------------------------------------------------------------------------
    @property
    def peers(self) -> int:
        """TCP connections served now, on both ports."""
        return sum(len(p) for p in self._peers)

    def _peer_events(self, monitor: zmq.Socket, live: set[int]) -> None:
        """Count the monitor's accepted and closed connections; shut the excess down."""
        for _ in range(10_000):  # bounded: the request socket is served between batches
            try:
                frames = monitor.recv_multipart(zmq.NOBLOCK)
            except zmq.ZMQError:
                return
            if not frames or len(frames[0]) < 6:
                continue
            event, fd = struct.unpack("=HI", frames[0][:6])
            if event == zmq.EVENT_ACCEPTED:
                if len(live) < self.max_peers:
                    live.add(fd)
                else:
                    self.refused += 1
                    _shut_down(fd, (self.port, self.publisher_port))
            elif event == zmq.EVENT_DISCONNECTED:
                live.discard(fd)

    # -- requests --------------------------------------------------------------------------
    def handle(self, parts: list[bytes]) -> list[bytes]:
        """The reply to one request (multipart in, multipart out)."""
        if not parts or len(parts[0]) != REQUEST_HEADER_SIZE:
            return [b"error", b"wrong request header"]
        header = parts[0]
        kind = header[1:2]
        reply = [bytes([PROTOCOL_ID]) + header[1:6] + self.tree_uuid]
        if kind == FULLTREE:
            reply.append(self.tree_xml.encode())
        elif kind == STATUS:
            reply.append(self.status_buffer())
        elif kind in (BLACKBOARD,):
            if len(parts) != 2:
                return [b"error", b"must be 2 parts message"]
            names = parts[1].decode("utf-8", "replace")
            reply.append(encode_blackboards(self.blackboards(names)))
        elif kind == HOOKS_DUMP:
            reply.append(b"[]")
        elif kind in (REMOVE_ALL_HOOKS, DISABLE_ALL_HOOKS):
            pass  # no hooks are ever installed
        else:  # breakpoints, hook replacement, recording: refused as unknown requests
            return [b"error", b"Request not recognized"]
        return reply

    def _loop(self) -> None:
        sock = self._server
        poller = zmq.Poller()
        poller.register(sock, zmq.POLLIN)
        for monitor in self._monitors:
            poller.register(monitor, zmq.POLLIN)
        while not self._stop.is_set():
            try:
                ready = dict(poller.poll(POLL_MS))
                for monitor, live in zip(self._monitors, self._peers, strict=True):
                    if monitor in ready:
                        self._peer_events(monitor, live)
                if sock not in ready:
                    self.status_buffer()  # fold the queued changes (bounds the queue)
                    continue
                parts = sock.recv_multipart(zmq.NOBLOCK)
            except zmq.ZMQError:
                if self._stop.is_set():
                    return
                continue
            self.last_request = time.monotonic()
            self.requests += 1
            try:
                reply = (
                    self.handle(parts)
                    if len(parts) <= MAX_PARTS
                    else [b"error", b"too many message parts"]
                )
            except Exception as exc:  # never let a request end the thread (or the mission)
                reply = [b"error", f"internal error: {type(exc).__name__}".encode()]
            if reply[0] == b"error":
                self.errors += 1
            try:
                sock.send_multipart(reply)
            except zmq.ZMQError:
                pass  # the client went away; REP resets on the next request

    def close(self) -> None:
        """Stop the thread and close the sockets (idempotent)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(2.0)
        for s, monitor in zip((self._server, self._publisher), self._monitors, strict=True):
            try:
                s.disable_monitor()
            except zmq.ZMQError:
                pass
            monitor.close(0)
        self._server.close(0)
        self._publisher.close(0)
        self._ctx.term()

    def __enter__(self) -> Groot2Server:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _shut_down(fd: int, ports: tuple[int, ...]) -> bool:
    """Shut down (not close: libzmq owns it) the TCP connection with descriptor ``fd`` if it
    is still one of ours (its local port is one of ``ports``): the descriptor may have been
    closed and reused since the monitor reported it. True if it was shut down."""
    try:
        conn = socket.socket(fileno=fd)
    except OSError:  # closed meanwhile, or no socket
        return False
    try:
        if conn.family not in (socket.AF_INET, socket.AF_INET6):
            return False
        if conn.type != socket.SOCK_STREAM or conn.getsockname()[1] not in ports:
            return False
        conn.shutdown(socket.SHUT_RDWR)
        return True
    except OSError:
        return False
    finally:
        conn.detach()
