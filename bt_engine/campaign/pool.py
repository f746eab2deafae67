"""Where a campaign's runs execute: a local pool of worker processes, or a Dask cluster.

Either way a run executes in a :class:`WorkerProcess`: a fresh Python interpreter (spawned,
never forked: no inherited threads or locks) running :mod:`bt_engine.campaign.worker`,
which stays up from run to run so imports and loaded models are reused. The process is
supervised from outside: a run that outlives its time-out has its process killed (row
``TIMEOUT``), a process that dies mid-run (row ``CRASHED``) is replaced, and the campaign
goes on. The results are the same whoever supervises:

* :class:`LocalPool` (default): one supervising thread per worker process on this machine;
* :class:`DaskPool` (``--scheduler tcp://HOST:8786``): each task of a ``dask.distributed``
  cluster runs :func:`run_on_dask_worker`, which keeps one :class:`WorkerProcess` per Dask
  worker thread. Dask workers are daemonic processes (they may not fork children with
  ``multiprocessing``), hence a plain subprocess. The cluster's machines must see the
  campaign's files and output folder at the same paths (a shared file system) and have
  btrun installed.
"""

from __future__ import annotations

import atexit
import itertools
import json
import os
import queue
import selectors
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterable, Iterator
from typing import Any

from bt_engine.campaign.worker import ONE_THREAD_ENV, keep_folder

#: Seconds a new worker process may take to import everything and say it is ready.
STARTUP_TIMEOUT_S = 300.0
#: Seconds the Dask scheduler has to answer (``btrun campaign --connect-timeout``).
CONNECT_TIMEOUT_S = 5.0


class WorkerError(RuntimeError):
    """A worker process could not be started."""


class SchedulerUnreachable(Exception):
    """The Dask scheduler did not answer (or its address does not read): nothing ran. The
    message says the address tried and how to start a scheduler."""

    def __init__(self, address: str, timeout_s: float, cause: BaseException) -> None:
        self.address, self.timeout_s, self.cause = address, timeout_s, cause
        if isinstance(cause, OSError):  # Dask says "timed out" whatever went wrong
            what = f"no Dask scheduler answered at {address} within {timeout_s:g} s"
        else:
            what = f"{address!r} is not a Dask scheduler address ({cause})"
        super().__init__(
            f"{what}.\n  A scheduler must be running there, reachable from this machine: "
            "start one with `dask scheduler`\n  (it listens on tcp://HOST:8786) and workers "
            "with `dask worker tcp://HOST:8786 --nthreads 1`;\n  --connect-timeout SECONDS "
            "waits longer for a slow network."
        )


class WorkersCannotRun(Exception):
    """Dask workers whose worker processes lack nodes the campaign's missions use (their
    plug-in is not loaded there) or fail to load a plug-in: nothing ran."""

    def __init__(self, bad: list[tuple[str, dict[str, Any]]], total: int) -> None:
        self.bad = bad
        lines = []
        for address, answer in bad[:5]:
            what = answer.get("error") or "unknown node(s) " + ", ".join(answer["missing"])
            lines.append(f"  {address} (host {answer.get('host', '?')}): {what}")
        if len(bad) > 5:
            lines.append(f"  ... and {len(bad) - 5} more")
        here = os.environ.get("BTRUN_PLUGINS", "")
        named = f" (here BTRUN_PLUGINS={here}" if here else " (BTRUN_PLUGINS"
        super().__init__(
            f"{len(bad)} of the {total} Dask workers cannot run this campaign's missions; "
            "nothing ran:\n" + "\n".join(lines) + "\n  Every worker needs the plug-ins "
            f"this command loaded{named}, with PYTHONPATH for one that is not installed) or "
            "their package installed with its btrun.plugins entry point: start `dask "
            "worker` in that environment (docs/campaigns.md, On a Dask cluster)."
        )


