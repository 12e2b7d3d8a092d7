"""Errors raised for bad input data: each names the file and the problem.

``DatasetError`` is a ``ValueError``; ``DatasetFileNotFoundError`` is both a
``DatasetError`` and a ``FileNotFoundError``, so callers may catch either family.
``SceneError`` is a ``DatasetError`` for scene definitions (scene JSON files).
"""
from __future__ import annotations

__all__ = ["DatasetError", "DatasetFileNotFoundError", "SceneError"]


class DatasetError(ValueError):
    """A data set cannot be used as it is; the message names the file and the problem."""


class DatasetFileNotFoundError(DatasetError, FileNotFoundError):
    """A file that a data set needs is missing; the message names it."""


class SceneError(DatasetError):
    """A scene definition cannot be rendered as it is; the message names the scene file, the
    entry and the values it allows."""
