"""Errors of the perception package that reach users as clear messages (never tracebacks)."""

from __future__ import annotations


class ModelError(Exception):
    """A model that cannot be used: missing or corrupt weights, wrong architecture, or an input
    (frame, crop) of the wrong size or colour format. The message names the file or the
    offending value and what was expected."""


class GalleryError(Exception):
    """A gallery that cannot be used (missing, damaged, other model, wrong shapes)."""
