"""A throw-away PostgreSQL server for the tests: initdb into a temporary folder, pg_ctl
start on a free port, listening only on a unix socket in that folder, stopped at the end.

Uses the PostgreSQL binaries of the machine (Debian's ``postgresql`` package:
``/usr/lib/postgresql/<version>/bin``; ``.ci/run`` installs it). initdb refuses to run as
root, so as root the server runs as the ``postgres`` user the package creates.
"""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
from dataclasses import dataclass


def pg_bin() -> str | None:
    """The newest ``/usr/lib/postgresql/*/bin`` holding initdb and pg_ctl (or
    ``$BTRUN_PG_BIN``), None if none."""
    env = os.environ.get("BTRUN_PG_BIN")
    candidates = [env] if env else []

    def version(path: str) -> float:
        try:
            return float(path.rstrip("/").split("/")[-2])
        except ValueError:
            return 0.0

    candidates += sorted(glob.glob("/usr/lib/postgresql/*/bin"), key=version, reverse=True)
    for c in candidates:
        if os.access(os.path.join(c, "initdb"), os.X_OK) and os.access(
            os.path.join(c, "pg_ctl"), os.X_OK
        ):
            return c
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class PgServer:
    """A running server: ``url`` reaches its ``postgres`` database."""

    folder: str
    bin: str
    port: int
    user: str | None  # the OS user running it (None: this one)

    @property
    def url(self) -> str:
        return f"postgresql://postgres@/postgres?host={self.folder}&port={self.port}"

    def database(self, name: str) -> str:
        """A new empty database ``name`` on this server; its URL."""
        import psycopg

        with psycopg.connect(self.url, autocommit=True) as c:
            c.execute(f'DROP DATABASE IF EXISTS "{name}"')
            c.execute(f'CREATE DATABASE "{name}"')
        return f"postgresql://postgres@/{name}?host={self.folder}&port={self.port}"

    def stop(self) -> None:
        """Stop the server (immediately) and remove its folder."""
        _run(self, [os.path.join(self.bin, "pg_ctl"), "-D", self.data, "-m", "immediate", "stop"])
        shutil.rmtree(self.folder, ignore_errors=True)

    @property
    def data(self) -> str:
        return os.path.join(self.folder, "data")


def _run(server: PgServer, cmd: list[str]) -> subprocess.CompletedProcess:
    if server.user is not None:
        cmd = ["runuser", "-u", server.user, "--", *cmd]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)


def start_server() -> PgServer:
    """initdb + pg_ctl start; raises RuntimeError with the server's words if it fails."""
    bindir = pg_bin()
    if bindir is None:
        raise RuntimeError("no PostgreSQL binaries (/usr/lib/postgresql/*/bin/initdb)")
    folder = tempfile.mkdtemp(prefix="btrun-pg-")
    user = None
    if os.geteuid() == 0:
        user = "postgres"
        pw = pwd.getpwnam(user)
        os.chown(folder, pw.pw_uid, pw.pw_gid)
    os.chmod(folder, 0o700)
    server = PgServer(folder, bindir, _free_port(), user)
    init = _run(
        server,
        [
            os.path.join(bindir, "initdb"),
            "-D",
            server.data,
            "-A",
            "trust",
            "-U",
            "postgres",
            "-E",
            "UTF8",
            "--no-sync",
        ],
    )
    if init.returncode:
        shutil.rmtree(folder, ignore_errors=True)
        raise RuntimeError(f"initdb failed: {init.stderr.strip()[-500:]}")
    opts = f"-k {folder} -p {server.port} -c listen_addresses='' -c fsync=off"
    start = _run(
        server,
        [
            os.path.join(bindir, "pg_ctl"),
            "-D",
            server.data,
            "-o",
            opts,
            "-l",
            os.path.join(folder, "server.log"),
            "-w",
            "-t",
            "60",
            "start",
        ],
    )
    if start.returncode:
        try:
            with open(os.path.join(folder, "server.log")) as f:
                log = f.read()[-800:]
        except OSError:
            log = ""
        shutil.rmtree(folder, ignore_errors=True)
        raise RuntimeError(f"pg_ctl start failed: {start.stderr.strip()[-300:]} {log}")
    return server
