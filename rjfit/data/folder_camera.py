"""A photometric-stereo folder's camera: its declaration in ``rjfit.json`` checked, the view direction at
every pixel, and the record ``meta["camera"]`` keeps (the conventions: :mod:`rjfit.data.diligent`)."""
from __future__ import annotations

import numpy as np

from rjfit.errors import DatasetError

__all__ = ["CAMERA_KINDS", "check_camera", "view_directions", "camera_meta", "is_finite_number"]

CAMERA_KINDS = ("orthographic", "perspective")


def check_camera(camera, where: str) -> dict:
    """A photometric-stereo folder's camera declaration, checked; returns it with its defaults filled in.

    Parameters
    ----------
    camera : dict or None
        ``{"kind": "orthographic"}`` (the default, None) or ``{"kind": "perspective",
        "focal_px": f, "principal_point": [cx, cy]}`` (principal point optional).
    where : str
        Names the declaration in messages (the file and key).

    Raises
    ------
    DatasetError
        If the kind is unknown, a key is unknown, the focal length is not a positive number or
        the principal point is not two finite numbers.
    """
    if camera is None:
        return {"kind": "orthographic"}
    if not isinstance(camera, dict):
        raise DatasetError(f"{where} is {camera!r}; it must be an object such as {{\"kind\": \"orthographic\"}}")
    kind = camera.get("kind")
    if kind not in CAMERA_KINDS:
        raise DatasetError(f"{where}: kind is {kind!r}; it must be one of {', '.join(CAMERA_KINDS)}")
    allowed = {"orthographic": {"kind"}, "perspective": {"kind", "focal_px", "principal_point"}}[kind]
    unknown = sorted(set(camera) - allowed)
    if unknown:
        raise DatasetError(f"{where}: unknown key(s) {', '.join(unknown)} for a {kind} camera; allowed: "
                           f"{', '.join(sorted(allowed))}")
    if kind == "orthographic":
        return {"kind": "orthographic"}
    focal = camera.get("focal_px")
    if not (is_finite_number(focal) and focal > 0):
        raise DatasetError(f"{where}: focal_px is {focal!r}; a perspective camera needs its focal length in pixels, "
                           f"a number > 0")
    principal = camera.get("principal_point")
    if principal is not None and not (isinstance(principal, (list, tuple)) and len(principal) == 2
                                      and all(is_finite_number(v) for v in principal)):
        raise DatasetError(f"{where}: principal_point is {principal!r}; it must be [cx, cy] in pixels (or left out "
                           f"for the frame's centre)")
    return {"kind": "perspective", "focal_px": float(focal),
            "principal_point": None if principal is None else [float(v) for v in principal]}


def view_directions(camera: dict, height: int, width: int) -> np.ndarray:
    """Unit directions towards the camera at every pixel centre, (H, W, 3), for a checked ``camera``.

    Orthographic: (0, 0, 1) everywhere. Perspective: minus the pixel-centre ray's direction
    (module docstring), with the principal point defaulting to the frame's centre.
    """
    if camera["kind"] == "orthographic":
        return np.broadcast_to(np.array([0.0, 0.0, 1.0]), (height, width, 3)).copy()
    cx, cy = camera["principal_point"] or (width / 2.0, height / 2.0)
    focal = camera["focal_px"]
    cols, rows = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    towards = np.stack([-(cols - cx) / focal, (rows - cy) / focal, np.ones_like(cols)], axis=-1)
    return towards / np.linalg.norm(towards, axis=-1, keepdims=True)


def camera_meta(camera, height, width) -> dict:
    """The camera as ``meta["camera"]`` records it: ``kind`` (as in ``rjfit.json`` and scenes) and, for a
    pinhole, its intrinsics in pixels."""
    if camera["kind"] == "orthographic":
        return {"kind": "orthographic", "view_direction": [0.0, 0.0, 1.0]}
    return {"kind": "perspective", "focal_px": camera["focal_px"],
            "principal_point": camera["principal_point"] or [width / 2.0, height / 2.0]}


def is_finite_number(value) -> bool:
    """An int or float (not a bool) that is finite: what a declared number in ``rjfit.json`` must be."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value)
