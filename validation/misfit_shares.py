"""Which physics pays on the measured stacks: each candidate part's share of the residual correlation (issue 45, item 5).

For one stack and one segmentation, every material is fitted (least squares, amplitudes >= 0,
the lobe's shape by a grid and Nelder-Mead on its logarithm) under a variant of the model, and
the standardised residuals' lag-1 correlation between horizontal and vertical neighbours under
one light (and one channel) gives the likelihood power ((1 - rho) / (1 + rho))^2 of the
coarsening rule (:mod:`rjfit.data.coarsen`). The variants, each a part issue 45 names:

``a``    one Lambert + energy-normalised Blinn lobe per material, the given normals (the fit's model);
``b``    (a) with every pixel's normal re-estimated given its material's BRDF (:func:`refine_normals`);
``c``    Lambert + a GGX lobe (Smith masking, Schlick Fresnel: roughness, F0, amplitude per material);
``d``    Lambert + two Blinn lobes;
``e``    (a) with per-channel amplitudes (R, G, B albedo and lobe) and a shared lobe shape, residuals of R, G, B;
``bc``, ``bce``  the combinations; ``g``: (bc) with shadowed observations left out (:func:`shadow_mask`);
``l``, ``r``  not issue 45's parts: (a) with each light's direction and gain re-estimated (:func:`refine_lights`);
         (a) with a smooth correction of the camera response shared by every pixel (:func:`response_correction`);
``p``    a bound, not a part: (a) with every pixel's prediction scaled by its own least-squares factor (an albedo
         texture inside a material: what no segmentation into a few paints can exceed);
``f``    not a part: (a) with each light's irradiance a smooth field over the image (a quadratic in the pixel's
         position, six numbers per light): lights that are near or not uniform.

The reference row ``pp`` is the rule as the fit reports it today: per-pixel fits, standardised
by the preset's normal-error noise scales (:func:`rjfit.data.coarsen.suggest_likelihood_power`).

Estimators (simple, stated): the white noise sd per channel from second differences of the
calibrated images along rows and columns inside the object (1.4826 MAD / sqrt(6)); residuals
standardised per material and channel by 1.4826 MAD; rho the Pearson correlation of all
neighbour pairs (as the coarsening rule), rho_rows and rho_cols averaged and floored at 0.

Example::

    python validation/misfit_shares.py /work/shared/data/psm-cat --kmeans 2 3 4 --out /tmp/shares/cat.jsonl
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy import ndimage
from scipy.optimize import minimize, nnls

from rjfit.data.calibrate import calibrate_measured
from rjfit.data.coarsen import neighbour_correlations, suggest_likelihood_power
from rjfit.data.noise import noise_scale
from rjfit.model.blinn import blinn_normalisation
from rjfit.pipeline.fit_dataset import ghost_material_prior
from rjfit.render.datasets import load_dataset
from rjfit.sampler.regions.materials.kmeans import kmeans_labels

# variant -> (lobe family, normals re-estimated, colour, shadows left out, lights re-estimated)
VARIANTS = {"a": ("blinn", False, False, False, False), "b": ("blinn", True, False, False, False),
            "c": ("ggx", False, False, False, False), "d": ("blinn2", False, False, False, False),
            "e": ("blinn", False, True, False, False), "bc": ("ggx", True, False, False, False),
            "bce": ("ggx", True, True, False, False), "g": ("ggx", True, False, True, False),
            "l": ("blinn", False, False, False, True), "r": ("blinn", False, False, False, False),
            "p": ("blinn", False, False, False, False), "f": ("blinn", False, False, False, False)}
PARTS = ("b", "c", "d", "e", "bc", "bce", "g")      # the variants that are issue 45's parts (the rest are bounds, probes)
# lobe shape grids (the search starts at the best grid point): Blinn exponents as rjfit's pixel fits, GGX roughness
GRIDS = {"blinn": [np.geomspace(0.5, 500.0, 16)], "ggx": [np.geomspace(0.02, 1.0, 14)],
         "blinn2": [np.geomspace(0.5, 500.0, 10)] * 2}
SHADOW_COS = 0.1        # <l.n> below it: the terminator's attached shadow (the light within 6 deg of the horizon)
SHADOW_FRACTION = 0.3   # darker than this fraction of the pixel's own Lambertian prediction: a cast shadow
MAD_SD = 1.4826


@dataclasses.dataclass(frozen=True)
class Stack:
    """A calibrated stack on its object pixels: values (P, L, 3), valid (P, L), normals and view (P, 3),
    lights (L, 3, unit, towards the light), irradiance (L,), the half vectors (P, L, 3), pixel rows and cols."""

    y: np.ndarray
    valid: np.ndarray
    normals: np.ndarray
    view: np.ndarray
    lights: np.ndarray
    irradiance: np.ndarray
    half: np.ndarray
    rows: np.ndarray
    cols: np.ndarray
    shape: tuple

    def values(self, colour: bool) -> np.ndarray:
        """(P, L, C): R, G, B (C = 3) or their mean (C = 1)."""
        return self.y if colour else self.y.mean(axis=-1, keepdims=True)


def stack_from_dataset(dataset) -> Stack:
    """The object pixels of a data set with directional lights, valid as the mean channel's fit sees them.

    Raises
    ------
    ValueError
        If a light is not directional.
    """
    if any(light.kind != "directional" for light in dataset.lights):
        raise ValueError(f"{dataset.path}: only directional lights are supported here")
    rows, cols = np.nonzero(dataset.object_mask)
    lights = np.array([light.direction for light in dataset.lights], float)
    lights /= np.linalg.norm(lights, axis=1, keepdims=True)
    view = np.asarray(dataset.view_dirs, float)[rows, cols]
    half = lights[None] + view[:, None]
    half /= np.linalg.norm(half, axis=-1, keepdims=True)
    irradiance = np.array([light.intensity for light in dataset.lights], float) / dataset.reference_intensity
    return Stack(y=np.moveaxis(np.asarray(dataset.images, float)[:, rows, cols, :], 0, 1),
                 valid=dataset.valid_mask("mean")[:, rows, cols].T, normals=np.asarray(dataset.normals, float)[rows, cols],
                 view=view, lights=lights, irradiance=irradiance, half=half, rows=rows, cols=cols,
                 shape=dataset.image_shape)


def geometry(stack: Stack, normals, pixels=slice(None)) -> dict:
    """<l.n>, <h.n>, <v.n>, <l.h> and E of ``pixels`` for these normals (each (p, L))."""
    half = stack.half[pixels]
    return {"ln": normals @ stack.lights.T, "hn": np.einsum("plk,pk->pl", half, normals),
            "vn": np.sum(normals * stack.view[pixels], axis=-1)[:, None],
            "lh": np.einsum("plk,lk->pl", half, stack.lights), "E": stack.irradiance[None]}


def columns(family: str, shape, geo: dict) -> list:
    """The model's basis functions at ``geo``: Lambert first, then the lobe's (each E <l.n> times a BRDF term)."""
    shading = geo["E"] * np.maximum(geo["ln"], 0.0)
    hn = np.clip(geo["hn"], 1e-12, 1.0)
    lambert = shading / np.pi
    if family in ("blinn", "blinn2"):
        return [lambert] + [shading * blinn_normalisation(g) * np.exp(g * np.log(hn)) for g in shape]
    alpha2 = float(shape[0]) ** 2
    ln, vn = np.clip(geo["ln"], 1e-6, 1.0), np.clip(geo["vn"], 1e-6, 1.0)
    distribution = alpha2 / (np.pi * (hn * hn * (alpha2 - 1.0) + 1.0) ** 2)

    def g1(c):      # Smith's masking of the GGX distribution (separable form)
        return 2.0 * c / (c + np.sqrt(alpha2 + (1.0 - alpha2) * c * c))

    # E <l.n> D G / (4 <l.n> <v.n>); Schlick F = F0 + (1 - F0)(1 - <l.h>)^5: amplitudes b F0 and b (1 - F0)
    specular = np.where(geo["ln"] > 0, geo["E"] * distribution * g1(ln) * g1(vn) / (4.0 * vn), 0.0)
    return [lambert, specular, specular * (1.0 - np.clip(geo["lh"], 0.0, 1.0)) ** 5]


def nonnegative_fit(basis, y) -> tuple[np.ndarray, np.ndarray]:
    """Amplitudes >= 0 (k, C) of ``y`` (n, C) on the columns of ``basis`` (n, k), and the sums of squared residuals (C,).

    Least squares through the Gram matrix: with G = R^T R, min |A x - y|^2 is min |R x - R^-T A^T y|^2.
    """
    gram = basis.T @ basis
    rhs = basis.T @ y
    scale = np.sqrt(np.maximum(np.diag(gram), 1e-300))
    upper = np.linalg.cholesky(gram / np.outer(scale, scale) + 1e-10 * np.eye(len(scale))).T
    coef = np.column_stack([nnls(upper, np.linalg.solve(upper.T, rhs[:, c] / scale))[0] / scale
                            for c in range(y.shape[1])])
    ssr = np.sum(y * y, axis=0) - 2.0 * np.sum(coef * rhs, axis=0) + np.sum(coef * (gram @ coef), axis=0)
    return coef, ssr


def fit_material(family: str, geo: dict, y, valid) -> dict:
    """One material's lobe shape (grid, then Nelder-Mead on its log) and amplitudes on its valid observations."""
    def ssr(log_shape):
        basis = np.stack([column[valid] for column in columns(family, np.exp(log_shape), geo)], axis=1)
        return float(np.sum(nonnegative_fit(basis, y[valid])[1]))

    grids = [np.log(grid) for grid in GRIDS[family]]
    candidates = [np.array(point) for point in np.array(np.meshgrid(*grids)).reshape(len(grids), -1).T
                  if len(point) == 1 or point[0] < point[1]]
    start = min(candidates, key=ssr)
    best = minimize(ssr, start, method="Nelder-Mead",
                    options={"xatol": 1e-3, "fatol": 1e-9 * ssr(start), "maxiter": 80 * len(start)})
    shape = np.exp(np.clip(best.x, min(g.min() for g in grids) - 3.0, max(g.max() for g in grids) + 3.0))
    basis = np.stack([column[valid] for column in columns(family, shape, geo)], axis=1)
    coef, total = nonnegative_fit(basis, y[valid])
    return {"shape": shape.tolist(), "coef": coef, "ssr": total.tolist(), "n": int(valid.sum())}


