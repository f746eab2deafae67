"""The tick watchdog: a thread outside the tree that ends a tick which never returns.

BehaviorTree.CPP semantics allow a tick that loops forever (``Repeat num_cycles="-1"``
around a child that finishes at once). btrun keeps those semantics but not the danger: the
runner arms this watchdog around every tick. When a tick overruns its wall-clock budget the
watchdog

1. names the node the tree is stuck in (from the main thread's stack) and raises
   :class:`TickOverrun` inside the main thread (an asynchronous exception, delivered at the
   next Python bytecode), so the runner ends the run ABORTED with that located reason and
   its shutdown hooks land the drone as after any other fault;
2. if the main thread still has not come back after a second budget (stuck in native
   code) and the run is in real time, calls ``on_stuck`` itself (the runner passes the
   shutdown hooks: the safety supervisor lands the drone from this thread; the real-time
   platform keeps sending set-points meanwhile);
3. if the main thread has still not come back ``give_up_s`` after step 1 (a leaf that
   swallows :class:`TickOverrun`, ``time.sleep`` or a C call that never ends), calls
   ``on_give_up`` once, from this thread: the owner ends the run without the main thread
   (the runner lands, flushes and lets ``btrun`` write summary.json and exit).

A lock-step simulation cannot drift while the tree is stuck (its clock does not move), so
step 2 does not apply there; steps 1 and 3 do. There only a hang matters, and a tick that
does bounded work the world's size sets is not one (the first frame facing a larger site's
racks textures a hundred pallet faces, 0.1 s each): with ``progress`` the budget counts
from the tick's last progress instead of its start. The work is bounded (each face is made
once, by the tick or by the renderer's look-ahead thread), so a real hang is still caught,
at most that bounded work later.

An operator interrupt (Ctrl-C, SIGTERM) makes the budget short (:meth:`TickWatchdog.hurry`):
a stuck tick is then ended about a second after it, whatever the budget, at rest or not.
"""

from __future__ import annotations

import ctypes
import os
import sys
import threading
import time
from collections.abc import Callable
from typing import Any


class TickOverrun(BaseException):  # noqa: N818 - a BaseException: leaves' "except Exception" must not swallow it
    """Raised in the main thread when one tick ran longer than its budget."""


def _raise_in(thread_id: int, exc_type: type[BaseException]) -> bool:
    done = ctypes.pythonapi.PyThreadState_SetAsyncExc(
        ctypes.c_ulong(thread_id), ctypes.py_object(exc_type)
    )
    if done > 1:  # more than one thread state changed: undo
        ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(thread_id), None)
        return False
    return done == 1


def _innermost(thread_id: int) -> Any:
    frame = sys._current_frames().get(thread_id)
    while frame is not None:
        obj = frame.f_locals.get("self")
        if obj is not None and hasattr(obj, "describe") and hasattr(obj, "loc"):
            return obj
        frame = frame.f_back
    return None


def stuck_leaf(thread_id: int, samples: int = 5, every_s: float = 0.01) -> str:
    """`` in <leaf> (<file:line:col>)`` when ``thread_id``'s innermost tree node is the same
    leaf in each of ``samples`` looks ``every_s`` apart: a leaf that does not return (done
    in one tick, it was never RUNNING: its parent would be blamed). "" for a loop of
    children ticked again and again within the tick (a control or decorator shows up
    between them) or no node."""
    first = _innermost(thread_id)
    if first is None or getattr(first, "children", None):
        return ""
    calls = getattr(first, "tick_count", None)  # a hung leaf is in one call all along
    for _ in range(samples - 1):
        time.sleep(every_s)
        if _innermost(thread_id) is not first or getattr(first, "tick_count", None) != calls:
            return ""
    try:
        return f" in {first.describe()} ({first.loc})"
    except Exception:  # pragma: no cover - a half-built node
        return ""


def stuck_in(thread_id: int) -> str:
    """`` in <node> (<file:line:col>)`` for the deepest tree node on ``thread_id``'s stack."""
    frame = sys._current_frames().get(thread_id)
    found = None
    while frame is not None:
        obj = frame.f_locals.get("self")
        if obj is not None and hasattr(obj, "describe") and hasattr(obj, "loc"):
            if found is None:
                found = obj  # innermost first
        frame = frame.f_back
    if found is None:
        return ""
    try:
        return f" in {found.describe()} ({found.loc})"
    except Exception:  # pragma: no cover - a half-built node
        return ""


