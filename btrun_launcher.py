"""``btrun``'s console script: catch Ctrl-C before anything of btrun is imported.

``import bt_engine`` imports the whole engine (and ``btrun`` then the plug-ins, torch ...).
A SIGINT during those imports raised KeyboardInterrupt wherever the interpreter happened to
be, and CPython swallows an exception raised inside a weakref callback (importlib runs one
for its module locks): the Ctrl-C was then lost and the mission flew. This module imports
only :mod:`signal` and :mod:`sys`, installs a handler that records SIGINT/SIGTERM/SIGHUP, and
only then imports :mod:`bt_engine.cli`, which takes the recorded signals over: a ``btrun run``
interrupted while it loads ends ABORTED (``operator interrupt``) before the first tick,
with summary.json, exit code 1; any other command prints ``interrupted`` and exits 1.
"""

from __future__ import annotations

import signal
import sys

#: "Ctrl-C" / "SIGTERM" / "SIGHUP", in order, caught before bt_engine.cli
#: took the signals over (the names of bt_engine.interrupts.signal_source)
PENDING: list[str] = []
_SIGNALS = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))


def _remember(signum: int, frame: object) -> None:  # noqa: ARG001
    if signum == signal.SIGINT:
        PENDING.append("Ctrl-C")
    else:
        PENDING.append("SIGTERM" if signum == signal.SIGTERM else "SIGHUP")


class _Console:
    """``sys.stdout`` / ``sys.stderr`` that stops printing, and only that, once its reader
    is gone (``btrun ... | head -1``: BrokenPipeError; a closed terminal: EIO): the print of
    a leaf's progress had raised inside a tick and ended the flight as an internal error, and
    a flight that ended well lost its summary."""

    def __init__(self, stream: object) -> None:
        self._stream, self._gone = stream, False

    def write(self, text: str) -> int:
        if not self._gone:
            try:
                return self._stream.write(text)  # type: ignore[attr-defined]
            except (OSError, ValueError):
                self._gone = True
        return len(text)

    def flush(self) -> None:
        if not self._gone:
            try:
                self._stream.flush()  # type: ignore[attr-defined]
            except (OSError, ValueError):
                self._gone = True

    def __getattr__(self, name: str) -> object:
        return getattr(self._stream, name)


def main() -> int:
    """The ``btrun`` command: route SIGINT/SIGTERM/SIGHUP to a recorder, then run
    :func:`bt_engine.cli.main` with what it recorded; returns the exit code."""
    sys.stdout = _Console(sys.stdout)  # type: ignore[assignment]
    sys.stderr = _Console(sys.stderr)  # type: ignore[assignment]
    old = {}
    try:
        for sig in _SIGNALS:
            old[sig] = signal.signal(sig, _remember)
    except ValueError:  # pragma: no cover - not the main thread: nothing to route
        pass
    try:
        from bt_engine.cli import main as cli_main
    except KeyboardInterrupt:  # pragma: no cover - raised by an import itself
        print("interrupted", file=sys.stderr)
        return 1
    finally:
        # Python's own handlers back before bt_engine.cli takes the signals over: what it
        # restores afterwards (every command but ``run``: gallery, fleet, campaign, sim
        # serve) must be a Ctrl-C that interrupts, not this recorder
        for sig, handler in old.items():
            try:
                signal.signal(sig, handler)
            except (ValueError, TypeError):  # pragma: no cover
                pass
    try:
        code = cli_main(earlier_interrupts=PENDING)
    except KeyboardInterrupt:  # between the two handlers: nothing has started yet
        print("interrupted", file=sys.stderr)
        return 1
    import os  # (here: the module level imports only what catching Ctrl-C needs)

    main_file = getattr(sys.modules.get("__main__"), "__file__", None) or ""
    if os.path.basename(main_file).startswith("btrun"):  # the command, not a test's call
        _leave_on_signal(code)
        _exit(code)
    return code


def _leave_on_signal(code: int) -> None:
    """The command is done (its summary written): a Ctrl-C, SIGTERM or SIGHUP now only
    hurries the exit, with the command's code. A second Ctrl-C just after a run ended had
    come while Python tore itself down (with its signal handlers back to the default, so
    the signal killed it): exit code 130 for a run that had ended and said so."""

    import os

    def leave(signum: int, frame: object) -> None:  # noqa: ARG001
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(code)

    for sig in _SIGNALS:
        try:
            signal.signal(sig, leave)
        except (ValueError, OSError):  # pragma: no cover - not the main thread
            pass


#: how long ``btrun`` waits, once its command is done, for threads that are not daemons
EXIT_WAIT_S = 5.0


def _exit(code: int) -> None:
    """Exit with ``code``: the threads that are no daemons are waited for at most
    :data:`EXIT_WAIT_S` (a plug-in's that never ends had kept btrun alive after its
    summary, deaf to Ctrl-C, and the exit code a campaign or CI waits for never came; it is
    named and left behind), the exit handlers run (logs, temporary folders, worker
    processes), the streams are flushed, and the process ends without the interpreter's
    teardown, whose default signal handlers a late Ctrl-C would die of."""
    import atexit
    import os
    import threading
    import time

    # Python's own exit runs these before it waits for the threads (concurrent.futures'
    # wakes its idle pool workers so they end): without them an idle worker of btrun's own
    # pools (verify_0) was waited for, then called a stray thread
    for hook in reversed(list(getattr(threading, "_threading_atexits", ()))):
        try:
            hook()
        except Exception:  # noqa: BLE001 - the exit goes on
            pass
    deadline = time.monotonic() + EXIT_WAIT_S
    stray = []
    for t in threading.enumerate():
        if t is threading.main_thread() or t.daemon:
            continue
        t.join(max(0.0, deadline - time.monotonic()))
        if t.is_alive():
            stray.append(t.name)
    if stray:
        print(
            f"btrun: exiting with {len(stray)} thread(s) still running "
            f"({', '.join(stray[:5])}): a thread that never ends (a plug-in's?) is left "
            "behind; make it a daemon or end it in the leaf's halt",
            file=sys.stderr,
        )
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code if isinstance(code, int) else 1)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
