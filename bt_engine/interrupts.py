"""Ctrl-C, SIGTERM and SIGHUP before and between runs: remembered, never lost, never
half-handled.

``btrun`` routes these signals to a recorder first thing (:func:`catch_early_interrupts`);
a run that starts then begins interrupted. :mod:`bt_engine.runner` routes them to the
running :class:`~bt_engine.runner.Runner` while it flies, and gives them back afterwards.
SIGHUP (the terminal closed: an ssh session dropped, a window shut) stops a run as SIGTERM
does: the drone lands and the summary is written; its default would kill btrun mid-flight.
"""

from __future__ import annotations

import signal
from collections.abc import Callable
from typing import Any

#: SIGINT/SIGTERM/SIGHUP received before a run took the signals over
#: (see :func:`catch_early_interrupts`)
PENDING_INTERRUPTS: list[str] = []

#: the signals that stop a run (SIGHUP where the platform has it)
INTERRUPT_SIGNALS: tuple[int, ...] = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)


def signal_source(signum: int) -> str:
    """What a run's reason calls ``signum``: ``Ctrl-C``, ``SIGTERM`` or ``SIGHUP``."""
    if signum == signal.SIGINT:
        return "Ctrl-C"
    if signum == getattr(signal, "SIGHUP", None):
        return "SIGHUP"
    return "SIGTERM"


def catch_early_interrupts(earlier: list[str] | None = None) -> dict | None:
    """From now until a :class:`Runner` starts, remember SIGINT/SIGTERM instead of dying;
    returns the handlers this replaced (for :func:`release_early_interrupts`).

    ``btrun`` calls this first thing: a Ctrl-C while it loads (models, plug-ins, the rig) is
    then never lost or half-handled by a library; the run that follows starts interrupted
    (it ends ABORTED at once, nothing flies, the summary says so). ``earlier``: the signals
    the launcher (``btrun_launcher``) caught before this module was imported, read after the
    handler is swapped so that none falls between. Main thread only.
    """

    def handler(signum, frame):  # noqa: ARG001
        PENDING_INTERRUPTS.append(signal_source(signum))

    PENDING_INTERRUPTS.clear()
    old = _route_signals(handler)
    PENDING_INTERRUPTS[:0] = list(earlier or ())
    return old


def interrupt_pending() -> bool:
    """Whether a SIGINT/SIGTERM/SIGHUP is waiting for the run (:func:`catch_early_interrupts`):
    long work before the first tick (a gallery build) asks, and stops, rather than make a
    Ctrl-C wait until it is done."""
    return bool(PENDING_INTERRUPTS)


def release_early_interrupts(old: dict | None) -> None:
    """Give the signals back to the handlers :func:`catch_early_interrupts` replaced; a
    signal that arrived meanwhile (and no run consumed) is raised now as KeyboardInterrupt."""
    _restore_sigint(old)
    if PENDING_INTERRUPTS:
        PENDING_INTERRUPTS.clear()
        raise KeyboardInterrupt


def _route_signals(handler: Callable[[int, Any], None]) -> dict | None:
    """Install ``handler`` for :data:`INTERRUPT_SIGNALS`; return the old handlers (None,
    and nothing changed, outside the main thread)."""
    old: dict = {}
    try:
        for sig in INTERRUPT_SIGNALS:
            old[sig] = signal.signal(sig, handler)
    except ValueError:  # not in the main thread
        _restore_sigint(old)
        return None
    return old


def _restore_sigint(old: dict | None) -> None:
    for sig, handler in (old or {}).items():
        try:
            signal.signal(sig, handler)
        except (ValueError, TypeError):
            pass


def sigterm_interrupts() -> None:
    """Make SIGTERM and SIGHUP raise KeyboardInterrupt, as Ctrl-C does, where they would
    kill the process outright (their default): a command stopped by ``kill`` or a closed
    terminal then cleans up as one stopped by Ctrl-C (a gallery build's temporary file
    removed, its worker processes ended, an emulator closed). Main thread only; a handler
    already installed is kept."""

    def handler(signum, frame):  # noqa: ARG001
        raise KeyboardInterrupt

    for sig in INTERRUPT_SIGNALS[1:]:
        try:
            if signal.getsignal(sig) == signal.SIG_DFL:
                signal.signal(sig, handler)
        except ValueError:  # not in the main thread
            return
