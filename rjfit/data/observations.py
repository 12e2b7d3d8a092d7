"""Observations: per pixel and light, y, <l.n>, <h.n>, irradiance, and which are valid.

Only valid observations are stored (flat arrays over observations), so memory grows with
the number of valid observations rather than with pixels x lights.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Observations", "valid_observation_mask", "exclusion_reasons", "observations_from_stack", "stack_channels",
           "valid_images_per_pixel", "MIN_COS", "RIM_COS", "EXCLUSION_RULES"]


@dataclass(frozen=True)
class Observations:
    """The valid observations of one image stack (paper, eq. 1: one y per pixel and light).

    Usually built by :meth:`rjfit.Dataset.observations` or :func:`observations_from_stack`;
    the constructor stores its arguments as they are (no copy, no check). Each parameter
    is kept as the attribute of the same name.

    Parameters
    ----------
    image_shape : (int, int)
        ``(height, width)`` of the images.
    n_lights : int
    pixel : ndarray of int64, shape (N,)
        Flat pixel index ``row * width + col`` of each observation.
    light : ndarray of int32, shape (N,)
        Light (image) index of each observation.
    y, cos_ln, cos_hn, irradiance : ndarray of float64, shape (N,)
        Measured value, geometry terms and relative irradiance (intensity / r^2).
    object_mask : ndarray of bool, shape (H, W)
    channel : ndarray of int8, shape (N,), optional
        The colour channel of each observation of a joint colour fit (``--channel rgb``: 0, 1,
        2 for R, G, B; the observations of one pixel and light may be there once per channel);
        None for a single-channel stack (every observation one channel).
    n_channels : int
        The number of colour channels fitted jointly (1 for a single channel).
    cos_lh : ndarray of float64, shape (N,), or None
        ``<l.h>`` of each observation (the cosine of half the angle between the light and the
        view): with ``cos_ln`` and ``cos_hn`` it fixes how the prediction changes with the
        normal (:mod:`rjfit.data.normal_error`). None where the builder did not record it.
    tangent : ndarray of float32, shape (N, 4), or None
        ``(l.t1, l.t2, h.t1, h.t2)``: the light's and the half vector's components in an
        orthonormal tangent frame ``(t1, t2)`` of the pixel's given normal (one frame per
        pixel, :func:`rjfit.data.lights.tangent_frame`), what a fit that samples the normals
        needs (``--normals sample``, :mod:`rjfit.sampler.normals`). Built only when asked
        (16 bytes per observation); None otherwise.
    """

    image_shape: tuple[int, int]
    n_lights: int
    pixel: np.ndarray
    light: np.ndarray
    y: np.ndarray
    cos_ln: np.ndarray
    cos_hn: np.ndarray
    irradiance: np.ndarray
    object_mask: np.ndarray
    channel: np.ndarray | None = None
    n_channels: int = 1
    cos_lh: np.ndarray | None = None
    tangent: np.ndarray | None = None

    @property
    def n_obs(self) -> int:
        """The number of observations N."""
        return int(self.y.shape[0])

    @property
    def row(self) -> np.ndarray:
        """Image row of each observation, shape (N,)."""
        return self.pixel // self.image_shape[1]

    @property
    def col(self) -> np.ndarray:
        """Image column of each observation, shape (N,)."""
        return self.pixel % self.image_shape[1]

    @property
    def valid_count(self) -> np.ndarray:
        """The paper's "valid images per pixel" map (its Fig. 8), shape (H, W)."""
        height, width = self.image_shape
        return np.bincount(self.pixel, minlength=height * width).reshape(height, width)

    def dense(self, values=None) -> np.ndarray:
        """Per-observation ``values`` (default ``y``) scattered into images (L, H, W), NaN where none.

        One channel only: a joint colour stack has several observations per pixel and light.
        """
        height, width = self.image_shape
        out = np.full((self.n_lights, height, width), np.nan)
        out[np.asarray(self.light, np.int64), self.row, self.col] = self.y if values is None else values
        return out

    def subset(self, keep: np.ndarray) -> "Observations":
        """The observations selected by a boolean or index array over observations."""
        return Observations(
            image_shape=self.image_shape, n_lights=self.n_lights, pixel=self.pixel[keep],
            light=self.light[keep], y=self.y[keep], cos_ln=self.cos_ln[keep],
            cos_hn=self.cos_hn[keep], irradiance=self.irradiance[keep], object_mask=self.object_mask,
            channel=None if self.channel is None else self.channel[keep], n_channels=self.n_channels,
            cos_lh=None if self.cos_lh is None else self.cos_lh[keep],
            tangent=None if self.tangent is None else self.tangent[keep],
        )


