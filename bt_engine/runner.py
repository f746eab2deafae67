"""The runner: tick a mission at a fixed rate on its clock, with hooks and a tick log.

On a :class:`~bt_engine.clock.SimClock` each step advances the clock by one period, calls
the ``before_tick`` hooks (the simulator steps its physics up to the new time), ticks the
tree, then calls ``after_tick`` hooks (the safety supervisor). On a wall clock the runner
sleeps until the next period. Ctrl-C or SIGTERM halts the tree and runs the shutdown hooks;
a tick that does not return is ended by the watchdog (at once after Ctrl-C), and given up
(the run ends without the main thread, ``on_give_up``) if it still does not return.
"""

from __future__ import annotations

import threading
import time
import traceback
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from bt_engine.interrupts import (  # noqa: F401  (re-exported: btrun's CLI, fleets)
    PENDING_INTERRUPTS,
    _restore_sigint,
    _route_signals,
    catch_early_interrupts,
    release_early_interrupts,
    signal_source,
)
from bt_engine.mission import Mission
from bt_engine.node import FAILURE, RUNNING, SUCCESS, NodeRuntimeError, NodeStatus
from bt_engine.ticklog import TickLog
from bt_engine.trace import (  # noqa: F401  (re-exported)
    TRACE_LIMIT_BYTES,
    Trace,
    record_cost,
    summarised,
)
from bt_engine.watchdog import TickOverrun, TickWatchdog


class Hooks(Protocol):
    """What a platform (simulator, real drone, supervisor) may plug into the runner."""

    def before_tick(self, t_s: float) -> None: ...

    def after_tick(self, t_s: float) -> None: ...

    def shutdown(self, reason: str) -> None: ...


@dataclass
class RunResult:
    """How a run ended."""

    status: str  # SUCCESS, FAILURE or ABORTED
    reason: str
    ticks: int
    mission_time_s: float
    wall_time_s: float
    tick_periods_s: list[float] = field(default_factory=list, repr=False)
    #: real time: tick slots skipped after a tick (or the host) ran late
    slots_skipped: int = 0
    #: mission seconds per wall second (``--realtime 4``: 4); the periods above are wall time
    clock_factor: float = 1.0


class Abort(Exception):
    """Raised by a hook to end the run as ABORTED (e.g. a safety fault)."""