class WorkerProcess:
    """One supervised worker process (started on first use, restarted after a kill)."""

    def __init__(self, log_path: str | None = None) -> None:
        self.log_path = log_path
        self.proc: subprocess.Popen | None = None
        self.runs = 0

    def _start(self) -> None:
        env = {**os.environ, **ONE_THREAD_ENV}
        log = open(self.log_path, "ab") if self.log_path else None  # noqa: SIM115
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "bt_engine.campaign.worker"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=log,
                env=env,
                start_new_session=True,  # a terminal's Ctrl-C is the campaign's, not the run's
            )
        finally:
            if log is not None:
                log.close()
        reply = self._read(STARTUP_TIMEOUT_S)
        if not isinstance(reply, dict) or not reply.get("ready"):
            rc = self.kill()
            where = f"; see {self.log_path}" if self.log_path else ""
            raise WorkerError(f"a campaign worker process failed to start ({rc}){where}")

    def _read(self, timeout_s: float) -> dict | str:
        """The next answer line, ``"timeout"`` or ``"died"``."""
        assert self.proc is not None and self.proc.stdout is not None
        with selectors.DefaultSelector() as sel:
            sel.register(self.proc.stdout, selectors.EVENT_READ)
            if not sel.select(timeout=max(timeout_s, 0.0)):
                return "timeout"
        line = self.proc.stdout.readline()
        if not line.endswith(b"\n"):
            return "died"
        try:
            return json.loads(line)
        except ValueError:
            return "died"

    def kill(self) -> str:
        """Kill the process (and anything it started); return how it ended."""
        proc, self.proc = self.proc, None
        if proc is None:
            return "not running"
        if proc.poll() is None:
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except OSError:
                proc.kill()
        rc = proc.wait()
        for stream in (proc.stdin, proc.stdout):
            try:
                stream.close()  # type: ignore[union-attr]
            except OSError:
                pass
        return _exit_text(rc)

    def close(self) -> None:
        """Ask the process to stop after its current run; kill it if it does not."""
        proc = self.proc
        if proc is None:
            return
        try:
            proc.stdin.write(b'{"stop": true}\n')  # type: ignore[union-attr]
            proc.stdin.flush()  # type: ignore[union-attr]
            proc.wait(timeout=5.0)
        except (OSError, subprocess.TimeoutExpired):
            pass
        self.kill()

    def run(self, payload: dict[str, Any]) -> dict[str, Any]:
        """Run one row (``payload`` from :func:`bt_engine.campaign.execution.payload`); a run
        that outlives ``payload["timeout_s"]`` or kills its process gets a TIMEOUT or CRASHED
        result (and the process is replaced at the next run)."""
        if self.proc is None or self.proc.poll() is not None:
            self.kill()
            self._start()
        assert self.proc is not None and self.proc.stdin is not None
        t0 = time.perf_counter()
        try:
            self.proc.stdin.write((json.dumps({"row": payload}) + "\n").encode())
            self.proc.stdin.flush()
            reply = self._read(float(payload["timeout_s"]))
        except OSError:
            reply = "died"
        self.runs += 1
        if isinstance(reply, dict) and "result" in reply:
            return reply["result"]
        if reply == "timeout":
            self.kill()
            status = "TIMEOUT"
            reason = (
                f"no result within the {payload['timeout_s']:g} s time-out; "
                "the worker process was killed"
            )
        else:
            status = "CRASHED"
            reason = f"the worker process died during the run ({self.kill()})"
        run_dir = payload["run_dir"]
        kept = keep_folder(payload.get("keep", "failed"), status)
        if not kept:
            shutil.rmtree(run_dir, ignore_errors=True)
        return {
            "key": payload["key"],
            "status": status,
            "reason": reason,
            "metrics": {name: None for name, _ in payload.get("metrics", ())},
            "wall_s": round(time.perf_counter() - t0, 4),
            "run_dir": run_dir if kept and os.path.isdir(run_dir) else "",
            "pid": None,
        }


def _exit_text(rc: int) -> str:
    if rc < 0:
        try:
            return f"killed by {signal.Signals(-rc).name}"
        except ValueError:
            return f"killed by signal {-rc}"
    return f"exit code {rc}"