def predict(stack: Stack, normals, labels, fits, family: str) -> np.ndarray:
    """(P, L, C) model values of every pixel under its material's fit."""
    out = np.zeros(stack.valid.shape + (fits[0]["coef"].shape[1],))
    for m, fit in enumerate(fits):
        pixels = np.flatnonzero(labels == m)
        basis = columns(family, fit["shape"], geometry(stack, normals[pixels], pixels))
        out[pixels] = np.einsum("kpl,kc->plc", np.asarray(basis), fit["coef"])
    return out


def fit_all(stack: Stack, normals, labels, family: str, y, valid) -> list:
    """:func:`fit_material` for every material of ``labels``."""
    fits = []
    for m in range(int(labels.max()) + 1):
        pixels = np.flatnonzero(labels == m)
        fits.append(fit_material(family, geometry(stack, normals[pixels], pixels), y[pixels], valid[pixels]))
    return fits


def tangents(normals) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors per normal, orthogonal to it and to each other."""
    helper = np.where(np.abs(normals[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    first = np.cross(normals, helper)
    first /= np.linalg.norm(first, axis=1, keepdims=True)
    return first, np.cross(normals, first)


def refine_normals(stack: Stack, given, labels, fits, family, y, valid, noise_sd, prior_rad, steps=6) -> np.ndarray:
    """Each pixel's normal by Gauss-Newton on its two tangent-plane angles given its material's BRDF.

    Objective per pixel: sum over its valid observations (and channels) of ((y - mu(n)) / noise_sd)^2
    plus |angles|^2 / prior_rad^2, a Gaussian prior centred on the given normal. The Jacobian is a forward
    difference (1e-4 rad); a step that does not lower a pixel's objective is halved (up to 4 times).
    """
    first, second = tangents(given)
    weight = valid[..., None] / np.asarray(noise_sd, float)

    def normal(angles):
        n = given + angles[:, :1] * first + angles[:, 1:] * second
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    def residual(angles):
        return ((y - predict(stack, normal(angles), labels, fits, family)) * weight).reshape(len(given), -1)

    def objective(r, angles):
        return np.sum(r * r, axis=1) + np.sum(angles * angles, axis=1) / prior_rad ** 2

    angles = np.zeros((len(given), 2))
    r = residual(angles)
    cost = objective(r, angles)
    for _ in range(steps):
        jac = np.stack([-(residual(angles + 1e-4 * np.eye(2)[i]) - r) / 1e-4 for i in range(2)], axis=2)
        a = np.einsum("pmi,pmj->pij", jac, jac) + np.eye(2) / prior_rad ** 2
        step = np.linalg.solve(a, (np.einsum("pmi,pm->pi", jac, r) - angles / prior_rad ** 2)[..., None])[..., 0]
        for _ in range(5):
            trial = angles + step
            r_trial = residual(trial)
            cost_trial = objective(r_trial, trial)
            better = cost_trial < cost
            angles[better], r[better], cost[better] = trial[better], r_trial[better], cost_trial[better]
            step = np.where(better[:, None], 0.0, 0.5 * step)
            if not step.any():
                break
    return normal(angles)


def with_lights(stack: Stack, lights, gains) -> Stack:
    """The stack under other light directions (L, 3) and relative gains (L,): half vectors and irradiance anew."""
    lights = lights / np.linalg.norm(lights, axis=1, keepdims=True)
    half = lights[None] + stack.view[:, None]
    return dataclasses.replace(stack, lights=lights, irradiance=stack.irradiance * gains,
                               half=half / np.linalg.norm(half, axis=-1, keepdims=True))


def refine_lights(stack: Stack, normals, labels, fits, family, y, valid, steps=4) -> tuple[Stack, dict]:
    """Each light's direction (two tangent angles) and gain by Gauss-Newton on all its observations, the
    materials' fits held; no prior (thousands of pixels per light). Forward-difference Jacobian (1e-4)."""
    first, second = tangents(stack.lights)
    given = stack.lights

    def residual(x):
        lights = given + x[:, :1] * first + x[:, 1:2] * second
        moved = with_lights(stack, lights, np.exp(x[:, 2]))
        r = np.where(valid[..., None], y - predict(moved, normals, labels, fits, family), 0.0)
        return np.moveaxis(r, 1, 0).reshape(len(given), -1), moved

    x = np.zeros((len(given), 3))
    r, moved = residual(x)
    for _ in range(steps):
        jac = np.stack([-(residual(x + 1e-4 * np.eye(3)[i])[0] - r) / 1e-4 for i in range(3)], axis=2)
        step = np.linalg.solve(np.einsum("lmi,lmj->lij", jac, jac) + 1e-12 * np.eye(3),
                               np.einsum("lmi,lm->li", jac, r)[..., None])[..., 0]
        trial, moved_trial = residual(x + step)
        if np.sum(trial ** 2) >= np.sum(r ** 2):
            break
        x, r, moved = x + step, trial, moved_trial
    turn = np.degrees(np.hypot(x[:, 0], x[:, 1]))
    return moved, {"turn_deg": turn.tolist(), "gain": np.exp(x[:, 2]).tolist()}


