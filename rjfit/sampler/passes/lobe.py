"""The lobe column of a problem with effects: per-observation terms that make B other than ``C <h.n>^gamma``.

The plain model's lobe column is ``B_i(g) = C_i <h.n>_i^g`` with the same ``C`` as the
diffuse column ``A_i = C_i / pi``. Effects inside the fit (issue 26,
:mod:`rjfit.effects`, each effect's fit form) make it

    B_i(g) = CB_i ((1 - u) <h.n>_i^g + u f_GGX,i(alpha(g)) / N(g)) M_i(g) + (second_i + amb_i alb(g, v_i)) / N(g)

- ``CB``: the lobe's own ``C`` (Fresnel multiplies the lobe only, so ``CB != C``);
- ``u``, ``f_GGX``: a GGX microfacet lobe mixed into the Blinn lobe (:mod:`rjfit.effects.ggx`;
  ``u = 0``: none), its roughness the region's ``alpha(g) = sqrt(2 / (g + 2))``, its
  <h.n>^2 ``exp(2 log <h.n>)``;
- ``M_i(g) = (1 - w) + w G1(tan v_i, alpha(g)) G1(tan l_i, alpha(g))``: Smith-Beckmann
  shadowing / masking with the roughness of the region's gamma (``w = 0``: none);
- ``second_i = C_i v f_GGX,i(alpha2)``: a second lobe of global weight and roughness
  (:mod:`rjfit.effects.second_lobe`; computed with the effect's parameters, empty: none);
- ``amb_i alb(g, v_i) / N(g)``: the lobe's share of ambient light, its directional albedo
  interpolated in the table of :func:`rjfit.effects.ambient.albedo_table` (``amb`` empty: none).

A :class:`LobeTerms` holds those terms, in the problem's observation order; the problem
carries it as ``Problem.lobe`` (None for the plain model). Every compiled pass takes it as
its last argument: Numba compiles the pass once for ``None``, where the branches on it are
pruned at compile time (the plain model's machine code, bits and speed are those it had),
and once for a :class:`LobeTerms`. The gamma-dependent parts are evaluated per region once
per pass (:func:`lobe_rows`: the roughness, the albedo row over the view angles divided by
N(g), and 1 / N(g)), then per observation (:func:`lobe_scalar`, for a run of observations :func:`lobe_fill`).

The Newton gamma move's derivative sums weight B by ``log <h.n>`` (``dB/dg = B log <h.n>``,
exact for the plain lobe); with masking or ambient light that is an approximation of the
derivative, used only to place the proposal, whose density both ways the acceptance ratio
holds: the move stays exact.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from rjfit.effects.ggx import LOG_COS_H_ZERO, ggx_scalar
from rjfit.effects.masking import g1_tan
from rjfit.sampler.passes.special import fast_exp

__all__ = ["LobeTerms", "lobe_rows", "lobe_row", "lobe_scalar", "lobe_fill", "lobe_at", "plain_lobe_terms"]


class LobeTerms(NamedTuple):
    """The lobe column's terms of a problem with effects (module docstring), flat over observations.

    Parts an effect does not use are empty arrays (``mask_w`` 0), so every problem with
    effects has the same types and the passes compile once for all of them.
    """

    cb: np.ndarray          # float32 (N,): the lobe's C (divided by the noise scale like C)
    mask_w: float           # shadowing / masking weight w (0: none)
    tan_v: np.ndarray       # float32 (N,) or (0,): tan of the view angle
    tan_l: np.ndarray       # float32 (N,) or (0,): tan of the light angle
    amb: np.ndarray         # float32 (N,) or (0,): ambient radiance a / s_i (empty: no ambient light)
    amb_j: np.ndarray       # int32 (N,) or (0,): albedo table column below the view angle
    amb_fy: np.ndarray      # float32 (N,) or (0,): weight of the column above
    table: np.ndarray       # float64 (G, J): the albedo table (rows: log gamma)
    grid: np.ndarray        # float64 (3,): the table's lowest and highest log gamma, and its step
    ggx_w: float = 0.0      # weight u of the GGX lobe in the mix (0: none); uses tan_v, tan_l
    second: np.ndarray = np.zeros(0, np.float32)    # float32 (N,) or (0,): C v f_GGX(alpha2) / s (empty: none)

    def take(self, idx) -> LobeTerms:
        """The terms of the observations ``idx`` (gathered, in that order)."""
        def part(values):
            return values[idx] if values.shape[0] else values
        return self._replace(cb=self.cb[idx], tan_v=part(self.tan_v), tan_l=part(self.tan_l), amb=part(self.amb),
                             amb_j=part(self.amb_j), amb_fy=part(self.amb_fy), second=part(self.second))


def plain_lobe_terms(cb) -> LobeTerms:
    """Terms with only a lobe column of its own (no masking, no GGX, no ambient light, no second lobe)."""
    empty32 = np.zeros(0, np.float32)
    return LobeTerms(cb=np.asarray(cb, np.float32), mask_w=0.0, tan_v=empty32, tan_l=empty32, amb=empty32,
                     amb_j=np.zeros(0, np.int32), amb_fy=empty32, table=np.zeros((2, 2)),
                     grid=np.array([0.0, 1.0, 1.0]), ggx_w=0.0, second=empty32)


@njit(cache=True, nogil=True)
def lobe_rows(ext, gammas):
    """Per region (R, 2 + J): the Beckmann roughness ``alpha(g)``, the albedo row over the view angles / N(g)
    and, last, 1 / N(g).

    None for the plain model (``ext`` None). The albedo row is the table interpolated
    linearly in log gamma (clipped to the table), as :func:`rjfit.effects.ambient.albedo_rows`.
    """
    if ext is None:
        return None
    n_cols = ext.table.shape[1]
    out = np.zeros((gammas.shape[0], 2 + n_cols))
    for r in range(gammas.shape[0]):
        g = gammas[r]
        out[r, 0] = math.sqrt(2.0 / (g + 2.0))
        # Giesen's normalisation, as rjfit.model.blinn.blinn_normalisation (not callable from Numba)
        norm = (g + 2.0) * (g + 4.0) / (8.0 * math.pi * (2.0 ** (-g / 2.0) + g))
        out[r, 1 + n_cols] = 1.0 / norm
        if ext.amb.shape[0] > 0:
            x = (min(max(math.log(g), ext.grid[0]), ext.grid[1]) - ext.grid[0]) / ext.grid[2]
            i = min(int(x), ext.table.shape[0] - 2)
            fx = x - i
            for j in range(n_cols):
                out[r, 1 + j] = ((1.0 - fx) * ext.table[i, j] + fx * ext.table[i + 1, j]) / norm
    return out


@njit(cache=True, nogil=True)
def lobe_row(ext, gamma):
    """:func:`lobe_rows` of one exponent: (2 + J,), or None for the plain model."""
    if ext is None:
        return None
    return lobe_rows(ext, np.full(1, gamma))[0]


@njit(inline="always")
def lobe_scalar(cb, lh, g, w, tan_v, tan_l, alpha, amb, fy, albedo_j, albedo_next, u, inv_norm, second):
    """``B`` of one observation from its terms (scalars only: an inlined function that takes arrays
    costs a reference count per array and call, ten times the arithmetic).

    ``cb``, ``lh``: its lobe C and log <h.n>; ``g``, ``alpha``, ``inv_norm``: its region's exponent,
    roughness and 1 / N(g); ``w``, ``tan_v``, ``tan_l``: masking (w = 0: none); ``u``: the GGX
    mix's weight (0: none); ``amb``, ``fy``, ``albedo_j``, ``albedo_next``: its ambient radiance,
    view-angle weight and the region's albedo row (/ N(g)) at its two columns (amb = 0: none,
    adds 0); ``second``: its second lobe's ``C v f_GGX(alpha2)`` (0: none).
    """
    b = cb * fast_exp(g * lh)
    if u != 0.0:
        cos2_h = fast_exp(2.0 * lh) if lh > LOG_COS_H_ZERO else 0.0
        b = (1.0 - u) * b + u * (cb * (ggx_scalar(cos2_h, tan_v, tan_l, alpha) * inv_norm))
    if w != 0.0:
        b *= (1.0 - w) + w * (g1_tan(tan_v, alpha) * g1_tan(tan_l, alpha))
    b += second * inv_norm
    return b + amb * ((1.0 - fy) * albedo_j + fy * albedo_next)


@njit(cache=True, nogil=True, fastmath={"contract"})
def lobe_fill(ext, offset, log_cos_hn, g, row, out):
    """``out[k] = B_(offset + k)(g)`` for ``k < len(out)`` (``log_cos_hn[k]`` that observation's log <h.n>, ``row``
    its region's :func:`lobe_rows` row): the lobe column of a run of observations, for the passes to sum.

    One loop per term, each without branches or gathers where it can (the power and the
    masking factor vectorise), with the operations of :func:`lobe_scalar` in its order.
    """
    m = out.shape[0]
    cb = ext.cb[offset:offset + m]
    for k in range(m):
        out[k] = np.float64(cb[k]) * fast_exp(g * np.float64(log_cos_hn[k]))
    alpha, inv_norm = row[0], row[row.shape[0] - 1]
    u = ext.ggx_w
    if u != 0.0:
        tan_v, tan_l = ext.tan_v[offset:offset + m], ext.tan_l[offset:offset + m]
        for k in range(m):
            lh = np.float64(log_cos_hn[k])
            cos2_h = fast_exp(2.0 * lh) if lh > LOG_COS_H_ZERO else 0.0
            ggx = ggx_scalar(cos2_h, np.float64(tan_v[k]), np.float64(tan_l[k]), alpha)
            out[k] = (1.0 - u) * out[k] + u * (np.float64(cb[k]) * (ggx * inv_norm))
    w = ext.mask_w
    if w != 0.0:
        tan_v, tan_l = ext.tan_v[offset:offset + m], ext.tan_l[offset:offset + m]
        for k in range(m):
            out[k] *= (1.0 - w) + w * (g1_tan(np.float64(tan_v[k]), alpha) * g1_tan(np.float64(tan_l[k]), alpha))
    if ext.second.shape[0] != 0:
        second = ext.second[offset:offset + m]
        for k in range(m):
            out[k] += np.float64(second[k]) * inv_norm
    if ext.amb.shape[0] != 0:
        amb, fys, cols = ext.amb[offset:offset + m], ext.amb_fy[offset:offset + m], ext.amb_j[offset:offset + m]
        for k in range(m):
            j, fy = cols[k], np.float64(fys[k])
            out[k] = out[k] + np.float64(amb[k]) * ((1.0 - fy) * row[1 + j] + fy * row[2 + j])


@njit(cache=True, nogil=True)
def lobe_at(ext, idx, log_cos_hn, gammas, rows, regions, out):
    """``out[k] = B_(idx[k])`` in region ``regions[k]`` (its exponent ``gammas[r]``, its ``rows[r]``): the lobe
    column of scattered observations, each in a region of its own (the element moves' observations)."""
    w, u = ext.mask_w, ext.ggx_w
    has_ambient = ext.amb.shape[0] != 0
    has_second = ext.second.shape[0] != 0
    last = rows.shape[1] - 1
    for k in range(out.shape[0]):
        i, r = idx[k], regions[k]
        tan_v = tan_l = amb = fy = second = 0.0
        j = 0
        if w != 0.0 or u != 0.0:
            tan_v, tan_l = np.float64(ext.tan_v[i]), np.float64(ext.tan_l[i])
        if has_ambient:
            amb, fy, j = np.float64(ext.amb[i]), np.float64(ext.amb_fy[i]), ext.amb_j[i]
        if has_second:
            second = np.float64(ext.second[i])
        out[k] = lobe_scalar(np.float64(ext.cb[i]), np.float64(log_cos_hn[i]), gammas[r], w, tan_v, tan_l,
                             rows[r, 0], amb, fy, rows[r, 1 + j], rows[r, 2 + j], u, rows[r, last], second)
