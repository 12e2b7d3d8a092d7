"""How small a material a fit of the material model can find: the size at which a region of another
paint pays for itself.

A region of ``n`` pixels whose paint has ``c`` times the albedo of the material around it (both
amplitudes, diffuse and lobe, scaled by ``c``) gains about

    G(n) = n e,   e = zeta / (2 sigma^2) * mean over pixels of sum over lights of ((1 - c) mu_i)^2

log-likelihood units when it gets a material of its own (``mu_i`` the material's prediction on
the noise scales' units, ``sigma^2`` its residual variance, ``zeta`` the fit's likelihood power),
and costs its Potts boundary, ``beta`` per pair of 4-neighbours across it (about ``8 R`` pairs for
a digital disc of radius ``R``: 100 on the measured discs of radius 12), the prior odds of one more
material, ``-log rho``, and the labellings' ``log(K + 1)``. A disc is worth a material when
``pi R^2 e >= 8 beta R - log rho + log(K + 1)``: :func:`smallest_material` solves that for ``R``.

With the edge term in the target (:mod:`rjfit.sampler.regions.materials.edges`) the disc's
outline also earns: its pairs ``g`` px apart with one end inside (about ``8 g R`` of them) each
step by ``(1 - c) mu`` under every light, which the materials' step explains and no step does
not, so each earns about ``scale * mean over pixels of sum over lights of ((1 - c) mu_i)^2``
(``scale``: the term's ``power / (2 s^2)`` times the share of a step that no step misfits,
:data:`rjfit.sampler.regions.materials.edges.NO_STEP_NOISE`). The outline's gain is linear in ``R`` like the Potts
cost: where it exceeds ``beta`` per pair, a region pays for itself from a few pixels, the prior
odds its only cost.
The parameters' own Occam factor is left out, so a region at the returned size is at the edge
of being found, not sure to be.

Measured (docs/results/materials.md, "Resolution"): psm-horse under ``--preset measured`` with two
painted discs of a quarter of its albedo: predicted radius 12.5 px; discs of radius 6 and 9 were
not found, of 12 one of the two in each chain, of 16 both in every chain.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["smallest_material", "disc_radius", "RESOLUTION_CONTRAST", "RESOLUTION_WARN_PIXELS"]

#: the paint a fit's resolution is stated for: half (or, alike, 1.5 times) the material's albedo
RESOLUTION_CONTRAST = 0.5
#: a fit warns when a region of that paint must hold more pixels than this (an 11 x 11 patch: a painted
#: eye or a label on a 512-pixel-wide capture is smaller)
RESOLUTION_WARN_PIXELS = 100.0


def smallest_material(mu, pixel, sigma2: float, power: float, beta: float, rho: float, n_materials: int,
                      contrast: float = RESOLUTION_CONTRAST, edge_scale: float = 0.0, edge_gap: int = 3) -> dict:
    """The smallest disc of another paint that a material fit finds in a material (module docstring).

    Parameters
    ----------
    mu : ndarray, shape (N,)
        The material's prediction for each of its observations, divided by the observations'
        known noise scales (as the fit's likelihood sees it).
    pixel : ndarray of int, shape (N,)
        The pixel of each observation (only the number of distinct pixels is used).
    sigma2 : float or ndarray, shape (N,)
        The material's residual variance (on the same scale as ``mu``); per observation in a joint colour
        fit (its channel's).
    power, beta, rho : float
        The fit's likelihood power zeta and Potts prior (beta per unlike neighbour pair, rho per material).
    n_materials : int
        K, the fit's (MAP) number of materials.
    contrast : float
        The other paint's albedo as a multiple of this one's (positive, not 1).
    edge_scale, edge_gap : float or ndarray (N,), int
        The edge term's ``power / (2 s^2)`` (0: no edge term; per observation in a joint colour fit, its
        channel's ``power / (2 s_c^2)``, the channels' earnings summed) and its pairs' gap in pixels.

    Returns
    -------
    dict
        ``contrast``, ``evidence_per_pixel`` (e above), ``edge_evidence_per_pair`` (an outline pair's
        earning), ``radius_px`` and ``pixels`` (pi R^2) of the smallest such disc; ``radius_px`` is
        inf where the material has no observation.

    Raises
    ------
    ValueError
        If ``mu`` and ``pixel`` differ in length, or ``sigma2``, ``power``, ``rho`` or
        ``contrast`` is not positive and finite, ``contrast`` is 1, or ``beta``, ``edge_scale`` or
        ``edge_gap`` is negative.
    """
    mu = np.asarray(mu, dtype=float)
    pixel = np.asarray(pixel)
    if mu.shape != pixel.shape:
        raise ValueError(f"mu and pixel must have one entry per observation, got {mu.shape} and {pixel.shape}")
    for name, value in (("sigma2", sigma2), ("power", power), ("rho", rho), ("contrast", contrast)):
        if not np.all(np.isfinite(value) & (np.asarray(value) > 0)):
            raise ValueError(f"{name} must be positive and finite, got {value}")
    if contrast == 1.0 or not beta >= 0 or not np.all(np.asarray(edge_scale) >= 0) or not edge_gap >= 0:
        raise ValueError(f"contrast must differ from 1 and beta, edge_scale and edge_gap be >= 0, got {contrast}, "
                         f"{beta}, {edge_scale}, {edge_gap}")
    n_pixels = np.unique(pixel).size
    if n_pixels == 0:
        return {"contrast": contrast, "evidence_per_pixel": 0.0, "edge_evidence_per_pair": 0.0,
                "radius_px": math.inf, "pixels": math.inf}
    if np.ndim(sigma2) == 0 and np.ndim(edge_scale) == 0:
        step_per_pixel = float(np.sum(((1.0 - contrast) * mu) ** 2)) / n_pixels
        evidence = power * step_per_pixel / (2.0 * sigma2)
        per_pair = edge_scale * step_per_pixel
    else:       # a joint colour fit: each observation on its channel's variance and edge scale, the channels summed
        squared = ((1.0 - contrast) * mu) ** 2
        evidence = power * float(np.sum(squared / (2.0 * np.asarray(sigma2, float)))) / n_pixels
        per_pair = float(np.sum(np.asarray(edge_scale, float) * squared)) / n_pixels
    radius = disc_radius(evidence, beta - edge_gap * per_pair, rho, n_materials)
    return {"contrast": contrast, "evidence_per_pixel": evidence, "edge_evidence_per_pair": per_pair,
            "radius_px": radius, "pixels": math.pi * radius ** 2}


def disc_radius(evidence: float, beta: float, rho: float, n_materials: int) -> float:
    """The radius R at which a disc's gain ``pi R^2 evidence`` equals its cost ``8 beta R - log rho + log(K + 1)``
    (inf for no evidence). The evidence of another contrast ``c`` is this one's times ``(1 - c)^2 / (1 - c0)^2``.
    ``beta`` is the net cost per outline pair: negative where the edge term's earning exceeds the Potts cost."""
    if not evidence > 0:
        return math.inf
    fixed_cost = max(-math.log(rho) + math.log(n_materials + 1), 0.0)
    # pi e R^2 - 8 beta R - fixed_cost = 0, the positive root
    return (8.0 * beta + math.sqrt(64.0 * beta ** 2 + 4.0 * math.pi * evidence * fixed_cost)) / (2.0 * math.pi * evidence)
