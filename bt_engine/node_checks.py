"""What a node's own code handed back or raised, checked the way BehaviorTree.CPP v4 does.

:mod:`bt_engine.node` calls these from its tick; they stay here to keep that module small.

* A node's tick may not return IDLE (BehaviorTree.CPP: "you are not allowed to set manually
  the status to IDLE"), a synchronous action may not return RUNNING ("SyncActionNode MUST
  never return RUNNING") and a condition's ``check()`` returns True or False, not any
  value Python finds true (the text ``"no"``). Each is an error of that tick, said by the
  node (its location and the value).
* An exception raised by a plug-in's code while ticking is told where, in that code
  (``file:line``), it was raised: the run's reason then names it, not only the mission's
  node (the full traceback is in the run's ``error.log``).

And the bound on the list of status changes a tick records (:func:`compact_changes`).
"""

from __future__ import annotations

import inspect
import os
import traceback
from typing import Any

#: the engine's own folder: frames here are not a plug-in's code
_ENGINE = os.path.dirname(os.path.abspath(__file__)) + os.sep
#: set on an exception once it carries where it was raised (the parents re-raise it as is)
_NOTED = "_btrun_raised_at"

IDLE_RETURNED = (
    "returned IDLE: a tick returns SUCCESS, FAILURE, RUNNING or SKIPPED, never IDLE "
    "(BehaviorTree.CPP refuses it too: only a halt or a reset brings a node back to IDLE)"
)
SYNC_RUNNING = (
    "returned RUNNING, but a synchronous action (SyncActionNode) must finish within its "
    "tick (BehaviorTree.CPP: 'SyncActionNode MUST never return RUNNING'); an action that "
    "takes several ticks is a StatefulActionNode (on_start / on_running / on_halted)"
)


def check_result(value: Any) -> bool | None:
    """A condition's ``check()`` result as True or False; None if it is neither (a numpy
    bool counts, and so does the status SUCCESS or FAILURE)."""
    if value is True or value is False:
        return value
    kind = type(value)
    if kind.__name__ == "NodeStatus" and kind.__module__ == "bt_engine.node":
        return {"SUCCESS": True, "FAILURE": False}.get(value.value)
    if kind.__name__ in ("bool_", "bool") and kind.__module__ == "numpy":
        return bool(value)
    return None


def check_said(value: Any) -> str:
    """The message of a ``check()`` that returned ``value``, neither True nor False."""
    return (
        f"check() returned {value!r:.40} ({type(value).__name__}): a condition's check "
        "returns True (SUCCESS) or False (FAILURE)"
    )


def raised_at(exc: BaseException, node_cls: type | None = None) -> str | None:
    """``FILE:LINE`` where a plug-in's code raised ``exc``: the innermost frame in the file
    of ``node_cls`` (or of a class it derives from outside the engine), else the innermost
    frame outside the engine; None if only the engine's code ran."""
    try:
        frames = [
            f
            for f in traceback.extract_tb(exc.__traceback__)
            if not os.path.abspath(f.filename).startswith(_ENGINE)
        ]
    except Exception:  # noqa: BLE001 - never let the report of a fault raise another
        return None
    if not frames:
        return None
    own = set()
    for cls in node_cls.__mro__ if node_cls is not None else ():
        module = getattr(cls, "__module__", "") or ""
        if module.startswith("bt_engine.") or module == "builtins":
            continue
        try:
            own.add(os.path.abspath(inspect.getfile(cls)))
        except (TypeError, OSError):
            continue
    mine = [f for f in frames if os.path.abspath(f.filename) in own]
    frame = (mine or frames)[-1]
    return f"{frame.filename}:{frame.lineno}"


def said(exc: BaseException, node_cls: type | None = None) -> str:
    """``Kind: message (raised at FILE:LINE)``: a plug-in's exception in one line."""
    where = getattr(exc, _NOTED, None) or raised_at(exc, node_cls)
    text = f"{type(exc).__name__}: {exc}".strip()
    return f"{text} (raised at {where})" if where and where not in text else text


def note_raised_at(exc: BaseException, node_cls: type) -> None:
    """Add `` (raised at FILE:LINE)`` (:func:`raised_at`) to the message of ``exc``, raised
    while a node of ``node_cls`` ticked, when the code that raised it is not the engine's.
    Done once per exception (the parents' ticks see it again). The message changes only
    for exceptions that print their text argument (``ValueError("...")``,
    ``KeyError("...")``); any other gets a note (shown with its traceback in ``error.log``)."""
    if getattr(exc, _NOTED, None) is not None:
        return
    where = raised_at(exc, node_cls)
    if where is None:  # the engine's own code: the runner reports it as it is
        return
    try:
        setattr(exc, _NOTED, where)
    except (AttributeError, TypeError):
        return
    args = exc.args
    plain = type(exc).__str__ in (BaseException.__str__, KeyError.__str__)
    if plain and len(args) <= 1 and all(isinstance(a, str) for a in args):
        text = str(exc)
        exc.args = (_Said(f"{text} (raised at {where})" if text else f"(raised at {where})"),)
    else:
        exc.add_note(f"raised at {where}")


class _Said(str):
    """An exception's message that prints as itself (``KeyError`` shows ``repr()`` of its
    argument: quoted once, not twice)."""

    def __repr__(self) -> str:
        return str(self)


#: Status changes recorded between two reads of the tick log before they are compacted
#: (a loop that never leaves one tick must not grow memory without bound).
CHANGE_LIMIT = 50_000
_FINISHED = ("SUCCESS", "FAILURE")


def compact_changes(changes: list) -> None:
    """Shrink a list of ``(node, old, new)`` status changes in place to what the tick log
    and the failure report read: each node's first change (its status before the tick) and
    each node's last SUCCESS/FAILURE, in the order they happened."""
    first: dict[Any, tuple[int, tuple]] = {}
    done: dict[Any, tuple[int, tuple]] = {}
    for i, (n, old, st) in enumerate(changes):
        if n not in first:
            first[n] = (i, (n, old, st))
        if st.value in _FINISHED:
            done[n] = (i, (n, st, st))
    keep = sorted([*first.values(), *done.values()], key=lambda item: item[0])
    changes[:] = [t for _, t in keep]