def response_correction(prediction, residuals, valid, degree: int = 5) -> np.ndarray:
    """p(mu): a polynomial of degree ``degree`` in the prediction over its maximum, fitted by least squares to the
    residuals of every valid observation: what a camera response that is not exactly the estimated power law leaves."""
    out = np.zeros_like(prediction)
    for c in range(prediction.shape[-1]):       # one curve per channel
        mu, r = prediction[..., c], residuals[..., c]
        scale = np.max(mu[valid])
        out[..., c] = np.polyval(np.polyfit(mu[valid] / scale, r[valid], degree), mu / scale)
    return out


def light_field(stack: Stack, prediction, residuals, valid) -> np.ndarray:
    """Per light and channel, the least-squares fit of the residuals by prediction x (1, x, y, x^2, xy, y^2), x and
    y the pixel's position over the image's size: a smooth irradiance field per light."""
    x, z = stack.cols / stack.shape[1] - 0.5, stack.rows / stack.shape[0] - 0.5
    terms = np.stack([np.ones_like(x), x, z, x * x, x * z, z * z], axis=1)        # (P, 6)
    out = np.zeros_like(residuals)
    for light in range(residuals.shape[1]):
        keep = valid[:, light]
        for c in range(residuals.shape[2]):
            basis = terms * prediction[:, light, c][:, None]
            coef = np.linalg.lstsq(basis[keep], residuals[keep, light, c], rcond=None)[0]
            out[:, light, c] = basis @ coef
    return out


