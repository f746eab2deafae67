"""Types for command-line numbers: argparse refuses a bad value with one line naming the
option, the value and what was expected (``btrun run: error: argument --rate: expected a
number of Hz > 0 and at most 1000, got '0'``), exit code 2, before anything is loaded."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def positive(what: str, most: float | None = None) -> Callable[[str], float]:
    """An argparse ``type``: a finite number > 0 (and <= ``most``); ``what`` says what it
    is in the message (``"a tick rate in Hz"``).
    ``nan``, ``inf``, 0 and negative numbers are refused (a tick rate of ``inf`` ticked for
    ever at no time step; a time limit of ``nan`` was no limit)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and value > 0 and (most is None or value <= most)):
            bound = f" and at most {most:g}" if most is not None else ""
            raise argparse.ArgumentTypeError(f"expected {what} > 0{bound}, got {text!r}")
        return value

    parse.__name__ = what  # argparse names the type in some messages
    return parse


def count(what: str) -> Callable[[str], int]:
    """An argparse ``type``: a whole number >= 1 (``--limit 0`` and ``-1`` showed
    everything, ``--page 0`` the first page)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = 0
        if value < 1:
            raise argparse.ArgumentTypeError(f"expected {what}: a whole number >= 1, got {text!r}")
        return value

    parse.__name__ = what
    return parse


def port_number(most: int = 65535) -> Callable[[str], int]:
    """An argparse ``type``: a TCP port 0..``most``, 0 for any free one (``--groot 99999``
    said it served on 99999 and listened on 34463: the number wrapped). Only decimal digits
    are a port: ``xyz`` and ``1668x`` had become 0 (any free port) without a word, and
    ``int()`` also takes ``1_668``, ``+1668`` and non-ASCII digits."""

    def parse(text: str) -> int:
        digits = text.strip()
        value = int(digits) if digits.isascii() and digits.isdigit() else -1
        if not 0 <= value <= most:
            raise argparse.ArgumentTypeError(
                f"expected a TCP port 1 to {most} (0: any free one), got {text!r}"
            )
        return value

    parse.__name__ = "a TCP port"
    return parse
