"""``btrun console``: serve the operator console over HTTP (docs/console.md).

::

    btrun console                          # runs/ on http://127.0.0.1:8080, token printed
    btrun console --runs /data/runs --port 9000 --token "$CONSOLE_TOKEN"
    btrun console --host 0.0.0.0           # other machines too: a network you trust
    btrun console --host 0.0.0.0 --allow-host gs1.site.example   # + a DNS alias it answers to
    btrun console --store postgresql://btrun@db.site/btrun   # + the site store's runs

Bad input (a runs folder that does not exist, a port in use, a store that cannot be
reached) is one line, exit code 2.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import ipaddress
import os
import secrets
import socket
import sys
import threading
from typing import Any

from nodes.console.app import ConsoleConfig, make_app
from nodes.console.paths import RunsRoot
from nodes.console.review import DEFAULT_STEM
from nodes.console.site_store import check_store, resolve_url
from store import StoreError


class ConsoleError(Exception):
    """A user error of ``btrun console`` (one line, exit code 2)."""


def setup(p: argparse.ArgumentParser) -> None:
    """The ``btrun console`` options."""
    p.add_argument("--runs", default="runs", help="the runs folder to show (default runs/)")
    p.add_argument("--port", type=int, default=8080, help="HTTP port (default 8080; 0: any free)")
    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to bind (default 127.0.0.1: this machine only; 0.0.0.0: every "
        "interface, only on a network you trust)",
    )
    p.add_argument(
        "--allow-host",
        action="append",
        default=[],
        metavar="NAME",
        help="a host name (or address) the console also answers to, beside localhost, the "
        "--host address and this machine's names and addresses (a DNS alias of the ground "
        "station; repeatable; '*.site.example' for every name under a domain)",
    )
    p.add_argument(
        "--token",
        default=None,
        help="the token review decisions need (default: a random one, printed at start)",
    )
    p.add_argument(
        "--gallery",
        default=None,
        help="gallery file review decisions update (default: the run's gallery file, else "
        "RUNS/site-gallery-<world>-<key>.sqlite, one per world, started from that world's "
        "demo gallery); fly the next inventory with --set gallery=THAT_FILE",
    )
    p.add_argument(
        "--store",
        default=None,
        metavar="URL",
        help="the site store read for the runs recorded elsewhere and a place's history "
        "(default: $BTRUN_STORE, else RUNS/site.sqlite if it exists; none: no store)",
    )


def _bind(host: str, port: int) -> socket.socket:
    """A listening socket, or :class:`ConsoleError` saying why not."""
    if not 0 <= port <= 65535:
        raise ConsoleError(f"--port {port}: a port is 0..65535")
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise ConsoleError(f"--host {host}: {exc.strerror}") from None
    family, _, _, _, addr = infos[0]
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(addr)
        sock.listen(64)
    except OSError as exc:
        sock.close()
        why = "in use" if exc.errno == errno.EADDRINUSE else exc.strerror
        raise ConsoleError(f"--port {port}: cannot listen on {host}:{port}: {why}") from None
    sock.set_inheritable(True)
    return sock


LOOPBACK_NAMES = ["127.0.0.1", "localhost", "[::1]"]


def allowed_hosts(host: str, extra: list[str]) -> list[str]:
    """The ``Host`` names the console answers to: the loopback names, the bound address,
    and for an address other machines reach (``0.0.0.0``, a LAN address) this machine's
    names and addresses, plus ``--allow-host`` names. Never every name: a web page of
    another site reached through DNS rebinding names its own host, and is refused."""
    names = list(LOOPBACK_NAMES)
    for name in extra:
        name = name.strip().lower()
        literal = ipv6_name(name)
        if literal is not None:
            names.append(literal)
            continue
        if (
            not name
            or any(c in name for c in "/: \t[]")
            or ("*" in name and not name.startswith("*."))
        ):
            raise ConsoleError(
                f"--allow-host {name!r}: a host name, an IPv4 address or an IPv6 address (no port)"
            )
        names.append(name)
    if host not in ("127.0.0.1", "localhost", "::1"):
        if host not in ("0.0.0.0", "::", ""):
            names.append(ipv6_name(host) or host.lower())
        names += machine_names(ipv6=":" in host)
    return list(dict.fromkeys(names))


def ipv6_name(text: str) -> str | None:
    """``text`` as a ``Host`` header names an IPv6 address (``[fe80::1]``: bracketed,
    lower case, compressed), or None when it is no IPv6 address (with or without brackets)."""
    bare = text[1:-1] if text.startswith("[") and text.endswith("]") else text
    try:
        return f"[{ipaddress.IPv6Address(bare).compressed}]"
    except ValueError:
        return None


def machine_names(ipv6: bool = False) -> list[str]:
    """This machine's host name, its fully qualified name and its IPv4 addresses (those its
    names resolve to and the one it reaches other hosts from), and with ``ipv6`` (a bind to
    an IPv6 address) the IPv6 addresses its names resolve to, bracketed as a ``Host``
    header has them: how an operator's browser on the network may name the console."""
    out: list[str] = []
    for name in {socket.gethostname(), socket.getfqdn()}:
        if name:
            out.append(name.lower())
            with contextlib.suppress(OSError):
                out += [i[4][0] for i in socket.getaddrinfo(name, None, socket.AF_INET)]
            if ipv6:
                with contextlib.suppress(OSError):
                    found = socket.getaddrinfo(name, None, socket.AF_INET6)
                    out += [ipv6_name(str(i[4][0]).partition("%")[0]) or "" for i in found]
    with contextlib.suppress(OSError), socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.connect(("192.0.2.1", 9))  # a documentation address: no packet is sent
        out.append(s.getsockname()[0])
    return [n for n in dict.fromkeys(out) if n and n != "0.0.0.0"]