# <l.n> at or below which the light grazes or is behind the surface: no usable observation
MIN_COS = 1e-3
#: <v.n> below which a pixel is seen at a grazing angle (more than 72.5 degrees from its normal):
#: the rim, where a measured normal's error, a pixel's footprint and the object's edge (pixels
#: partly background) change the radiance most, and a rough surface's retro-reflection lives
RIM_COS = 0.3
# the rules that leave an observation out, in the order :func:`exclusion_reasons` returns them
EXCLUSION_RULES = ("unlit", "grazing_view", "shadowed", "saturated", "too_dark", "not_finite")


def exclusion_reasons(images, cos_ln, visible, *, saturation=None, dark=None, min_cos=MIN_COS,
                      grazing=None) -> dict:
    """Why observations may not enter the likelihood: one bool array per rule, in this order.

    ``unlit`` (the surface does not face the light: ``<l.n> <= min_cos``), ``grazing_view``
    (the camera sees the surface at a grazing angle: ``grazing``), ``shadowed`` (the
    light is occluded: not ``visible``), ``saturated`` (at or above ``saturation``: a clipped
    value is a bound, not a measurement), ``too_dark`` (at or below ``dark``) and
    ``not_finite``. A rule without its input (``visible``, ``saturation``, ``dark`` or
    ``grazing`` None) flags nothing. The rules are the complements of the valid tests, so an observation is
    valid exactly when no rule flags it (:func:`valid_observation_mask`).

    Parameters
    ----------
    images, cos_ln : ndarray, shape (L, H, W) (or any one shape)
    visible : ndarray of bool of that shape, or None (no cast shadows known)
    saturation, dark : float or None
    grazing : ndarray of bool broadcastable to that shape, or None
        Pixels seen at a grazing angle (e.g. :meth:`rjfit.data.dataset.Dataset.rim_pixels`).

    Returns
    -------
    dict of str -> ndarray of bool
    """
    images = np.asarray(images)

    def none():     # a fresh array per rule: callers add their own flags to a rule in place
        return np.zeros(images.shape, dtype=bool)

    return {"unlit": ~(np.asarray(cos_ln) > min_cos),
            "grazing_view": np.broadcast_to(np.asarray(grazing, dtype=bool), images.shape).copy()
            if grazing is not None else none(),
            "shadowed": ~np.asarray(visible, dtype=bool) if visible is not None else none(),
            "saturated": ~(images < saturation) if saturation is not None else none(),
            "too_dark": ~(images > dark) if dark is not None else none(),
            "not_finite": ~np.isfinite(images)}


def valid_observation_mask(images, cos_ln, visible, object_mask, *, saturation=None, dark=None,
                           min_cos=MIN_COS):
    """Which observations may enter the likelihood.

    An observation (light ``l``, pixel ``p``) is valid when the pixel lies in the object
    mask and no rule of :func:`exclusion_reasons` flags it: the surface faces the light
    (``<l.n> > min_cos``), the light is not occluded (``visible``), the value is finite, below
    ``saturation`` (a saturated value is a bound, not a measurement) and, if given, above ``dark``.

    Parameters
    ----------
    images, cos_ln : ndarray, shape (L, H, W)
    visible : ndarray of bool, shape (L, H, W) or None (no cast shadows known)
    object_mask : ndarray of bool, shape (H, W)
    saturation, dark : float or None

    Returns
    -------
    ndarray of bool, shape (L, H, W)
    """
    images = np.asarray(images)
    reasons = exclusion_reasons(images, cos_ln, visible, saturation=saturation, dark=dark, min_cos=min_cos)
    return np.broadcast_to(np.asarray(object_mask, dtype=bool), images.shape) & ~np.logical_or.reduce(
        list(reasons.values()))


def valid_images_per_pixel(valid):
    """Count of valid images per pixel (paper, Fig. 8) from an (L, H, W) validity mask."""
    return np.asarray(valid, dtype=bool).sum(axis=0)


