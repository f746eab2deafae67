"""The UDP server: a software Crazyflie answering CRTP on 127.0.0.1, stepped in real time.

Design: one daemon thread owns the socket and the simulated drone. Each loop iteration it
steps the drone to the wall-clock time since :meth:`CrtpEmulator.start` (physics 500 Hz,
firmware 100 Hz, in :class:`drivers.sim.drone.SimCrazyflie`), captures due mocap frames, sends
the log blocks that are due, then waits in ``select`` (at most 2 ms, less if a block is due
sooner) for datagrams and dispatches each one by CRTP port. Everything the drone sees happens
on that thread, under :attr:`CrtpEmulator.lock` (take it to read a consistent state from
another thread). Replies go to the sender; log data go to the last client that sent a packet.

Robustness: datagrams that are empty or longer than 31 bytes are counted as malformed and
dropped; a handler that fails on a short or odd payload is counted in ``stats.errors`` and
the packet is dropped, like firmware that ignores what it cannot parse.

Faults for tests: :meth:`set_dropping` loses every packet both ways (radio out of range);
:meth:`stop` closes the socket (cflib's UDP driver then sees "connection refused").
"""

from __future__ import annotations

import logging
import select
import socket
import threading
import time

from drivers.sim.emulators.crtp.crtp import COMMANDER, Packet, PortHandler, decode
from drivers.sim.emulators.crtp.high_level import HighLevelPort
from drivers.sim.emulators.crtp.link_port import LinkPort, LinkStats
from drivers.sim.emulators.crtp.localization import LocalizationPort
from drivers.sim.emulators.crtp.log import LogPort
from drivers.sim.emulators.crtp.mem import MemPort
from drivers.sim.emulators.crtp.mocap import EmulatorMocap
from drivers.sim.emulators.crtp.param import ParamPort
from drivers.sim.emulators.crtp.platform_port import PlatformPort
from drivers.sim.emulators.crtp.setpoints import SetpointPort
from drivers.sim.emulators.crtp.state import EmulatedCrazyflie
from drivers.sim.emulators.crtp.supervisor import SupervisorPort

log = logging.getLogger(__name__)
MAX_WAIT_S = 0.002


class CrtpEmulator:
    """A CRTP-over-UDP server in front of an :class:`EmulatedCrazyflie`."""

    def __init__(
        self,
        cf: EmulatedCrazyflie,
        host: str = "127.0.0.1",
        port: int = 0,
        mocap: EmulatorMocap | None = None,
        feed_mocap: bool = False,
    ) -> None:
        self.cf, self.mocap = cf, mocap
        #: the firmware takes the simulated mocap's frames itself, as extpose (``btrun sim
        #: serve crazyflie --mocap``: a drone in a lab whose mocap bridge is not btrun)
        self.feed_mocap = feed_mocap and mocap is not None
        self.stats = LinkStats()
        self.log = LogPort(cf)
        self.param = ParamPort(cf)
        self.high_level = HighLevelPort(cf)
        self.setpoints = SetpointPort(cf, self.high_level)
        self.supervisor = SupervisorPort(cf)
        self.localization = LocalizationPort(cf)
        handlers: list[PortHandler] = [
            LinkPort(self.stats),
            PlatformPort(cf),
            self.log,
            self.param,
            MemPort(),
            self.setpoints,
            self.localization,
            self.supervisor,
            self.high_level,
        ]
        self.handlers: dict[int, PortHandler] = {h.port: h for h in handlers}
        self.handlers[COMMANDER] = self.setpoints
        self.lock = threading.Lock()
        self.dropping = False
        self.client: tuple[str, int] | None = None
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind((host, port))
        self._sock.setblocking(False)
        self.host, self.port = self._sock.getsockname()[:2]
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._t0 = 0.0

    @property
    def uri(self) -> str:
        """The cflib URI of this emulator (``udp://127.0.0.1:<port>``)."""
        return f"udp://{self.host}:{self.port}"

    @property
    def running(self) -> bool:
        """True while the server thread runs."""
        return self._thread is not None and self._thread.is_alive()

    def now_s(self) -> float:
        """Emulator (firmware) time: wall seconds since :meth:`start`."""
        return time.monotonic() - self._t0

    def start(self) -> CrtpEmulator:
        """Start the server thread (the drone's clock starts now)."""
        self._t0 = time.monotonic() - self.cf.t_s
        self._thread = threading.Thread(target=self._run, name="crtp-emulator", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread and close the socket (idempotent)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        try:
            self._sock.close()
        except OSError:
            pass

    def set_dropping(self, dropping: bool = True) -> None:
        """Lose every packet in both directions (True) or restore the link (False)."""
        self.dropping = dropping

    def __enter__(self) -> CrtpEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ thread
    def _send(self, packets: list[Packet], addr: tuple[str, int] | None) -> None:
        if addr is None:
            return
        for pk in packets:
            if self.dropping:
                self.stats.dropped_tx += 1
                continue
            try:
                self._sock.sendto(pk.encode(), addr)
                self.stats.tx += 1
            except OSError:
                self.stats.errors += 1

    def _advance(self) -> None:
        t = self.now_s()
        cf = self.cf
        self.high_level.update(cf.t_s)
        cf.step_to(t)
        if self.mocap is not None:
            self.mocap.tick(cf.t_s, cf.drone.body)
            if self.feed_mocap:
                for f in self.mocap.poll(cf.t_s):
                    self.localization.feed(f.x_m, f.y_m, f.z_m, f.quaternion)
        due = self.log.due(cf.t_s)
        if due:
            self._send(due, self.client)

    def _dispatch(self, datagram: bytes, addr: tuple[str, int]) -> None:
        stats = self.stats
        if self.dropping:
            stats.dropped_rx += 1
            return
        pk = decode(datagram)
        if pk is None:
            stats.malformed += 1
            return
        stats.rx += 1
        if datagram[0] != 0xFF:  # a scan probe is not a client
            self.client = addr
        handler = self.handlers.get(pk.port)
        if handler is None:
            stats.unsupported[pk.port] = stats.unsupported.get(pk.port, 0) + 1
            return
        try:
            replies = handler.handle(pk)
        except Exception as exc:  # malformed payload: drop it, never the server
            stats.errors += 1
            log.debug("port %d ch %d: %r on %s", pk.port, pk.channel, exc, datagram.hex())
            return
        self._send(replies, addr)

    def _run(self) -> None:
        sock = self._sock
        while not self._stop.is_set():
            with self.lock:
                self._advance()
                wait = min(MAX_WAIT_S, self.log.next_due_s() - self.now_s())
            try:
                readable, _, _ = select.select([sock], [], [], max(0.0, wait))
            except (OSError, ValueError):  # socket closed under us
                break
            if not readable:
                continue
            with self.lock:
                self.cf.step_to(self.now_s())
                for _ in range(256):
                    try:
                        datagram, addr = sock.recvfrom(2048)
                    except (BlockingIOError, InterruptedError):
                        break
                    except OSError:  # ICMP errors from a vanished client, closed socket
                        break
                    self._dispatch(datagram, addr)