def white_noise_sd(stack: Stack, colour: bool) -> np.ndarray:
    """(C,) the white noise sd per channel: 1.4826 MAD / sqrt(6) of second differences along rows and columns.

    Three consecutive object pixels with valid observations under one light; a smooth signal's curvature
    over two pixels is small next to 8-bit or photon noise, so this estimates the noise, not the misfit.
    """
    dense = dense_values(stack, stack.values(colour))
    diffs = [dense[..., :, :-2] - 2 * dense[..., :, 1:-1] + dense[..., :, 2:],
             dense[..., :-2, :] - 2 * dense[..., 1:-1, :] + dense[..., 2:, :]]
    out = []
    for c in range(dense.shape[1]):
        d = np.concatenate([diff[:, c][np.isfinite(diff[:, c])] for diff in diffs])
        out.append(MAD_SD * np.median(np.abs(d - np.median(d))) / np.sqrt(6.0))
    return np.array(out)


def dense_values(stack: Stack, values, valid=None) -> np.ndarray:
    """(L, C, H, W) images of per-observation values (P, L, C); NaN off the object and where not valid."""
    valid = stack.valid if valid is None else valid
    out = np.full((values.shape[1], values.shape[2]) + tuple(stack.shape), np.nan)
    masked = np.where(valid[..., None], values, np.nan)
    out[:, :, stack.rows, stack.cols] = np.moveaxis(masked, 0, -1)
    return out