class Runner:
    """Tick ``mission`` at ``rate_hz`` on its clock.

    Args:
        mission: the built mission.
        rate_hz: ticks per second of mission time (default 50).
        hooks: objects with ``before_tick``/``after_tick``/``shutdown`` (any may be missing).
        log: where to write one JSON line per tick (optional).
        telemetry: a callable returning a small dict of vehicle state for the tick log.
        on_tick: a callable run after every tick (e.g. the live terminal view).
        tick_budget_s: wall-clock seconds one tick may take before the watchdog
            (:mod:`bt_engine.watchdog`) ends the run ABORTED and the hooks land the drone;
            None: no watchdog (``btrun`` always sets one).
        at_rest: True while a slow tick can harm nothing (the drone on the ground): the
            watchdog then allows :data:`REST_TICK_BUDGET_S` (e.g. building a gallery).
        on_give_up: called with the runner, from the watchdog thread, when a tick did not
            return even one more budget (at most :data:`GIVE_UP_S`) after the watchdog
            stopped it: the run has been concluded there (halted, shutdown hooks run, log
            flushed, :attr:`result` set) and the main thread may never come back; ``btrun``
            writes summary.json and ends the process. None: the run is concluded the same
            way and the main thread, if it returns, finds it ended.
        progress: lock-step: when (``time.monotonic()``) a long tick last did bounded work
            (a texture made); the watchdog's budget counts from then (:class:`TickWatchdog`).
    """

    def __init__(
        self,
        mission: Mission,
        rate_hz: float = 50.0,
        hooks: list[Any] | None = None,
        log: TickLog | None = None,
        telemetry: Callable[[], dict] | None = None,
        on_tick: Callable[[Runner], None] | None = None,
        tick_budget_s: float | None = None,
        at_rest: Callable[[], bool] | None = None,
        on_give_up: Callable[[Runner], Any] | None = None,
        progress: Callable[[], float | None] | None = None,
    ) -> None:
        if not rate_hz > 0:
            raise ValueError(f"tick rate must be > 0 Hz, got {rate_hz}")
        self.mission = mission
        self.clock = mission.clock
        self.period_s = 1.0 / rate_hz
        self.hooks = list(hooks or [])
        self.log = log
        if telemetry is None:  # a platform hook that reports vehicle state feeds the trace
            telemetry = next(
                (h.telemetry_row for h in self.hooks if hasattr(h, "telemetry_row")), None
            )
        self.telemetry = telemetry
        self.on_tick = on_tick
        self.tick_budget_s = tick_budget_s
        self.at_rest = at_rest
        self.on_give_up = on_give_up
        self.progress = progress
        self.watchdog: TickWatchdog | None = None
        #: set once the watchdog gave up on the main thread; done once that ending is over
        self._given_up = threading.Event()
        self._halting: tuple[str, str] = ("ABORTED", "the run was stopped")  # while halting
        self._halt_given_up = threading.Event()  # the halt never returned: ended without it
        self._give_up_done = threading.Event()
        self._end_lock = threading.Lock()
        #: the per-tick records (the report, the plug-ins' sections), bounded: :class:`Trace`
        self.trace: Trace = Trace()
        self.keep_trace = True
        self.status: NodeStatus = mission.status
        self.tick_periods_s: list[float] = []
        self.slots_skipped = 0
        self._interrupted = 0
        #: what interrupted the run: "Ctrl-C" (SIGINT) or "SIGTERM"
        self.interrupt_source = "Ctrl-C"
        self.last_record: dict = {}
        self.error_traceback = ""
        #: exceptions raised by shutdown hooks (each hook still ran)
        self.shutdown_errors: list[str] = []
        self._shut: set[int] = set()
        self._shutdown_lock = threading.RLock()
        self._last_wall: float | None = None
        self._t0 = self.clock.now()
        self._steps = 0
        self.outcome: tuple[str, str] | None = None
        self.result: RunResult | None = None
        self._wall0 = time.perf_counter()
        self._start_t = self._t0
        self._max_time_s: float | None = None

    # -- one step -------------------------------------------------------------------------
    def step(self) -> NodeStatus:
        """Advance the clock one period, run hooks, tick the tree once; return its status."""
        clock = self.clock
        self._steps += 1
        # t0 + n * period, not a running sum, so tick times do not drift with float error
        next_t = self._t0 + self._steps * self.period_s
        if not getattr(clock, "is_simulated", False):
            behind = clock.now() - next_t
            if behind > 2 * self.period_s:  # a slow tick: skip the missed slots instead of
                # ticking back to back to catch up (the drone lives in real time, a burst of
                # ticks a few microseconds apart would only repeat the newest state)
                skipped = int(behind / self.period_s)
                self._steps += skipped
                self.slots_skipped += skipped
                next_t = self._t0 + self._steps * self.period_s
        clock.sleep_until(next_t)
        if not getattr(clock, "is_simulated", False):
            now_wall = time.monotonic()
            if self._last_wall is not None:
                self.tick_periods_s.append(now_wall - self._last_wall)
            self._last_wall = now_wall
        t = clock.now()
        for h in self.hooks:
            fn = getattr(h, "before_tick", None)
            if fn is not None:
                fn(t)
        wd = self.watchdog
        if wd is not None:
            wd.start_tick(self.mission.ticks + 1)
            try:
                status = self.mission.tick()
            finally:
                wd.end_tick()
        else:
            status = self.mission.tick()
        try:
            for h in self.hooks:
                fn = getattr(h, "after_tick", None)
                if fn is not None:
                    fn(t)
        finally:  # a hook may end the run (Abort): the tick still goes into the log
            self.status = status
            self._record(t, status)
        if self.on_tick is not None:
            self.on_tick(self)
        return status

    def _record(self, t: float, status: NodeStatus) -> None:
        m = self.mission
        rec = {"tick": m.ticks, "t": round(t, 6), "status": status.value}
        changed = m.drain_changes()
        if changed:
            rec["changed"] = changed
            done = {k: v for k, v in m.finished.items() if changed.get(k) != v}
            if done:
                rec["done"] = done
        writes = m.scope.drain_writes()
        if writes:
            rec["bb"] = writes
        if m.ctx.messages:
            rec["messages"] = list(m.ctx.messages)
            m.ctx.messages.clear()
        if self.telemetry is not None:
            rec["vehicle"] = self.telemetry()
        # what stays in memory holds summaries only: the full values of the last tick would
        # otherwise live on beside the blackboard's new ones (twice the memory of a run)
        slim = summarised(rec)
        self.last_record = slim
        if self.keep_trace:
            self.trace.keep(slim)
        if self.log is not None:
            self.log.write(rec)

    def run_until(self, predicate: Callable[[Mission], bool], max_ticks: int = 100_000) -> int:
        """Step until ``predicate(mission)`` is true; return the ticks taken.

        Raises TimeoutError if it does not hold within ``max_ticks``.
        """
        for i in range(1, max_ticks + 1):
            self.step()
            if predicate(self.mission):
                return i
        raise TimeoutError(f"condition not reached within {max_ticks} ticks")

    # -- whole run ------------------------------------------------------------------------
    def run(self, max_time_s: float | None = None) -> RunResult:
        """Tick until the root finishes, a hook aborts, Ctrl-C, or ``max_time_s`` passes."""
        old = _install_sigint(self)
        try:
            self.begin(max_time_s)
            try:
                while self.outcome is None:
                    try:
                        self.advance()
                    except KeyboardInterrupt:  # a second signal before the tick returned
                        if self.outcome is None:
                            self.outcome = self._interrupt_outcome()
            finally:
                self.conclude()
        finally:
            _restore_sigint(old)
        assert self.result is not None
        return self.result

    def begin(self, max_time_s: float | None = None) -> None:
        """Start a run stepped from outside (:meth:`advance` until :attr:`outcome` is set,
        then :meth:`conclude`): several runners on one clock (a fleet) use these three; the
        caller routes SIGINT/SIGTERM to :meth:`interrupt`."""
        self._wall0 = time.perf_counter()
        self._start_t = self.clock.now()
        self._max_time_s = max_time_s
        #: (status, reason) once the run has ended (SUCCESS, FAILURE or ABORTED), else None
        self.outcome: tuple[str, str] | None = None
        self.result: RunResult | None = None
        if self.tick_budget_s is not None and self.watchdog is None:
            self.watchdog = TickWatchdog(
                self.tick_budget_s,
                real_time=not getattr(self.clock, "is_simulated", False),
                on_stuck=self._shutdown_hooks,
                running=self._running_leaf,
                request_stop=self._request_stop,
                at_rest=self.at_rest,
                rest_budget_s=REST_TICK_BUDGET_S,
                on_give_up=self._give_up,
                give_up_s=min(GIVE_UP_S, self.tick_budget_s),
                progress=self.progress,
            )
        _LIVE.add(self)
        if PENDING_INTERRUPTS:  # a signal arrived while btrun was still loading
            self.interrupt_source = PENDING_INTERRUPTS[-1]
            self._interrupted = 1
            PENDING_INTERRUPTS.clear()

    def advance(self) -> tuple[str, str] | None:
        """One step of a run started with :meth:`begin`; returns (and keeps in
        :attr:`outcome`) how the run ended, or None while it goes on."""
        if self.outcome is not None:
            return self.outcome
        outcome = self._step_outcome()
        if self._given_up.is_set():  # the watchdog ended the run meanwhile: its outcome stands
            self._give_up_done.wait()
            return self.outcome
        self.outcome = outcome
        return self.outcome

    def _interrupt_outcome(self) -> tuple[str, str]:
        twice = f"; {self.interrupt_source} again: emergency stop" if self._interrupted >= 2 else ""
        return "ABORTED", f"operator interrupt ({self.interrupt_source}){twice}"

    def _step_outcome(self) -> tuple[str, str] | None:
        if self._interrupted:
            return self._interrupt_outcome()
        try:
            status = self.step()
        except Abort as exc:
            return "ABORTED", str(exc)
        except TickOverrun:
            wd = self.watchdog
            reason = (wd.reason if wd else None) or "watchdog"
            self.mission.ctx.log(reason)
            return "ABORTED", reason
        except NodeRuntimeError as exc:
            return "ABORTED", str(exc)
        except SystemExit as exc:  # a plug-in's sys.exit() in a tick: the run ends, landed
            self.error_traceback = traceback.format_exc()
            return "ABORTED", f"a node called sys.exit({exc.code!r}){_raising_node(exc)}"
        except KeyboardInterrupt as exc:
            if self._interrupted:  # an operator's second signal: the caller says it
                raise
            # no signal came: a node's own code raised it (it had been told as Ctrl-C)
            self.error_traceback = traceback.format_exc()
            return "ABORTED", (
                f"a node raised KeyboardInterrupt{_raising_node(exc)} (no operator interrupt came)"
            )
        except Exception as exc:  # a bug in a leaf must not leave the drone flying
            self.error_traceback = traceback.format_exc()
            return "ABORTED", f"internal error{_raising_node(exc)}: {type(exc).__name__}: {exc}"
        if self.mission.ctx.halt_errors:
            return "ABORTED", self.mission.ctx.halt_errors[0]
        if status is SUCCESS:
            return "SUCCESS", "the mission tree returned SUCCESS"
        if status is FAILURE:
            return "FAILURE", _failure_reason(self.mission)
        if status is not RUNNING:
            return "FAILURE", f"the root returned {status.value}"
        limit = self._max_time_s
        if limit is not None and self.clock.now() - self._start_t >= limit:
            return "ABORTED", f"mission time limit of {limit:g} s reached"
        return None

    def conclude(self) -> RunResult:
        """End a run: halt the tree unless it succeeded, run every shutdown hook (land the
        drone), flush the log; the :class:`RunResult` is kept in :attr:`result`."""
        with self._end_lock:  # the watchdog's give-up may be ending the run: wait for it
            if self._given_up.is_set() and self.result is not None:
                return self.result
            return self._conclude()

    def _conclude(self) -> RunResult:
        _LIVE.discard(self)
        result, reason = self.outcome or ("ABORTED", "the run was stopped")
        try:
            self._close_watchdog()
            # Nothing that happens while halting may skip the landing: a failing halt is
            # recorded, and every shutdown hook still runs.
            if result != "SUCCESS" or self.mission.root.bt_status is RUNNING:
                self._halting = (result, reason)
                try:
                    self._halt_watched()
                except TickOverrun as exc:  # a halt that did not return: stopped
                    why = str(exc.args[0]) if exc.args else "watchdog"
                    reason += f"; while halting: {why}"
                    result = "ABORTED"
                except (Exception, SystemExit) as exc:  # a plug-in's sys.exit() too
                    self.error_traceback += traceback.format_exc()
                    from bt_engine.node_checks import said

                    # the node and its line, and the plug-in's file:line, as a tick's error
                    node = _raising_node(exc)
                    cls = _raising_class(exc)
                    reason += f"; halting the tree failed{node}: {said(exc, cls)}"
                    result = "ABORTED" if result == "SUCCESS" else result
                if self._halt_given_up.is_set():  # that thread ended the run
                    self._give_up_done.wait()
                    assert self.result is not None
                    return self.result
                errors = self.mission.ctx.halt_errors
                if errors and result != "ABORTED":
                    result, reason = "ABORTED", errors[0]
                elif errors and errors[0] not in reason:
                    reason += f"; while halting: {errors[0]}"
            return self._land_and_close(result, reason)
        finally:
            self._close_watchdog()
            if self.log is not None:
                self.log.flush()

    def _land_and_close(self, result: str, reason: str) -> RunResult:
        """The end of :meth:`_conclude` once the tree is halted: land, keep the result."""
        try:
            # Signals stay routed while the shutdown hooks land the drone: a second
            # SIGINT/SIGTERM raises KeyboardInterrupt there (the supervisor cuts the motors).
            self._shutdown_hooks(reason if result != "SUCCESS" else "mission complete")
            again = f"; {self.interrupt_source} again: emergency stop"
            if self._interrupted >= 2 and again not in reason:  # it came during the landing
                reason += again
        finally:
            if self.log is not None:
                self.log.flush()
        self.outcome = (result, reason)
        self.result = RunResult(
            result,
            reason,
            self.mission.ticks,
            self.clock.now() - self._start_t,
            time.perf_counter() - self._wall0,
            self.tick_periods_s,
            self.slots_skipped,
            float(getattr(self.clock, "_factor", 1.0) or 1.0),
        )
        return self.result

    def _halt_watched(self) -> None:
        """Halt the tree within :data:`HALT_BUDGET_S` of wall time when the run has a tick
        budget. A halt that does not return (a plug-in's ``on_halted`` that spins or waits)
        is stopped as an overrunning tick is (:class:`TickOverrun` in this thread); in real
        time the drone is landed from the watchdog's thread meanwhile; and if the halt still
        has not returned :data:`HALT_BUDGET_S` later, the run ends without this thread
        (:meth:`_give_up_halt`: landed, summary written, as a tick given up)."""
        if self.tick_budget_s is None:
            self.mission.halt()
            return
        hw = TickWatchdog(
            HALT_BUDGET_S,
            real_time=not getattr(self.clock, "is_simulated", False),
            on_stuck=self._shutdown_hooks,
            running=self._running_leaf,
            on_give_up=self._give_up_halt,
            subject="halting",
        )
        hw.start_tick(self.mission.ticks)
        try:
            self.mission.halt()
        except TickOverrun:
            raise TickOverrun(hw.reason or "watchdog") from None
        finally:
            hw.end_tick()
            hw.close()

    def _give_up_halt(self, why: str) -> None:
        """The halt watchdog's step 3, on its thread: the main thread never came back from
        halting the tree. Land, keep the result, end the other runs of this process, hand
        over to :attr:`on_give_up` (``btrun`` writes summary.json and exits)."""
        reason = self._halting[1]
        self._halt_given_up.set()
        self._given_up.set()
        try:
            self._land_and_close("ABORTED", f"{reason}; while halting: {why}")
            for other in list(_LIVE):
                if other is not self and other.result is None:
                    try:
                        other.outcome = ("ABORTED", f"another run of this process: {why}")
                        other.conclude()
                    except Exception:  # noqa: BLE001 - the next one still lands
                        self.error_traceback += traceback.format_exc()
        finally:
            self._give_up_done.set()
        if self.on_give_up is not None:
            self.on_give_up(self)

    def _close_watchdog(self) -> None:
        """Stop the watchdog before halting and landing (a stop it raised late lands here)."""
        wd, self.watchdog = self.watchdog, None
        if wd is None:
            return
        try:
            wd.close()
            self.mission.ctx.stop_reason = None
        except TickOverrun:
            self.mission.ctx.stop_reason = None

    def _request_stop(self, reason: str) -> None:
        self.mission.ctx.stop_reason = reason

    def _give_up(self, reason: str) -> None:
        """The watchdog's step 3, on its thread: the tick never returned after it was stopped.
        Conclude this run (and land every other run of this process: a fleet's main thread
        is just as stuck), then hand over to :attr:`on_give_up`."""
        with self._end_lock:
            if self.result is not None:  # the run ended meanwhile
                return
            self._given_up.set()
            try:
                self._end_given_up(reason)
            finally:
                self._give_up_done.set()

    def _end_given_up(self, reason: str) -> None:
        self.outcome = ("ABORTED", reason)
        self._conclude()
        for other in list(_LIVE):
            if other is not self and other.result is None:
                try:
                    other.outcome = ("ABORTED", f"another run of this process: {reason}")
                    other.conclude()
                except Exception:  # noqa: BLE001 - the next one still lands
                    self.error_traceback += traceback.format_exc()
        if self.on_give_up is not None:
            self.on_give_up(self)

    def _running_leaf(self) -> str:
        """`` in <node> (<loc>)`` for the deepest running node (the watchdog's report)."""
        nodes = list(self.mission.running_nodes())
        return f" in {nodes[-1].describe()} ({nodes[-1].loc})" if nodes else ""

    def _shutdown_hooks(self, why: str) -> None:
        """Every hook's ``shutdown`` once, in order; one that raises does not stop the next."""
        with self._shutdown_lock:
            for h in self.hooks:
                if id(h) in self._shut:
                    continue
                self._shut.add(id(h))
                fn = getattr(h, "shutdown", None)
                if fn is None:
                    continue
                try:
                    fn(why)
                except (Exception, KeyboardInterrupt, TickOverrun) as exc:
                    self.error_traceback += traceback.format_exc()
                    self.shutdown_errors.append(f"{type(exc).__name__}: {exc}")

    def interrupt(self) -> None:
        """Ask the run to stop at the next tick (what Ctrl-C does); a tick that does not
        return is stopped by the watchdog :data:`~bt_engine.watchdog.HURRY_BUDGET_S` later."""
        self._interrupted += 1
        wd = self.watchdog
        if wd is not None:
            wd.hurry(self._interrupt_outcome()[1])