def observations_from_stack(images, cos_ln, cos_hn, irradiance, valid, object_mask, cos_lh=None,
                            tangent=None) -> Observations:
    """Gather the valid entries of dense (L, H, W) arrays into :class:`Observations`.

    Parameters
    ----------
    images, cos_ln, cos_hn, irradiance : array_like, shape (L, H, W)
        Measured values, geometry terms and relative irradiance per light and pixel.
    valid : array_like of bool, shape (L, H, W)
        Which entries to keep, used as given (e.g. from :func:`valid_observation_mask`;
        it is not intersected with ``object_mask`` here).
    object_mask : array_like of bool, shape (H, W)
        Stored with the observations.
    cos_lh : array_like, shape (L, H, W), optional
        ``<l.h>`` per light and pixel (:attr:`Observations.cos_lh`).
    tangent : array_like, shape (L, H, W, 4), optional
        The tangent-frame components per light and pixel (:attr:`Observations.tangent`).

    Returns
    -------
    Observations
        The entries where ``valid`` is true, in (light, row, column) order.

    Raises
    ------
    ValueError
        If ``images`` is not 3-D, another array's shape differs from it (``object_mask``:
        from its last two axes), or no observation is valid.
    """
    images = np.asarray(images, dtype=float)
    if images.ndim != 3:
        raise ValueError(f"images must have shape (lights, height, width), got {images.shape}")
    for name, array in (("cos_ln", cos_ln), ("cos_hn", cos_hn), ("irradiance", irradiance), ("valid", valid),
                        ("cos_lh", images if cos_lh is None else cos_lh)):
        if np.shape(array) != images.shape:
            raise ValueError(f"{name} has shape {np.shape(array)}, images have {images.shape}")
    if tangent is not None and np.shape(tangent) != images.shape + (4,):
        raise ValueError(f"tangent has shape {np.shape(tangent)}, images have {images.shape} (+ 4 components)")
    if np.shape(object_mask) != images.shape[1:]:
        raise ValueError(f"object mask has shape {np.shape(object_mask)}, images are {images.shape[1:]}")
    valid = np.asarray(valid, dtype=bool)
    if not valid.any():
        raise ValueError("no valid observation: check the object mask, the lights and the saturation level")
    light_index, rows, cols = np.nonzero(valid)
    width = images.shape[2]
    return Observations(
        image_shape=(int(images.shape[1]), int(width)),
        n_lights=int(images.shape[0]),
        pixel=(rows.astype(np.int64) * width + cols),
        light=light_index.astype(np.int32),
        y=images[valid],
        cos_ln=np.asarray(cos_ln, dtype=float)[valid],
        cos_hn=np.asarray(cos_hn, dtype=float)[valid],
        irradiance=np.asarray(irradiance, dtype=float)[valid],
        object_mask=np.asarray(object_mask, dtype=bool),
        cos_lh=None if cos_lh is None else np.asarray(cos_lh, dtype=float)[valid],
        tangent=None if tangent is None else np.asarray(tangent, dtype=np.float32)[valid],
    )


def stack_channels(per_channel) -> Observations:
    """The observations of a joint colour fit: each channel's :class:`Observations`, one after the other.

    Parameters
    ----------
    per_channel : sequence of Observations
        One per colour channel (R, G, B), of one stack: the same images, lights and mask.
        Each keeps its own valid observations (a channel too dark or not finite there drops
        out of that channel only).

    Returns
    -------
    Observations
        ``channel`` holds each observation's channel index, ``n_channels`` their number.

    Raises
    ------
    ValueError
        If fewer than two channels are given, or they differ in image shape or lights.
    """
    parts = list(per_channel)
    if len(parts) < 2:
        raise ValueError(f"a joint colour fit needs two or more channels, got {len(parts)}")
    first = parts[0]
    if any(o.image_shape != first.image_shape or o.n_lights != first.n_lights or o.channel is not None
           for o in parts):
        raise ValueError("the channels of a joint colour fit must be single channels of one stack "
                         "(same image shape and lights)")
    return Observations(
        image_shape=first.image_shape, n_lights=first.n_lights,
        **{name: np.concatenate([getattr(o, name) for o in parts])
           for name in ("pixel", "light", "y", "cos_ln", "cos_hn", "irradiance")},
        object_mask=first.object_mask,
        channel=np.concatenate([np.full(o.n_obs, c, np.int8) for c, o in enumerate(parts)]),
        n_channels=len(parts),
        cos_lh=None if any(o.cos_lh is None for o in parts) else np.concatenate([o.cos_lh for o in parts]),
        tangent=None if any(o.tangent is None for o in parts) else np.concatenate([o.tangent for o in parts]))