def standardised(residuals, labels, valid) -> np.ndarray:
    """Residuals (P, L, C) over 1.4826 MAD per material and channel (a robust sd); NaN where not valid."""
    out = np.full(residuals.shape, np.nan)
    for m in range(int(labels.max()) + 1):
        chosen = (labels == m)[:, None] & valid
        for c in range(residuals.shape[2]):
            r = residuals[..., c][chosen]
            out[..., c][chosen] = r / max(MAD_SD * np.median(np.abs(r - np.median(r))), 1e-300)
    return out


def correlation_row(stack: Stack, residuals, labels, valid, noise_sd) -> dict:
    """rho_rows, rho_cols, rho (their mean, >= 0), the implied power and the RMS residual over the noise sd."""
    dense = dense_values(stack, standardised(residuals, labels, valid), valid)
    (rho_rows, rho_cols), pairs = neighbour_correlations(dense)
    rho = max(0.0, float(np.nanmean([rho_rows, rho_cols])))
    # the same on residuals clipped at 3 robust sd: how much of rho a few large residuals (a highlight, a shadow) carry
    rho_clipped = max(0.0, float(np.nanmean(neighbour_correlations(np.clip(dense, -3.0, 3.0))[0])))
    profile = {lag: float(np.nanmean(neighbour_correlations(dense[..., ::lag, ::lag])[0])) for lag in (2, 4, 8)}
    rms = np.sqrt(np.mean((residuals / noise_sd)[valid] ** 2))
    return {"rho_rows": rho_rows, "rho_cols": rho_cols, "rho": rho, "power": ((1 - rho) / (1 + rho)) ** 2,
            "rho_clipped": rho_clipped, "rho_at_lag": profile, "pairs": pairs, "rms_over_noise": float(rms),
            "observations": int(valid.sum()) * residuals.shape[2]}


def shadow_mask(stack: Stack, normals, y) -> np.ndarray:
    """(P, L) observations in shadow: <l.n> below :data:`SHADOW_COS` for these normals (attached shadow), or
    darker than :data:`SHADOW_FRACTION` of the pixel's own Lambertian prediction (a cast shadow).

    The Lambertian albedo of a pixel is the median of y / (E <l.n>) over its valid lights with <l.n> > 0.3:
    the pixel's own other lights, not a fitted material, so the rule does not select on the model's residual.
    """
    geo = geometry(stack, normals)
    shading = geo["E"] * geo["ln"]
    mean = y.mean(axis=-1)
    lit = stack.valid & (geo["ln"] > 0.3)
    ratio = np.where(lit, mean / np.where(lit, shading, 1.0), np.nan)
    albedo = np.zeros(len(ratio))      # a pixel without such a light: no cast-shadow test (albedo 0)
    some = lit.any(axis=1)
    albedo[some] = np.nanmedian(ratio[some], axis=1)
    return (geo["ln"] < SHADOW_COS) | (mean < SHADOW_FRACTION * albedo[:, None] * shading)