class LocalPool:
    """``workers`` worker processes on this machine, each supervised by a thread."""

    def __init__(self, workers: int, log_dir: str | None = None) -> None:
        self.workers = max(1, int(workers))
        self.log_dir = log_dir
        self._stop = threading.Event()
        self._procs: list[WorkerProcess] = []
        self._threads: list[threading.Thread] = []

    def results(self, payloads: Iterable[dict[str, Any]]) -> Iterator[dict[str, Any]]:
        """Run every payload; yield the results as they finish (any order). ``payloads`` may
        be a generator: each worker takes the next payload when it is free, so only the
        payloads in flight exist at once. A worker process starts with its first payload."""
        source = iter(payloads)
        take = threading.Lock()  # one thread at a time advances the payloads' iterator
        exhausted = threading.Event()
        done: queue.Queue = queue.Queue()
        for i in range(self.workers):
            log = os.path.join(self.log_dir, f"worker-{i}.log") if self.log_dir else None
            wp = WorkerProcess(log)
            self._procs.append(wp)
            args = (wp, source, take, exhausted, done)
            t = threading.Thread(target=self._serve, args=args, daemon=True)
            self._threads.append(t)
            t.start()
        while True:
            try:
                item = done.get(timeout=0.2)  # short waits: Ctrl-C is seen at once
            except queue.Empty:
                if not any(t.is_alive() for t in self._threads) and done.empty():
                    if exhausted.is_set():
                        return  # every payload ran, every result was yielded
                    raise WorkerError("every campaign worker stopped") from None
                continue
            if isinstance(item, BaseException):
                raise item
            yield item

    def _serve(
        self,
        wp: WorkerProcess,
        source: Iterator[dict[str, Any]],
        take: threading.Lock,
        exhausted: threading.Event,
        done: queue.Queue,
    ) -> None:
        try:
            while not self._stop.is_set():
                with take:
                    payload = next(source, None)
                if payload is None:
                    exhausted.set()
                    break
                result = wp.run(payload)
                if not self._stop.is_set():
                    done.put(result)
        except Exception as exc:  # a worker that cannot start: the campaign must hear of it
            done.put(exc)
        finally:
            if self._stop.is_set():
                wp.kill()
            else:
                wp.close()

    def stop(self) -> None:
        """Stop now: kill the worker processes (their runs are lost, not recorded)."""
        self._stop.set()
        for wp in self._procs:
            wp.kill()
        for t in self._threads:
            t.join(timeout=10.0)

    def close(self) -> None:
        """Release the worker processes (all runs done: they have stopped already)."""
        self.stop()


class DaskPool:
    """The runs as tasks of a ``dask.distributed`` cluster (its scheduler's address).

    Connecting waits at most ``connect_timeout_s`` (default :data:`CONNECT_TIMEOUT_S`, not
    Dask's 30 s) and raises :class:`SchedulerUnreachable` with a hint."""

    def __init__(self, address: str, connect_timeout_s: float = CONNECT_TIMEOUT_S) -> None:
        from dask.distributed import Client
        from distributed.comm.addressing import get_address_host_port, parse_address

        self.address = address
        try:
            if parse_address(address)[0] != "inproc":  # a bad address, before a Client exists
                get_address_host_port(address)
            self.client = Client(address, timeout=connect_timeout_s, set_as_default=False)
        except (OSError, ValueError, TypeError) as exc:  # TimeoutError is an OSError
            raise SchedulerUnreachable(address, connect_timeout_s, exc) from None
        self._futures: list[Any] = []

    @property
    def dashboard_link(self) -> str | None:
        """The scheduler's dashboard (``client.dashboard_link``), or None if it serves none
        (Dask serves it only where ``bokeh`` is installed)."""
        try:
            return self.client.dashboard_link
        except Exception:  # KeyError: no dashboard service on the scheduler
            return None

    def describe(self) -> str:
        """One line for the user: the scheduler, its worker threads, the dashboard link."""
        threads = sum(self.client.nthreads().values())
        link = self.dashboard_link
        plural = "" if threads == 1 else "s"
        text = f"Dask scheduler {self.client.scheduler.address}, {threads} worker thread{plural}"
        if not threads:
            text += f" (none yet: start some with `dask worker {self.address}`)"
        if link:
            return f"{text}; dashboard: {link}"
        return f"{text}; no dashboard (the scheduler serves one where bokeh is installed)"

    def check_workers(self, node_ids: Iterable[str], timeout_s: float = STARTUP_TIMEOUT_S) -> None:
        """Raise :class:`WorkersCannotRun` unless a worker process of every Dask worker
        connected now loads the plug-ins and knows every node of ``node_ids`` (one short
        task per worker, :func:`check_nodes_on_dask_worker`): workers started without the
        plug-in's environment made every row CRASHED. Workers that join later are not
        checked (their rows say it, CRASHED)."""
        ids = sorted(set(node_ids))
        workers = list(self.client.nthreads())  # every worker connected now
        if not workers:
            return
        session = uuid.uuid4().hex[:8]
        futures = [
            (
                w,
                self.client.submit(
                    check_nodes_on_dask_worker,
                    ids,
                    key=f"btrun-check-{i}-{session}",
                    workers=[w],
                    allow_other_workers=False,
                    pure=False,
                ),
            )
            for i, w in enumerate(workers)
        ]
        bad = []
        for address, future in futures:
            try:
                answer = future.result(timeout=timeout_s)
            except Exception as exc:  # noqa: BLE001 - the worker's failure is the answer
                answer = {"error": f"the check failed: {type(exc).__name__}: {exc}"}
            if answer.get("error") or answer.get("missing"):
                bad.append((address, answer))
        if bad:
            raise WorkersCannotRun(bad, len(workers))

    def results(self, payloads: Iterable[dict[str, Any]]) -> Iterator[dict[str, Any]]:
        """Run every payload; yield the results as they finish (any order). ``payloads`` may
        be a generator: it is advanced only as runs are submitted.

        One run in flight per worker thread of the cluster (counted again after every run,
        so a cluster that grows gets more): a finished run's thread takes the next one.
        Submitting every run at once let the scheduler share them out before it knew how
        long they take, and a worker that drew more runs finished last.
        """
        from dask.distributed import as_completed

        session = uuid.uuid4().hex[:8]  # a task key is unique to this submission
        todo = iter(payloads)

        def submit(p: dict[str, Any]) -> Any:
            return self.client.submit(
                run_on_dask_worker, p, key=f"btrun-run-{p['key'][:16]}-{session}", pure=False
            )

        running = as_completed(loop=self.client.loop)
        for p in itertools.islice(todo, self._threads()):
            running.add(future := submit(p))
            self._futures.append(future)
        for future in running:
            self._futures.remove(future)
            want = max(self._threads() - len(self._futures), 0 if self._futures else 1)
            for p in itertools.islice(todo, want):
                running.add(nxt := submit(p))
                self._futures.append(nxt)
            yield future.result()

    def _threads(self) -> int:
        """Worker threads in the cluster now (at least 1)."""
        return max(1, sum(self.client.nthreads().values()))

    def stop(self) -> None:
        """Cancel the tasks not finished (a run already going ends on its worker)."""
        try:
            if self._futures:
                self.client.cancel(self._futures)
        finally:
            self.client.close()

    def close(self) -> None:
        """Disconnect from the cluster."""
        self.client.close()


