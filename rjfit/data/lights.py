"""Lights of a data set and the per-pixel geometry terms they induce."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Light", "geometry_terms", "cos_light_half", "tangent_frame", "turned_normals", "tangent_terms",
           "light_tangent_terms"]


@dataclass(frozen=True)
class Light:
    """One light of a stack.

    ``kind`` is ``"point"`` (``position`` in scene units, ``intensity`` as Mitsuba's point
    emitter takes it: radiance ``I / r^2`` at the surface) or ``"directional"``
    (``direction`` points *towards* the light, ``intensity`` is the irradiance).

    Parameters
    ----------
    kind : {"point", "directional"}
        The emitter type.
    intensity : float
        Point light: Mitsuba's point-emitter intensity ``I``; directional light: the
        irradiance. Positive and finite.
    position : tuple of 3 floats, optional
        Position in scene units; required for a point light (ignored otherwise).
    direction : tuple of 3 floats, optional
        Direction *towards* the light, any non-zero finite length; required for a
        directional light (ignored otherwise).

    Raises
    ------
    ValueError
        If ``kind`` is neither ``"point"`` nor ``"directional"``, a point light has no
        ``position``, a directional light has no ``direction`` or one of zero or non-finite
        length, or ``intensity`` is not positive and finite. The length and values of
        ``position`` are not checked here (the data set checks do that).
    """

    kind: str
    intensity: float
    position: tuple[float, float, float] | None = None
    direction: tuple[float, float, float] | None = None

    def __post_init__(self):
        if self.kind not in ("point", "directional"):
            raise ValueError(f"light kind must be 'point' or 'directional', got {self.kind!r}")
        if self.kind == "point" and self.position is None:
            raise ValueError("a point light needs a position")
        if self.kind == "directional":
            if self.direction is None:
                raise ValueError("a directional light needs a direction (towards the light)")
            norm = float(np.linalg.norm(self.direction))
            if not np.isfinite(norm) or norm == 0.0:
                raise ValueError(f"directional light direction {self.direction} has no length")
        if not np.isfinite(self.intensity) or self.intensity <= 0:
            raise ValueError(f"light intensity must be positive and finite, got {self.intensity}")

    def to_json(self) -> dict:
        """The light as a ``dataset.json`` / scene entry (inverse of :meth:`from_json`).

        Returns
        -------
        dict
            ``{"kind", "intensity"}`` plus ``"position"`` and/or ``"direction"`` (lists of
            floats) where set.
        """
        out = {"kind": self.kind, "intensity": float(self.intensity)}
        if self.position is not None:
            out["position"] = [float(c) for c in self.position]
        if self.direction is not None:
            out["direction"] = [float(c) for c in self.direction]
        return out

    @classmethod
    def from_json(cls, entry: dict) -> "Light":
        """The light of a ``dataset.json`` / scene entry (inverse of :meth:`to_json`).

        Parameters
        ----------
        entry : dict
            ``{"kind", "intensity", "position" or "direction"}``; a missing or null
            ``position`` / ``direction`` is None.

        Returns
        -------
        Light

        Raises
        ------
        KeyError
            If ``entry`` has no ``"kind"`` or no ``"intensity"``.
        TypeError
            If ``intensity`` is not a number or string (e.g. null), or ``position`` /
            ``direction`` is not iterable (e.g. a number).
        ValueError
            If ``intensity`` is a string that is not a number, or from :class:`Light`'s own
            checks (kind, missing position or direction, zero direction, intensity <= 0).

        Notes
        -----
        This converts only; it does not check that ``position`` / ``direction`` have three
        finite components. Callers that read user files check the entry first (see
        :mod:`rjfit.data.descriptions`).
        """
        return cls(
            kind=entry["kind"],
            intensity=float(entry["intensity"]),
            position=tuple(entry["position"]) if entry.get("position") is not None else None,
            direction=tuple(entry["direction"]) if entry.get("direction") is not None else None,
        )


def _normalise(vectors):
    norm = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return vectors / np.where(norm > 0, norm, 1.0)


def geometry_terms(positions, normals, view_dirs, light, reference_intensity=1.0):
    """Per-pixel ``<l.n>``, ``<h.n>`` and relative irradiance for one light.

    Parameters
    ----------
    positions, normals, view_dirs : ndarray, shape (..., 3)
        Surface points, unit shading normals and unit directions towards the camera.
    light : Light
    reference_intensity : float
        The intensity that the fitted ``I0`` is relative to: the irradiance factor is
        ``light.intensity / reference_intensity / r^2``.

    Returns
    -------
    cos_ln, cos_hn, irradiance : ndarray, shape (...)
    """
    positions = np.asarray(positions, dtype=float)
    normals = np.asarray(normals, dtype=float)
    view_dirs = np.asarray(view_dirs, dtype=float)
    relative = light.intensity / reference_intensity
    if light.kind == "point":
        to_light = np.asarray(light.position, dtype=float) - positions
        dist2 = np.sum(to_light * to_light, axis=-1)
        light_dirs = to_light / np.sqrt(np.where(dist2 > 0, dist2, 1.0))[..., None]
        irradiance = relative / np.where(dist2 > 0, dist2, np.inf)
    else:
        light_dirs = np.broadcast_to(_normalise(np.asarray(light.direction, dtype=float)), positions.shape)
        irradiance = np.full(positions.shape[:-1], relative)
    half = _normalise(light_dirs + view_dirs)
    cos_ln = np.sum(light_dirs * normals, axis=-1)
    cos_hn = np.sum(half * normals, axis=-1)
    return cos_ln, cos_hn, irradiance


def cos_light_half(positions, view_dirs, light):
    """Per-pixel ``<l.h>``: the cosine of half the angle between the light and the view direction.

    It does not depend on the normal; with ``<l.n>`` and ``<h.n>`` it fixes how the prediction
    changes when the normal turns (:mod:`rjfit.data.normal_error`).

    Parameters
    ----------
    positions, view_dirs : ndarray, shape (..., 3)
    light : Light

    Returns
    -------
    ndarray, shape (...)
    """
    light_dirs = _light_dirs(positions, light)
    return np.sum(light_dirs * _normalise(light_dirs + np.asarray(view_dirs, dtype=float)), axis=-1)


def _light_dirs(positions, light):
    """Unit directions from ``positions`` (..., 3) towards ``light``."""
    positions = np.asarray(positions, dtype=float)
    if light.kind == "point":
        return _normalise(np.asarray(light.position, dtype=float) - positions)
    return np.broadcast_to(_normalise(np.asarray(light.direction, dtype=float)), positions.shape)


def tangent_frame(normals):
    """A per-pixel orthonormal tangent frame ``(t1, t2)`` of unit ``normals`` (..., 3), deterministic.

    ``t1`` is the unit vector along ``a x n``, ``a`` the coordinate axis x or y, whichever is
    less aligned with n (so the cross product never vanishes); ``t2 = n x t1``.
    """
    normals = np.asarray(normals, dtype=float)
    use_y = np.abs(normals[..., 0]) > np.abs(normals[..., 1])
    axis = np.zeros_like(normals)
    axis[..., 0] = ~use_y
    axis[..., 1] = use_y
    t1 = _normalise(np.cross(axis, normals))
    return t1, np.cross(normals, t1)


def turned_normals(normals, d):
    """The unit normals ``(n + dx t1 + dy t2) / sqrt(1 + dx^2 + dy^2)`` (..., 3) at tangent coordinates ``d``
    (..., 2) in the :func:`tangent_frame` ``(t1, t2)`` of the unit ``normals`` (``--normals sample``'s
    parametrisation, :mod:`rjfit.sampler.normals`)."""
    normals, d = np.asarray(normals, dtype=float), np.asarray(d, dtype=float)
    t1, t2 = tangent_frame(normals)
    return _normalise(normals + d[..., :1] * t1 + d[..., 1:] * t2)


def tangent_terms(light_dirs, view_dirs, t1, t2):
    """``(l.t1, l.t2, h.t1, h.t2)`` (..., 4) float32: the light's and the half vector's components in the
    tangent frame of the given normal (what a turned normal's ``<l.n'>`` and ``<h.n'>`` need,
    :mod:`rjfit.sampler.normals`)."""
    light_dirs = np.asarray(light_dirs, dtype=float)
    half = _normalise(light_dirs + np.asarray(view_dirs, dtype=float))
    return np.stack([np.sum(light_dirs * t1, axis=-1), np.sum(light_dirs * t2, axis=-1),
                     np.sum(half * t1, axis=-1), np.sum(half * t2, axis=-1)], axis=-1).astype(np.float32)


def light_tangent_terms(positions, normals, view_dirs, light):
    """:func:`tangent_terms` of ``light`` at surface points ``positions`` with unit ``normals`` (..., 3)."""
    t1, t2 = tangent_frame(normals)
    return tangent_terms(_light_dirs(positions, light), view_dirs, t1, t2)