def make_config(args: Any) -> ConsoleConfig:
    """The console's settings from the options; :class:`ConsoleError` for a bad one."""
    runs = args.runs
    if not os.path.isdir(runs):
        raise ConsoleError(f"--runs {runs}: no such folder (fly a run first, or give --runs DIR)")
    token = args.token if args.token is not None else secrets.token_urlsafe(18)
    if len(token) < 8 or not token.isprintable() or " " in token:
        raise ConsoleError("--token: at least 8 printable characters without spaces")
    if args.gallery is not None and os.path.isdir(args.gallery):
        raise ConsoleError(f"--gallery {args.gallery}: a folder, expected a gallery file")
    hosts = allowed_hosts(args.host, getattr(args, "allow_host", None) or [])
    store = resolve_url(args.store, runs)
    if store is not None:
        try:
            check_store(store)
        except StoreError as exc:
            raise ConsoleError(f"--store: {exc}") from None
    return ConsoleConfig(runs, token, args.gallery, store, hosts)


class ConsoleServer:
    """The console served by uvicorn on a bound socket, in this thread or another."""

    def __init__(self, config: ConsoleConfig, host: str = "127.0.0.1", port: int = 0) -> None:
        import uvicorn

        self.sock = _bind(host, port)
        self.host, self.port = host, self.sock.getsockname()[1]
        self.config = config
        self.app = make_app(config)
        self.server = uvicorn.Server(
            uvicorn.Config(
                self.app,
                log_level="warning",
                timeout_graceful_shutdown=2,
                limit_concurrency=64,
                h11_max_incomplete_event_size=16_384,
            )
        )
        self.thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        """The console's address."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}"

    def serve(self) -> None:
        """Serve until stopped (Ctrl-C)."""
        self.server.run(sockets=[self.sock])

    def start(self) -> ConsoleServer:
        """Serve on a thread of its own (tests); returns once it answers."""
        self.thread = threading.Thread(target=self.serve, name="console", daemon=True)
        self.thread.start()
        while not self.server.started and self.thread.is_alive():
            self.thread.join(0.02)
        return self

    def stop(self) -> None:
        """Stop serving (and wait for the thread)."""
        self.server.should_exit = True
        if self.thread is not None:
            self.thread.join(10)
        self.sock.close()


def run(args: argparse.Namespace) -> int:
    """Run ``btrun console``; return the exit code."""
    try:
        config = make_config(args)
        server = ConsoleServer(config, args.host, args.port)
    except ConsoleError as exc:
        print(f"btrun console: {exc}", file=sys.stderr)
        return 2
    root = RunsRoot(config.runs)
    gallery = config.gallery or os.path.join(
        root.root,
        f"{DEFAULT_STEM}-<world>-<key>.sqlite (one per world; each run's review page names it)",
    )
    print(f"btrun console: {server.url}/?token={config.token}", flush=True)
    print(f"  runs: {root.root}", flush=True)
    print(f"  review decisions update: {gallery}", flush=True)
    if server.app.state.site is not None:
        print(f"  site store: {server.app.state.site.shown}", flush=True)
    if args.token is None:
        print(f"  token for review decisions: {config.token}", flush=True)
    try:
        server.serve()
    except KeyboardInterrupt:
        pass
    return 0
