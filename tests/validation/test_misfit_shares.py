"""validation/misfit_shares.py's core: the per-pixel normal refinement and the lag-1 correlation, on a stack built here.

The stack: a 40 x 40 px sphere (about 1,250 object pixels) under 12 directional lights, one Lambert +
Blinn material (kd 0.7, exponent 30), radiance with white noise of sd 0.002 (0.5 % of the mean value).
The given normals are the true ones turned by planted tangential errors of sd 3 deg per axis.
"""
from __future__ import annotations

import numpy as np
import pytest

from builders import validation_script
from rjfit.model.blinn import radiance


SCRIPT = validation_script("misfit_shares")
PLANTED_DEG = 3.0
NOISE = 0.002


def _turned(normals, sd_deg, rng):
    first, second = SCRIPT.tangents(normals)
    angles = rng.normal(0.0, np.radians(sd_deg), (len(normals), 2))
    turned = normals + angles[:, :1] * first + angles[:, 1:] * second
    return turned / np.linalg.norm(turned, axis=1, keepdims=True)


def _stack(rng, given, true):
    """The sphere's Stack with ``given`` normals and radiance rendered at the ``true`` ones."""
    size = 40
    rows, cols = np.nonzero(np.hypot(*np.mgrid[-1:1:size * 1j, -1:1:size * 1j]) < 0.9)
    tilt = np.radians(np.linspace(15.0, 50.0, 12))
    azimuth = np.linspace(0.0, 2 * np.pi, 12, endpoint=False)
    lights = np.column_stack([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), np.cos(tilt)])
    view = np.tile([0.0, 0.0, 1.0], (rows.size, 1))
    half = lights[None] + view[:, None]
    half /= np.linalg.norm(half, axis=-1, keepdims=True)
    cos_ln, cos_hn = true @ lights.T, np.einsum("plk,pk->pl", half, true)
    y = radiance(1.0, 0.7, 30.0, cos_ln, cos_hn, 1.0) + rng.normal(0.0, NOISE, cos_ln.shape)
    return SCRIPT.Stack(y=np.repeat(y[..., None], 3, axis=-1), valid=(cos_ln > 0.05) & (given @ lights.T > 0.05),
                        normals=given, view=view, lights=lights, irradiance=np.ones(12), half=half, rows=rows,
                        cols=cols, shape=(size, size))


def _sphere_normals():
    size = 40
    yy, xx = np.mgrid[-1:1:size * 1j, -1:1:size * 1j]
    inside = np.hypot(xx, yy) < 0.9
    x, y = xx[inside], -yy[inside]
    return np.column_stack([x, y, np.sqrt(1.0 - x * x - y * y)])


def _angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=1), -1.0, 1.0)))


def test_the_normal_refinement_recovers_planted_normal_errors():
    """Planted errors of 3 deg sd per axis (median 3.5 deg) shrink to a median under 0.5 deg.

    Why 0.5 deg: at noise sd 0.002 and a shading gradient of about 0.2 per radian over 12 lights, a
    normal's posterior sd is about 0.002 / (0.2 sqrt(12)) = 0.003 rad = 0.17 deg per axis (median
    angle about 0.2 deg); the prior (sd 10 deg, wide) pulls by (0.17 / 10)^2, nothing; the material's
    fit on the wrong normals (refitted after one refinement) adds a small bias. 0.5 deg is under a
    seventh of the planted errors, so a refinement that did nothing, or moved normals the wrong
    way, fails.
    """
    rng = np.random.default_rng(3)
    true = _sphere_normals()
    given = _turned(true, PLANTED_DEG, rng)
    stack = _stack(rng, given, true)
    labels = np.zeros(len(given), int)
    y = stack.values(False)
    fits = SCRIPT.fit_all(stack, given, labels, "blinn", y, stack.valid)
    refined = SCRIPT.refine_normals(stack, given, labels, fits, "blinn", y, stack.valid, np.array([NOISE]),
                                    np.radians(10.0))
    fits = SCRIPT.fit_all(stack, refined, labels, "blinn", y, stack.valid)
    refined = SCRIPT.refine_normals(stack, given, labels, fits, "blinn", y, stack.valid, np.array([NOISE]),
                                    np.radians(10.0))
    before, after = np.median(_angle_deg(given, true)), np.median(_angle_deg(refined, true))
    assert before > 3.0, before
    assert after < 0.5, (before, after)


def test_the_lag1_correlation_of_white_noise_residuals_is_near_zero():
    """Residuals of white noise: each rho is Pearson's r of about 2,400 pairs per light over 12 lights, sd
    1 / sqrt(pairs) = 0.006; the tolerance is 4 sd (a false failure about once in 16,000 runs)."""
    rng = np.random.default_rng(5)
    true = _sphere_normals()
    stack = _stack(rng, true, true)
    labels = np.zeros(len(true), int)
    y = stack.values(False)
    fits = SCRIPT.fit_all(stack, true, labels, "blinn", y, stack.valid)
    residuals = y - SCRIPT.predict(stack, true, labels, fits, "blinn")
    row = SCRIPT.correlation_row(stack, residuals, labels, stack.valid, np.array([NOISE]))
    tolerance = 4.0 / np.sqrt(row["pairs"] / 2)
    assert abs(row["rho_rows"]) < tolerance and abs(row["rho_cols"]) < tolerance, (row, tolerance)
    assert row["rms_over_noise"] == pytest.approx(1.0, abs=0.05)     # the fit reaches the noise (3 parameters)
    # the second differences' estimate is an upper bound: the signal's curvature over two pixels adds to it
    # (the highlight on a 40 px sphere: 0.0025 measured); noise alone gives NOISE within about 2 %
    assert NOISE * 0.95 < SCRIPT.white_noise_sd(stack, False)[0] < NOISE * 1.4
