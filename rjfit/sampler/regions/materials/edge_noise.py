"""How noisy the edge term's differences are, pair by pair: a variance that grows with what changes across a pair,
measured once per fit on the data (:mod:`rjfit.sampler.regions.materials.edges`, "The differences' noise").

Why
---
The term compares each pair's data difference with the materials' predicted step on one noise scale. On measured
stacks the differences' misfit under one material is far from homoscedastic: in the tenth of matches where the
shading changes most across the pair, its robust variance is 11 (psm-horse), 33 (psm-cat) and 2.6 (psm-rock) times
that of the tenth where it changes least, and where the geometry turns fast across the pair (the given normals'
error, a lobe shape the model lacks and light from nearby surfaces all change fastest there) 1.2 to 10 times more
again. On one scale, the pairs beside occluding contours and folds weigh as much as a flat paint outline's, and
psm-horse's folds became materials of their own (docs/results/2026-11-29-edge-noise.md).

The model
---------
Each match's difference, on its channel's scale (``z``: the reference's misfit divided by the term's robust
spread ``s_c``), has the variance

    v = a + b g^2 + c t^2,

``g`` the reference's predicted difference across the pair under that light on the same scale (how much the shading
changes), ``t`` the pair's turn: the root mean square over its matched lights of the change of ``<h.n>`` between its
ends (how much the geometry turns as the lights see it; it follows the given normals' angle across the pair, at a
correlation of 0.73 to 0.77 on the shared stacks, and needs no normals beyond the problem's own columns). ``a``,
``b``, ``c`` >= 0 are fitted by non-negative least squares to the robust variances (1.4826 MAD, squared) of ``z`` in
:data:`CELLS` x :data:`CELLS` cells of the quantiles of ``|g|`` and ``t``: robust, so a paint's outline (a small
share of any cell) does not widen them; then again, up to :data:`FIT_ROUNDS` times, on ``z`` over the last fit's sd
(times that variance's mean in the cell), which is unbiased where the model holds. A surface whose misfit is white
gives ``b = c = 0`` and ``a`` near 1: the term of one scale.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import nnls

from rjfit.sampler.regions.materials.edge_gain import robust_sd

__all__ = ["difference_noise", "match_variance", "pair_turn", "valid_noise", "CELLS", "MIN_CELL_MATCHES",
           "MIN_WHITE", "FIT_ROUNDS"]

#: quantile cells per feature (|g|, t) in which the variance is read
CELLS = 10
#: a cell with fewer matches is left out of the fit (its robust variance is itself too noisy)
MIN_CELL_MATCHES = 50
#: at most this many fits, each on the misfits over the last fit's sd (:func:`difference_noise`)
FIT_ROUNDS = 10
#: the least white part ``a`` kept, relative to the term's robust spread squared: no match weighs more than this
#: many times a typical one (a rendered surface without noise would fit ``a`` near 0)
MIN_WHITE = 0.1


def pair_turn(log_cos_hn_first, log_cos_hn_second, pair, n_pairs: int) -> np.ndarray:
    """(P,) each pair's turn ``t`` (module docstring): the root mean square over its matches (``pair``: each match's
    pair) of the change of ``<h.n>`` between its ends; 0 for a pair without matches."""
    change = np.exp(np.asarray(log_cos_hn_first, np.float64)) - np.exp(np.asarray(log_cos_hn_second, np.float64))
    total = np.bincount(pair, change * change, minlength=n_pairs)
    count = np.bincount(pair, minlength=n_pairs)
    return np.sqrt(total / np.maximum(count, 1))


def difference_noise(z, shading_change, turn) -> dict:
    """The coefficients of ``v = a + b g^2 + c t^2`` (module docstring) fitted to the standardised misfits ``z``
    of the matches, with each match's ``shading_change`` (g, on z's scale) and ``turn`` (t).

    Returns ``{"white": a, "shading": b, "turn": c, "floored": bool}``; ``floored``: ``a`` was raised to
    :data:`MIN_WHITE` (a caveat to state). ``{"white": 1, "shading": 0, "turn": 0}`` where fewer than three cells
    hold enough matches.

    Raises
    ------
    ValueError
        If the three arrays differ in length.
    """
    z, g, t = (np.asarray(a, np.float64) for a in (z, shading_change, turn))
    if not z.shape == g.shape == t.shape:
        raise ValueError(f"difference_noise needs one shading change and one turn per match, got {z.shape}, "
                         f"{g.shape} and {t.shape}")
    cells = []
    if z.size >= MIN_CELL_MATCHES * 3:
        cell = _quantile_cell(np.abs(g)) * CELLS + _quantile_cell(t)
        order = np.argsort(cell, kind="stable")
        bounds = np.searchsorted(cell[order], np.arange(CELLS * CELLS + 1))
        cells = [order[lo:hi] for lo, hi in zip(bounds[:-1], bounds[1:]) if hi - lo >= MIN_CELL_MATCHES]
    if len(cells) < 3:
        return {"white": 1.0, "shading": 0.0, "turn": 0.0, "floored": False}
    rows = np.array([[1.0, np.mean(g[m] ** 2), np.mean(t[m] ** 2)] for m in cells])
    variance = np.ones(z.size)
    coefficients = np.zeros(3)
    for _ in range(FIT_ROUNDS):
        # a cell's robust variance of z itself understates its mean variance where that varies inside the cell (a
        # scale mixture has heavier tails than its mean's Gaussian: 7 to 13 % on the coefficients of a simulated
        # model); of z over the model's sd it is 1 where the model holds, so the fit is repeated on those
        cell_variance = [robust_sd(z[m] / np.sqrt(variance[m])) ** 2 * np.mean(variance[m]) for m in cells]
        new = nnls(rows, np.array(cell_variance))[0]
        done = np.allclose(new, coefficients, rtol=1e-3, atol=1e-9)
        coefficients = new
        variance = np.maximum(match_variance(coefficients, g, t), MIN_WHITE)
        if done:
            break
    white, shading, turned = (float(c) for c in coefficients)
    return {"white": max(white, MIN_WHITE), "shading": shading, "turn": turned, "floored": white < MIN_WHITE}


def match_variance(coefficients, shading_change, turn) -> np.ndarray:
    """Each match's variance ``a + b g^2 + c t^2`` on the standardised scale (``coefficients``: ``(a, b, c)``, as
    :func:`difference_noise` fits them)."""
    white, shading, turned = coefficients
    g, t = np.asarray(shading_change, np.float64), np.asarray(turn, np.float64)
    return white + shading * g * g + turned * t * t


def valid_noise(noise) -> bool:
    """Whether ``noise`` is an edge term's noise setting: 'constant', 'measured', or ``(white, shading, turn)``,
    finite, >= 0, white > 0."""
    if isinstance(noise, str):
        return noise in ("constant", "measured")
    try:
        values = [float(c) for c in noise]
    except (TypeError, ValueError):
        return False
    return len(values) == 3 and all(np.isfinite(values)) and min(values) >= 0 and values[0] > 0


def _quantile_cell(x) -> np.ndarray:
    """Each value's cell among :data:`CELLS` cells of equal counts (ties share a cell)."""
    edges = np.quantile(x, np.linspace(0.0, 1.0, CELLS + 1)[1:-1])
    return np.searchsorted(edges, x, side="right")
