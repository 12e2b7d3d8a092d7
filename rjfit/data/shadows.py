"""Observations of a measured stack that do not see the surface's reflectance: cast shadows (far darker than the
pixel's own Lambertian shading) and the silhouette's mixed pixels.

Why
---
A measured stack ships no visibility: an observation in a cast shadow (a leg in front of the
body, the crease under a chin) or deep in a concavity holds the light that reached it by
interreflection, not the reflectance the fit models. On the psm stacks 1 to 4 % of the
observations carry 6 to 32 % of a one-material fit's squared standardised residual, and
leaving them out lowers the residuals' neighbour correlation more than any lobe
(docs/results/misfit-shares.md, variant g). Left in, they are misfit the fit can only
absorb by a material of their own along the shadow.

The rule
--------
Per object pixel, its Lambertian albedo ``a = median over lights of y / (E <l.n>)``, over the
lights that face it well (``<l.n> > 0.3``) and whose observation is not otherwise left out;
an observation of a well-lit light with ``y < SHADOW_FRACTION * a * E <l.n>`` is a cast
shadow. Only well-lit observations are judged: near the terminator the Lambertian prediction
is as small as the noise, and a rule there would select observations by their noise draw. The albedo is the
pixel's own, so a paint's pixels are judged against their own paint, never against their
neighbours'; the median over the well-lit lights is robust to a highlight. The fraction is
physical, not fitted: direct light that reaches a surface gives its Lambertian share, and a
glossy lobe only adds to it, so under a third of it means the light was blocked (what is left
is ambient and interreflected light). Pixels with fewer than three well-lit observations are
not judged.

The silhouette
--------------
A pixel of the mask's outline (a 4-neighbour outside the mask) straddles the object's edge: part
of its footprint is background, so it is darker than the surface under every light, and its
photometric-stereo normal is a mix too. On psm-horse such pixels, a few dozen scattered along
the outline at under half the body's radiance, bought a material of their own in three chains
of four once the edge term earned at steps (docs/results/2026-11-28-paints.md).
:func:`flag_silhouette` leaves every observation of them out; like the rim's pixels, their
labels then follow their neighbours'.
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy import ndimage

__all__ = ["flag_cast_shadows", "flag_silhouette", "lambertian_albedo", "SHADOW_FRACTION", "WELL_LIT_COS"]

#: an observation darker than this share of its pixel's Lambertian prediction is a cast shadow
SHADOW_FRACTION = 0.3
#: the lights whose observations estimate a pixel's albedo face it at least this well (<l.n>)
WELL_LIT_COS = 0.3


def flag_cast_shadows(dataset, channel: str = "mean"):
    """The data set with its cast shadows left out (module docstring) and their record.

    The shadows are written into ``visibility`` (False: occluded), so the ``shadowed`` rule
    leaves them out and the fit's valid-images figure counts them.

    Parameters
    ----------
    dataset : rjfit.data.dataset.Dataset
        Linear values (after any response and gains).
    channel : str
        The channel the rule reads (the fit's).

    Returns
    -------
    (Dataset, dict)
        ``{"rule", "fraction", "observations_flagged", "share", "pixels_judged"}``.
    """
    obs = dataset.observations(channel)
    pixel, light = np.asarray(obs.pixel, np.int64), np.asarray(obs.light, np.int64)
    y, shading = np.asarray(obs.y, float), np.asarray(obs.irradiance, float) * np.asarray(obs.cos_ln, float)
    well_lit = (np.asarray(obs.cos_ln) > WELL_LIT_COS) & (shading > 0)
    _, compact, albedo = _median_albedo(obs, dataset.n_lights)
    judged = np.isfinite(albedo)
    with np.errstate(invalid="ignore"):      # unjudged pixels (NaN albedo) are never shadows
        shadow = well_lit & judged[compact] & (y < SHADOW_FRACTION * albedo[compact] * shading)
    visibility = np.ones((dataset.n_lights,) + dataset.image_shape, bool) if dataset.visibility is None \
        else np.array(dataset.visibility, bool)
    rows, cols = np.unravel_index(pixel[shadow], dataset.image_shape)
    visibility[light[shadow], rows, cols] = False
    flagged = int(shadow.sum())
    record = {"rule": f"y < {SHADOW_FRACTION} x the pixel's Lambertian prediction, its albedo the median of "
                      f"y / (E <l.n>) over its lights with <l.n> > {WELL_LIT_COS}",
              "fraction": SHADOW_FRACTION, "observations_flagged": flagged,
              "share": flagged / max(y.size, 1), "pixels_judged": int(judged.sum())}
    return dataclasses.replace(dataset, visibility=visibility), record


def lambertian_albedo(dataset, channel: str = "mean") -> tuple[np.ndarray, np.ndarray]:
    """Each observed pixel's Lambertian albedo: the median of ``y / (E <l.n>)`` over its lights with ``<l.n> >``
    :data:`WELL_LIT_COS` (the shadow rule's), where it has 3 or more.

    Returns
    -------
    (ndarray, ndarray)
        The flat pixel indices and their albedos (NaN where fewer than 3 lights face the pixel well).
    """
    pixels, _, albedo = _median_albedo(dataset.observations(channel), dataset.n_lights)
    return pixels, albedo


def _median_albedo(obs, n_lights: int):
    pixel, light = np.asarray(obs.pixel, np.int64), np.asarray(obs.light, np.int64)
    y, shading = np.asarray(obs.y, float), np.asarray(obs.irradiance, float) * np.asarray(obs.cos_ln, float)
    well_lit = (np.asarray(obs.cos_ln) > WELL_LIT_COS) & (shading > 0)
    pixels, compact = np.unique(pixel, return_inverse=True)       # a column per observed pixel, not per frame pixel
    ratio = np.full((n_lights, pixels.size), np.nan, np.float32)
    ratio[light[well_lit], compact[well_lit]] = y[well_lit] / shading[well_lit]
    judged = np.sum(np.isfinite(ratio), axis=0) >= 3
    albedo = np.full(pixels.size, np.nan)
    albedo[judged] = np.nanmedian(ratio[:, judged], axis=0)
    return pixels, compact, albedo


def flag_silhouette(dataset):
    """The data set with every observation of the mask's outline pixels left out (module docstring) and a record.

    Written into ``visibility`` (False), as :func:`flag_cast_shadows`.

    Returns
    -------
    (Dataset, dict)
        ``{"rule", "pixels_flagged"}``.
    """
    mask = np.asarray(dataset.object_mask, bool)
    outline = mask & ~ndimage.binary_erosion(mask, structure=ndimage.generate_binary_structure(2, 1),
                                             border_value=0)
    visibility = np.ones((dataset.n_lights,) + dataset.image_shape, bool) if dataset.visibility is None \
        else np.array(dataset.visibility, bool)
    visibility[:, outline] = False
    record = {"rule": "the mask's outline (a 4-neighbour outside the mask): pixels partly background",
              "pixels_flagged": int(outline.sum())}
    return dataclasses.replace(dataset, visibility=visibility), record