def run_variant(stack: Stack, labels, variant: str, noise: dict, prior_rad: float, rounds: int = 2) -> dict:
    """Fit every material under ``variant`` (:data:`VARIANTS`); its row of figures (:func:`correlation_row`'s, the
    normal shifts, the shadows' share, the materials' fits and the profile log-likelihood)."""
    family, normals_free, colour, shadows, lights_free = VARIANTS[variant]
    y = stack.values(colour)
    noise_sd = noise["colour" if colour else "mono"]
    valid, normals, given = stack.valid, stack.normals, stack
    fits = fit_all(stack, normals, labels, family, y, valid)
    row = {}
    for _ in range(rounds if normals_free or lights_free else 0):
        if lights_free:
            stack, row["lights"] = refine_lights(given, normals, labels, fits, family, y, valid)
        if normals_free:
            normals = refine_normals(stack, stack.normals, labels, fits, family, y, valid, noise_sd, prior_rad)
        fits = fit_all(stack, normals, labels, family, y, valid)
    if shadows:
        dropped = shadow_mask(stack, normals, y) & valid
        before = standardised(y - predict(stack, normals, labels, fits, family), labels, valid)
        row.update(shadow_fraction=float(dropped.sum() / valid.sum()),
                   shadow_ssr_share=float(np.nansum(before[dropped] ** 2) / np.nansum(before[valid] ** 2)))
        valid = valid & ~dropped
        fits = fit_all(stack, normals, labels, family, y, valid)
        normals = refine_normals(stack, stack.normals, labels, fits, family, y, valid, noise_sd, prior_rad)
        fits = fit_all(stack, normals, labels, family, y, valid)
    residuals = y - predict(stack, normals, labels, fits, family)
    for _ in range(rounds if variant == "r" else 0):
        correction = response_correction(y - residuals, residuals, valid)
        fits = fit_all(stack, normals, labels, family, y - correction, valid)
        mu = predict(stack, normals, labels, fits, family)
        residuals = y - mu - response_correction(mu, y - mu, valid)
    if variant == "f":
        residuals = residuals - light_field(stack, y - residuals, residuals, valid)
    if variant == "p":
        mu = y - residuals
        gain = np.sum(np.where(valid[..., None], y * mu, 0.0), axis=1) / np.maximum(
            np.sum(np.where(valid[..., None], mu * mu, 0.0), axis=1), 1e-300)
        residuals = y - gain[:, None, :] * mu
    row.update(correlation_row(stack, residuals, labels, valid, noise_sd))
    if normals_free:
        shift = np.degrees(np.arccos(np.clip(np.sum(normals * stack.normals, axis=1), -1.0, 1.0)))
        row["normal_shift_deg"] = {q: float(np.percentile(shift, p)) for q, p in
                                   (("median", 50), ("p90", 90), ("p99", 99), ("max", 100))}
        row["normal_shift_rms_deg"] = float(np.sqrt(np.mean(shift ** 2)))
    row["materials"] = [{"shape": fit["shape"], "amplitudes": fit["coef"].T.tolist(), "ssr": fit["ssr"], "n": fit["n"]}
                        for fit in fits]
    # profile Gaussian log-likelihood, one variance per material and channel (up to a constant)
    row["log_likelihood"] = float(-sum(0.5 * fit["n"] * np.sum(np.log(np.asarray(fit["ssr"]) / fit["n"])) for fit in fits))
    return row


def albedo_kmeans(stack: Stack, k: int, seed: int, starts: int = 4) -> np.ndarray:
    """k-means (k clusters) of each pixel's Lambertian photometric-stereo RGB albedo, the best of ``starts``
    seeded starts by within-cluster sum of squares; labels ordered by the cluster's mean albedo (0 darkest)."""
    from rjfit.sampler.regions.materials.kmeans import standardised as standardise

    shading = stack.irradiance[None] * np.maximum(stack.normals @ stack.lights.T, 0.0) * stack.valid
    albedo = np.einsum("plc,pl->pc", stack.y, shading) / np.maximum(np.sum(shading ** 2, axis=1), 1e-300)[:, None]
    x = standardise(albedo)
    rng = np.random.default_rng(seed)
    best, best_ss = None, np.inf
    for _ in range(starts):
        labels = kmeans_labels(albedo, k, rng)
        ss = sum(np.sum((x[labels == j] - x[labels == j].mean(axis=0)) ** 2) for j in range(k))
        if ss < best_ss:
            best, best_ss = labels, ss
    order = np.argsort([albedo[best == j].mean() for j in range(k)])
    return np.argsort(order)[best]


