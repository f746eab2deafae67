"""Camera frames to detections, in the step (lock-step) or on a worker thread (real time).

A perception leaf does not detect blocks itself: it asks its :class:`FrameFeed` for the
:class:`Observation` s made since its last tick (a frame, its white-balanced image, the
detected boxes), then sequences or tracks them, which is cheap.

* **Lock-step** (a simulated clock): the feed detects the newest camera frame inside the
  tick, as the tick asks for it, so a run is the same for the same seed.
* **Real time** (a wall clock, a real or SITL drone): one :class:`PerceptionWorker` thread
  per run takes the newest frame, detects blocks in it, and publishes the observation with
  the frame's capture time and the pose at capture. It always takes the newest frame and
  drops what it could not get to (counted), so a slow frame never backs the stream up and
  the tick never waits for a model. torch releases the GIL while it convolves, so the tick
  thread keeps its rate beside it.

The face fit and the block sequencer use the frame's own time and pose (``frame.t_s``,
``frame.pose``), not the tick's.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Observations the worker keeps for its readers (about 4 s at 15 frames/s).
KEEP = 64


@dataclass
class Observation:
    """One camera frame seen by the detector."""

    frame: Any  # the CameraFrame: index, t_s (capture, mission time), pose (at capture), meta
    bgr: np.ndarray  # the white-balanced image the detector took
    dets: list  # the detected boxes (perception.detector.Detection)
    seq: int  # the worker's running number (0 in lock-step)
    detect_ms: float  # white balance + detection


class PerceptionWorker:
    """Real time: detect blocks in the newest camera frame on a thread of its own.

    Args:
        camera_frame: returns the newest camera frame (the Vehicle's ``camera_frame``).
        detect: ``detect(frame) -> (bgr, dets)``; raises for a frame it cannot use.
        on_error: called with the message of a frame that could not be used.
        poll_s: how long to wait before looking for a new frame again.
    """

    def __init__(
        self,
        camera_frame: Callable[[], Any],
        detect: Callable[[Any], tuple[np.ndarray, list]],
        on_error: Callable[[str], None] | None = None,
        poll_s: float = 0.002,
    ) -> None:
        self._camera_frame = camera_frame
        self.detect = detect
        self.on_error = on_error
        self.poll_s = poll_s
        self._out: deque[Observation] = deque(maxlen=KEEP)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.seq = 0
        self.processed = 0
        self.dropped = 0  # frames that arrived while the worker was busy: never looked at
        self.errors = 0
        self.last_error = ""
        self._last_index: int | None = None
        self._thread = threading.Thread(target=self._run, name="perception", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                frame = self._camera_frame()
            except Exception:  # the vehicle is closing: try again, or stop
                frame = None
            if frame is None or frame.index == self._last_index:
                self._stop.wait(self.poll_s)
                continue
            if self._last_index is not None and frame.index > self._last_index + 1:
                self.dropped += frame.index - self._last_index - 1
            self._last_index = frame.index
            t0 = time.perf_counter()
            try:
                bgr, dets = self.detect(frame)
            except Exception as exc:  # a bad frame: the leaves report it, the worker goes on
                self.errors += 1
                self.last_error = str(exc)
                if self.on_error is not None:
                    self.on_error(str(exc))
                continue
            ms = (time.perf_counter() - t0) * 1e3
            with self._lock:
                self.seq += 1
                self.processed += 1
                self._out.append(Observation(frame, bgr, dets, self.seq, ms))

    def since(self, seq: int) -> list[Observation]:
        """The observations published after number ``seq`` (oldest first)."""
        with self._lock:
            return [o for o in self._out if o.seq > seq]

    def close(self) -> None:
        """Stop the thread (bounded wait)."""
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)


@dataclass
class FrameFeed:
    """What one leaf has consumed: the last camera frame index (lock-step), the last
    observation number and the worker's bad frames already reported (real time), and its
    frame gate (lock-step: skip frames whose view barely moved)."""

    last_index: int | None
    seq: int
    gate: Any
    errors: int = 0
