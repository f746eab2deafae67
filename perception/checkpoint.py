"""Helpers shared by the detector's and the embedder's checkpoint loaders."""

from __future__ import annotations

import hashlib
import os

import torch

from perception.errors import ModelError


def file_sha256(path: str) -> str:
    """Hex SHA-256 of a file (the model version of a checkpoint is derived from it)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def read_checkpoint(path: str, what: str, threads: int | None = None, expected: str = "") -> object:
    """Set torch's intra-op thread count (``threads``; None leaves it) and read the
    checkpoint at ``path`` (tensors only, on the CPU).

    Raises:
        ModelError: naming ``path`` and ``what`` it should hold (e.g. "detector weights")
            when the file is missing or cannot be read.
    """
    if threads is not None:
        torch.set_num_threads(max(1, int(threads)))
    if not os.path.isfile(path):
        raise ModelError(
            f"{path}: no {what} file" + (f" (expected a {expected})" if expected else "")
        )
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ModelError(f"{path}: corrupt or unreadable {what} ({first})") from None


def check_format_version(path: str, got: object, expected: int) -> None:
    """Raise :class:`ModelError` unless the checkpoint's format version is ``expected``."""
    if got != expected:
        raise ModelError(f"{path}: checkpoint format version {got!r}, this btrun reads {expected}")