def load_stack(path, max_view_angle: float, seed: int, cache: Path | None):
    """The calibrated stack (``calibrate_measured``, as ``--preset measured``; the rim beyond ``max_view_angle``
    left out) and the per-pixel rule's figures as the fit reports them; read from ``cache`` where present."""
    name = Path(path).name
    cached = None if cache is None else cache / f"{name}-{max_view_angle:g}-{seed}.npz"
    if cached is not None and cached.is_file():
        with np.load(cached, allow_pickle=False) as data:
            fields = {key: data[key] for key in data.files}
        reference = json.loads(str(fields.pop("reference")))
        fields["shape"] = tuple(int(v) for v in fields["shape"])
        return Stack(**fields), reference
    dataset, record = calibrate_measured(load_dataset(path, crop=True), "mean", seed)
    if max_view_angle < 90.0:
        dataset = dataclasses.replace(dataset, max_view_angle=max_view_angle)
    observations = dataset.observations("mean")
    reference = suggest_likelihood_power(observations, noise_scale(observations, "normals"))
    reference["kappa"] = record["response"]["kappa"] if record.get("response") else None
    stack = stack_from_dataset(dataset)
    if cached is not None:
        cache.mkdir(parents=True, exist_ok=True)
        temporary = cached.with_suffix(".tmp.npz")
        np.savez(temporary, reference=json.dumps(reference), **dataclasses.asdict(stack))
        temporary.replace(cached)
    return stack, reference


def largest_part(stack: Stack, chosen) -> np.ndarray:
    """(P,) bool: the largest 4-connected part of the chosen pixels."""
    image = np.zeros(stack.shape, bool)
    image[stack.rows, stack.cols] = chosen
    parts, _ = ndimage.label(image)
    sizes = np.bincount(parts.ravel())
    sizes[0] = 0
    return parts[stack.rows, stack.cols] == np.argmax(sizes)


def paint_evidence(stack: Stack, paint, variant: str, noise: dict, prior_rad: float, power: float) -> dict:
    """Log-likelihood gain of the ``paint`` pixels (P,) as a material of their own (against one material) under
    ``variant``, the same times the likelihood power ``power`` (what a coarsened fit weighs), and the Potts
    prior's cost of its outline at the measured preset's beta (:func:`ghost_material_prior`)."""
    one = run_variant(stack, np.zeros(paint.size, int), variant, noise, prior_rad)
    two = run_variant(stack, paint.astype(int), variant, noise, prior_rad)
    gain = two["log_likelihood"] - one["log_likelihood"]
    image = np.full(stack.shape, -1)
    image[stack.rows, stack.cols] = paint
    outline = sum(int(np.sum((a >= 0) & (b >= 0) & (a != b))) for a, b in
                  ((image[:, :-1], image[:, 1:]), (image[:-1, :], image[1:, :])))
    beta = ghost_material_prior(image >= 0, 3.0)[0]
    return {"variant": variant, "pixels": int(paint.sum()), "log_likelihood_gain": gain, "power": power,
            "weighted_gain": gain * power, "outline_pairs": outline, "potts_beta": beta, "potts_cost": beta * outline}


