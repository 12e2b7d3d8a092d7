"""Errors raised for bad input data: each names the file and the problem.

``DatasetError`` is a ``ValueError``; ``DatasetFileNotFoundError`` is both a
``DatasetError`` and a ``FileNotFoundError``, so callers may catch either family.
``SceneError`` is a ``DatasetError`` for scene definitions (scene JSON files).
``OutputError`` is an ``OSError``: a command's output cannot be written.
"""
from __future__ import annotations

__all__ = ["DatasetError", "DatasetFileNotFoundError", "SceneError", "OutputError"]


class DatasetError(ValueError):
    """A data set cannot be used as it is; the message names the file and the problem."""


class DatasetFileNotFoundError(DatasetError, FileNotFoundError):
    """A file that a data set needs is missing; the message names it."""


class SceneError(DatasetError):
    """A scene definition cannot be rendered as it is; the message names the scene file, the
    entry and the values it allows."""


class OutputError(OSError):
    """A command's output cannot be written (no permission, a file where a folder must be, a full
    disk); the message names the path, the reason and, where results were kept, how to publish them."""