_DASK_WORKERS: dict[int, WorkerProcess] = {}
_DASK_LOCK = threading.Lock()


def run_on_dask_worker(payload: dict[str, Any]) -> dict[str, Any]:
    """A Dask task: run the row in this Dask worker thread's own :class:`WorkerProcess`."""
    with _DASK_LOCK:
        wp = _DASK_WORKERS.get(threading.get_ident())
        if wp is None:
            if not _DASK_WORKERS:
                atexit.register(_close_dask_workers)
            wp = _DASK_WORKERS[threading.get_ident()] = WorkerProcess()
    return wp.run(payload)


def check_nodes_on_dask_worker(node_ids: list[str]) -> dict[str, Any]:
    """A Dask task: what a worker process started here (same interpreter, environment and
    folder as :class:`WorkerProcess`) lacks to run ``node_ids``
    (:func:`bt_engine.campaign.worker.check_nodes`), with this host's name."""
    cmd = [sys.executable, "-m", "bt_engine.campaign.worker", "--check-nodes"]
    answer: dict[str, Any]
    try:
        proc = subprocess.run(
            [*cmd, json.dumps(node_ids)],
            capture_output=True,
            env={**os.environ, **ONE_THREAD_ENV},
            timeout=STARTUP_TIMEOUT_S,
        )
        lines = proc.stdout.decode(errors="replace").strip().splitlines()
        answer = json.loads(lines[-1]) if lines else {}
        if not isinstance(answer, dict) or not answer:
            tail = proc.stderr.decode(errors="replace").strip().splitlines()[-1:]
            answer = {"error": f"a worker process failed ({_exit_text(proc.returncode)}) {tail}"}
    except (OSError, ValueError, subprocess.TimeoutExpired) as exc:
        answer = {"error": f"a worker process failed: {type(exc).__name__}: {exc}"}
    answer["host"] = socket.gethostname()
    return answer


def _close_dask_workers() -> None:
    for wp in list(_DASK_WORKERS.values()):
        wp.kill()
    _DASK_WORKERS.clear()