def summarise(path) -> str:
    """The rows of a JSON-lines file as a Markdown table (stack, segmentation, variant, rho, power, RMS / noise)."""
    lines = ["| stack | segmentation | variant | rho (rows / cols) | rho clipped | rho at lag 2 / 4 / 8 | power | "
             "RMS / noise | normal shift median / p90 (deg) |", "|" + " --- |" * 9]
    for row in (json.loads(line) for line in open(path)):
        if "rho" not in row:
            continue
        lag = row.get("rho_at_lag") or {}
        shift = row.get("normal_shift_deg")
        lines.append(" | ".join([
            f"| {row['stack']}", row["segmentation"], row["variant"],
            f"{row['rho']:.3f} ({row['rho_rows']:.3f} / {row['rho_cols']:.3f})",
            f"{row['rho_clipped']:.3f}" if "rho_clipped" in row else "",
            " / ".join(f"{lag[k]:.2f}" for k in ("2", "4", "8")) if lag else "",
            f"{row['power']:.4f}", f"{row['rms_over_noise']:.2f}" if "rms_over_noise" in row else "",
            f"{shift['median']:.1f} / {shift['p90']:.1f}" if shift else ""]) + " |")
    return "\n".join(lines)


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("stack", nargs="?", help="a photometric-stereo folder (e.g. /work/shared/data/psm-cat)")
    parser.add_argument("--summarise", type=Path, default=None,
                        help="print the rows of this JSON-lines file as a Markdown table and stop")
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS),
                        help="which variants to fit (the module docstring names them)")
    parser.add_argument("--kmeans", nargs="*", type=int, default=[],
                        help="also fit the segmentations of k-means on the pixels' RGB albedo with these k")
    parser.add_argument("--kmeans-variants", nargs="+", default=["a", "b", "c", "bc", "bce"], choices=list(VARIANTS),
                        help="the variants fitted on the k-means segmentations")
    parser.add_argument("--paint-cluster", type=int, default=None,
                        help="with --kmeans: the evidence for this cluster (0 is the darkest) of the largest k as a "
                             "material of its own, at variant a and at the variant of the highest power")
    parser.add_argument("--paint-part", action="store_true",
                        help="with --paint-cluster: the evidence for the cluster's largest connected part only")
    parser.add_argument("--normal-prior-deg", type=float, default=3.0,
                        help="sd (degrees) of the Gaussian prior of a pixel's normal about the given one")
    parser.add_argument("--max-view-angle", type=float, default=72.5,
                        help="leave out pixels seen further than this from their normal (the measured preset's rim)")
    parser.add_argument("--seed", type=int, default=1, help="seeds the calibration's bootstrap and the k-means starts")
    parser.add_argument("--cache", type=Path, default=None, help="folder keeping the calibrated stacks between runs")
    parser.add_argument("--out", type=Path, help="JSON-lines file the rows are appended to")
    args = parser.parse_args(argv)
    if args.summarise is None and (args.stack is None or args.out is None):
        parser.error("give a stack and --out (or --summarise FILE)")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.summarise is not None:
        print(summarise(args.summarise))
        return 0
    start = time.time()
    try:
        stack, reference = load_stack(args.stack, args.max_view_angle, args.seed, args.cache)
    except (OSError, ValueError) as error:
        print(str(error), file=sys.stderr)      # the loaders name the folder
        return 2
    noise = {"mono": white_noise_sd(stack, False), "colour": white_noise_sd(stack, True)}
    prior = np.radians(args.normal_prior_deg)
    base = {"stack": Path(args.stack).name, "max_view_angle": args.max_view_angle, "pixels": int(stack.rows.size),
            "noise_sd": {key: value.tolist() for key, value in noise.items()}, "normal_prior_deg": args.normal_prior_deg}
    rows = [{**base, "segmentation": "per-pixel", "variant": "pp", "rho": reference["rho"],
             "rho_rows": reference["rho_rows"], "rho_cols": reference["rho_cols"],
             "power": reference["likelihood_power"], "kappa": reference["kappa"]}]
    segmentations = [("one", np.zeros(stack.rows.size, int), args.variants)]
    segmentations += [(f"kmeans{k}", albedo_kmeans(stack, k, args.seed), args.kmeans_variants) for k in args.kmeans]
    for name, labels, variants in segmentations:
        for variant in variants:
            began = time.time()
            row = run_variant(stack, labels, variant, noise, prior)
            rows.append({**base, "segmentation": name, "variant": variant, "K": int(labels.max()) + 1,
                         "sizes": np.bincount(labels).tolist(), "seconds": round(time.time() - began, 1), **row})
            print(f"{rows[-1]['stack']} {name} {variant}: rho {row['rho']:.3f} power {row['power']:.4f} "
                  f"rms/noise {row['rms_over_noise']:.2f} ({rows[-1]['seconds']} s)", flush=True)
    if args.paint_cluster is not None and args.kmeans:
        paint = segmentations[-1][1] == args.paint_cluster
        paint = largest_part(stack, paint) if args.paint_part else paint
        one = [row for row in rows if row["segmentation"] == "one"]
        best = max((row for row in one if row["variant"] in PARTS), key=lambda row: row["power"])
        for row in (next(row for row in one if row["variant"] == "a"), best):
            evidence = {"cluster": args.paint_cluster, "largest_part": args.paint_part,
                        **paint_evidence(stack, paint, row["variant"], noise, prior, row["power"])}
            rows.append({**base, "segmentation": segmentations[-1][0], "variant": row["variant"], "evidence": evidence})
            print(f"evidence of cluster {args.paint_cluster} under {row['variant']}: {evidence}", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "a") as handle:
        handle.writelines(json.dumps(row) + "\n" for row in rows)
    print(f"{len(rows)} rows appended to {args.out} ({time.time() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