def _failure_reason(mission: Mission) -> str:
    return mission.last_failure or "the mission tree returned FAILURE"


def _raising(exc: BaseException) -> Any:
    """The deepest node whose code raised ``exc`` (None: no node's)."""
    from bt_engine.node import BTNode

    found = None
    tb = exc.__traceback__
    while tb is not None:
        obj = tb.tb_frame.f_locals.get("self")
        if isinstance(obj, BTNode):
            found = obj
        tb = tb.tb_next
    return found


def _raising_node(exc: BaseException) -> str:
    """' in <node> (<file:line:col>)' for the deepest node whose code raised ``exc``."""
    found = _raising(exc)
    return f" in {found.describe()} ({found.loc})" if found is not None else ""


def _raising_class(exc: BaseException) -> type | None:
    """The class of the deepest node whose code raised ``exc`` (None: no node's)."""
    found = _raising(exc)
    return type(found) if found is not None else None


#: Wall-clock budget of one tick while the run is at rest (the drone on the ground).
REST_TICK_BUDGET_S = 600.0

#: Wall-clock seconds halting the tree may take at the end of a run (a halt only stops
#: things: a node's ``on_halted`` that takes longer is stuck), and again from stopping the
#: halt to giving it up.
HALT_BUDGET_S = 3.0

#: Seconds from the watchdog stopping a tick to giving it up (the run ends without the main
#: thread), at most: the give-up comes at most one more budget later, so a tick is never
#: waited for more than twice its budget.
GIVE_UP_S = 5.0

#: the runs of this process between :meth:`Runner.begin` and :meth:`Runner.conclude`
_LIVE: weakref.WeakSet[Runner] = weakref.WeakSet()


def _install_sigint(runner: Runner) -> dict | None:
    """Route SIGINT (Ctrl-C), SIGTERM and SIGHUP to :meth:`Runner.interrupt`; return the old
    handlers.

    The first signal asks the run to stop at the next tick (halt, land, write the summary);
    a second one raises KeyboardInterrupt (emergency stop).
    """

    def handler(signum, frame):  # noqa: ARG001
        runner.interrupt_source = signal_source(signum)
        runner.interrupt()
        if runner._interrupted >= 2:
            raise KeyboardInterrupt

    return _route_signals(handler)