def _seconds(s: float) -> str:
    """A wait in seconds for a message: ``10``, ``22.1``, ``0.15``."""
    return f"{s:g}" if s == round(s, 1) else f"{s:.2g}" if s < 1 else f"{s:.1f}"


#: seconds one tick may still take once an operator interrupt arrived (:meth:`TickWatchdog.hurry`)
HURRY_BUDGET_S = 1.0
#: lock-step: a host this many times over-committed stretches the budget at most so much
MAX_BUSY_FACTOR = 10.0


def busy_factor() -> float:
    """How over-committed this host is: the 1-minute load average per CPU, at least 1 and at
    most :data:`MAX_BUSY_FACTOR`. In lock-step the simulated drone waits for the tree, so
    only a hang matters: a tick that takes long because other processes share the cores is
    not one (real time keeps its budget: there a drone is waiting)."""
    try:
        load = os.getloadavg()[0] / max(os.cpu_count() or 1, 1)
    except OSError:  # pragma: no cover - no load average on this platform
        return 1.0
    return min(max(load, 1.0), MAX_BUSY_FACTOR)


class TickWatchdog:
    """Arm with :meth:`start_tick` before each tick and :meth:`end_tick` after it.

    Args:
        budget_s: wall-clock seconds one tick may take.
        real_time: the run is paced by a wall clock (then step 2 applies).
        on_stuck: called (once, from the watchdog thread) with the reason when the main
            thread did not return within a second budget after step 1.
        running: the deepest running node as `` in <node> (<loc>)`` (the reason's "where").
        request_stop: called with the reason when the watchdog fires (loops stop at once).
        at_rest: True while a slow tick harms nothing (then ``rest_budget_s`` applies).
        rest_budget_s: the budget of a tick while ``at_rest()`` holds.
        on_give_up: called (once, from the watchdog thread) with the reason when the main
            thread did not return within ``give_up_s`` after step 1 (step 3).
        give_up_s: seconds from step 1 to step 3 (default: ``budget_s``, so a tick is given
            up two budgets after it began).
        progress: lock-step only: when (``time.monotonic()``) a long tick last did bounded
            work (a texture made), None before any; the budget then counts from then.
    """

    def __init__(
        self,
        budget_s: float,
        real_time: bool = False,
        on_stuck: Callable[[str], Any] | None = None,
        running: Callable[[], str] | None = None,
        request_stop: Callable[[str], Any] | None = None,
        at_rest: Callable[[], bool] | None = None,
        rest_budget_s: float = 600.0,
        on_give_up: Callable[[str], Any] | None = None,
        give_up_s: float | None = None,
        progress: Callable[[], float | None] | None = None,
        subject: str = "",
    ) -> None:
        if not budget_s > 0:
            raise ValueError(f"tick budget must be > 0 s, got {budget_s}")
        if give_up_s is not None and not give_up_s > 0:
            raise ValueError(f"give-up delay must be > 0 s, got {give_up_s}")
        self.budget_s = float(budget_s)
        self.real_time = real_time
        self.on_stuck = on_stuck
        self.running = running
        self.request_stop = request_stop
        self.at_rest = at_rest
        self.rest_budget_s = max(float(rest_budget_s), self.budget_s)
        self.on_give_up = on_give_up
        self.give_up_s = float(give_up_s) if give_up_s is not None else self.budget_s
        self.reason: str | None = None
        #: True once ``on_give_up`` was called (the main thread never came back)
        self.gave_up = False
        self._hurry: tuple[float, float, str] | None = None  # (since, budget, why)
        self._main = threading.main_thread().ident or threading.get_ident()
        self._target = threading.get_ident()
        self._tick = 0
        self._started: float | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._fired_at: float | None = None
        self._raised_at = 0.0
        self._stuck_called = False
        self.progress = None if real_time else progress
        #: what is watched, as the reason names it: "" for "tick N" (the tick under way),
        #: or e.g. "halting" (the runner's end-of-run halt)
        self.subject = subject
        self._thread = threading.Thread(target=self._loop, name="tick-watchdog", daemon=True)
        self._thread.start()

    def start_tick(self, tick: int) -> None:
        """A tick begins (on the thread that ticks the tree)."""
        with self._lock:
            self._target = threading.get_ident()
            self._tick = tick
            self._started = time.monotonic()

    def end_tick(self) -> None:
        """The tick returned in time (or was ended): disarm."""
        with self._lock:
            self._started = None

    def hurry(self, why: str, budget_s: float = HURRY_BUDGET_S) -> None:
        """An operator interrupt (``why``, e.g. ``operator interrupt (Ctrl-C)``) arrived: from
        now on a tick may take only ``budget_s`` more (at rest too), and is given up soon
        after. Safe from a signal handler (it takes no lock)."""
        if self._hurry is None:
            self._hurry = (time.monotonic(), max(float(budget_s), 0.01), why)

    def close(self) -> None:
        """Stop the watchdog thread."""
        self._stop.set()
        if self._thread is not threading.current_thread():  # closed by its own give-up
            self._thread.join(timeout=1.0)

    def _budget(self, started: float, now: float) -> tuple[float, float, str]:
        """(seconds allowed, measured from, why) for the tick that began at ``started``."""
        hurry = self._hurry
        if hurry is not None:
            since, budget, why = hurry
            return budget, max(since, started), why
        if self.progress is not None:  # lock-step: from the tick's last progress
            try:
                started = max(started, self.progress() or started)
            except Exception:  # noqa: BLE001 - read mid-update: from the tick's start
                pass
        budget = self.budget_s
        if now - started > budget and self.at_rest is not None:
            try:
                if self.at_rest():
                    budget = self.rest_budget_s
            except Exception:  # pragma: no cover - read mid-update: keep the tight one
                budget = self.budget_s
        return budget, started, ""

    def _loop(self) -> None:
        period = min(0.05, self.budget_s / 10.0, HURRY_BUDGET_S / 10.0)
        while not self._stop.wait(period):
            with self._lock:
                started, tick, target = self._started, self._tick, self._target
            now = time.monotonic()
            if started is None:
                continue
            if self._fired_at is None:
                budget, since, why = self._budget(started, now)
                busy = 1.0
                if now - since > budget and not self.real_time and self._hurry is None:
                    busy = busy_factor()  # lock-step on a busy host: not a hang yet
                if now - since > budget * busy:
                    self._fire(tick, target, budget, why, now, busy)
                continue
            every = self._hurry[1] if self._hurry is not None else self.budget_s
            if now - self._raised_at > every / 2:
                self._raised_at = now  # still in the same tick: raise again (never lost)
                _raise_in(target, TickOverrun)
            if (
                self.real_time
                and not self._stuck_called
                and now - self._fired_at > self.budget_s
                and self.on_stuck is not None
            ):
                self._stuck_called = True
                self.on_stuck(self.reason or "watchdog")
            give_up_s = self.give_up_s
            if self._hurry is not None:  # the operator is waiting
                give_up_s = min(give_up_s, 2 * self._hurry[1])
            if not self.gave_up and now - self._fired_at > give_up_s:
                self.gave_up = True
                self.reason = (self.reason or "watchdog") + (
                    f"; the {self.subject or 'tick'} still had not returned {give_up_s:g} s "
                    "later: given up"
                )
                if self.on_give_up is not None:
                    self.on_give_up(self.reason)

    def _fire(
        self, tick: int, target: int, budget: float, why: str, now: float, busy: float = 1.0
    ) -> None:
        """Step 1: name where the tree is stuck, ask loops to stop, raise in the main thread."""
        # a leaf on the stack is the one that does not return (a leaf done in one tick is
        # never RUNNING: its parent would be blamed); else the deepest RUNNING node, stable
        # over a loop of children ticked again and again within the tick
        where = stuck_leaf(target)
        if not where and self.running is not None:
            try:
                where = self.running()
            except Exception:  # pragma: no cover - the tree is mid-change
                where = ""
        where = where or stuck_in(target)
        waited = budget
        if busy >= 1.05:  # said only when it changed the budget noticeably (not "x1.0")
            waited = budget * busy  # what was waited for: the stretched budget
            where += f" (the {budget:g} s budget x{busy:.1f}: a busy host)"
        what = self.subject or f"tick {tick}"
        if why:
            self.reason = (
                f"{why}; watchdog: {what} did not return within {_seconds(waited)} s of it"
                f"{where}; the tree was stopped and the drone landed"
            )
        else:
            self.reason = (
                f"watchdog: {what} did not return within {_seconds(waited)} s{where}; "
                "the tree was stopped and the drone landed"
            )
        self._fired_at = now
        self._raised_at = now
        if self.request_stop is not None:
            self.request_stop(self.reason)
        _raise_in(target, TickOverrun)
