"""A light's gain as a smooth field over the image: the exponential of a low-order polynomial in image coordinates.

An uncalibrated rig's lights do not light the object evenly: a lamp's distance, its beam and its
angle change each light's irradiance over the image, each light in its own way. On the three psm
stacks (one rig), two lights 9.4 deg apart give the top of the object the ratio their shading
predicts and its bottom one 15 to 30 % darker under the second, a gradient down the image on
every object (docs/results/2026-11-29-light-field.md): no reflectance does that.

The field of light ``l`` at pixel (row, column) is ``exp(sum_j c[l, j] phi_j(u, v))`` with the
monomials ``u^a v^b`` (a + b <= degree) of ``u = (column - (W - 1) / 2) / ((W - 1) / 2)`` and
``v = (row - (H - 1) / 2) / ((H - 1) / 2)``; degree 0 is one gain per light. A field common to
every light is the object's albedo (or I0), so the coefficients of each monomial sum to 0 over
the lights: the fields' geometric mean over the lights is 1 at every pixel. Why a polynomial and
not a free field: a field free at each place can trade with the reflectance fitted there (a
field on nodes 32 px apart, estimated with 5 x 5 tile fits, drifted from a constant truth by
7 % rms on a rendered sphere); a polynomial spans the whole object, whose many normals a
reflectance cannot follow with one pattern over the lights.
"""
from __future__ import annotations

import numpy as np

__all__ = ["monomials", "field_basis", "field_image", "field_extent", "robust_polynomial", "BIWEIGHT_C"]

#: Tukey's biweight tuning constant (95 % efficiency under Gaussian errors)
BIWEIGHT_C = 4.685
#: Huber's (95 % efficiency), for the biweight's start
HUBER_C = 1.345
_IRLS_ROUNDS = 50


def monomials(degree: int) -> list[tuple[int, int]]:
    """The exponents (a, b) of ``u^a v^b``, a + b <= ``degree``: 1, u, v, u^2, u v, v^2, ..."""
    if degree < 0:
        raise ValueError(f"a light field's degree is 0 or more, not {degree}")
    return [(total - b, b) for total in range(degree + 1) for b in range(total + 1)]


def field_basis(pixel, image_shape, degree: int) -> np.ndarray:
    """The monomials at flat pixel indices ``pixel``, (n, n_terms), in the module docstring's coordinates."""
    pixel = np.asarray(pixel, np.int64)
    height, width = image_shape
    u = (pixel % width - (width - 1) / 2) / max((width - 1) / 2, 1)
    v = (pixel // width - (height - 1) / 2) / max((height - 1) / 2, 1)
    return np.stack([u ** a * v ** b for a, b in monomials(degree)], axis=1)


def field_image(coefficients, image_shape, degree: int) -> np.ndarray:
    """Every light's field at every pixel, (L, H, W), from ``coefficients`` (L, n_terms)."""
    coefficients = np.asarray(coefficients, float)
    height, width = image_shape
    basis = field_basis(np.arange(height * width), image_shape, degree)
    return np.exp(coefficients @ basis.T).reshape(len(coefficients), height, width)


def field_extent(record: dict) -> tuple[float, float]:
    """The smallest and largest gain over the object of a recorded field (``range``: one pair per light, or one
    pair for the common field)."""
    pairs = np.asarray(record["range"], float).reshape(-1, 2)
    return float(pairs[:, 0].min()), float(pairs[:, 1].max())


def robust_polynomial(values, basis) -> tuple[np.ndarray, np.ndarray, float]:
    """A least-squares fit of ``values`` on ``basis`` (n, n_terms), robust to a minority of other values: Tukey's
    biweight by iteratively reweighted least squares, started from Huber's (whose weights are never 0, so it
    moves off the plain fit however far a minority pulls that), the scale the residuals' MAD.

    Returns
    -------
    (ndarray, ndarray, float)
        The coefficients, each value's final weight (0: an outlier) and the scale.
    """
    values, basis = np.asarray(values, float), np.asarray(basis, float)
    weights, coefficients, scale = np.ones(values.size), None, 0.0
    for weight in (_huber, _biweight):
        for _ in range(_IRLS_ROUNDS):
            weighted = basis * weights[:, None]
            coefficients = np.linalg.solve(weighted.T @ basis, weighted.T @ values)
            residual = values - basis @ coefficients
            scale = 1.4826 * float(np.median(np.abs(residual - np.median(residual))))
            if scale <= 0:
                return coefficients, weights, scale
            new = weight(residual / scale)
            converged = np.max(np.abs(new - weights)) < 1e-6
            weights = new
            if converged:
                break
    return coefficients, weights, scale


def _huber(u):
    return np.minimum(1.0, HUBER_C / np.maximum(np.abs(u), 1e-300))


def _biweight(u):
    u = u / BIWEIGHT_C
    return np.where(np.abs(u) < 1, (1 - u * u) ** 2, 0.0)
