"""Compiled passes of the sampled normals (:mod:`rjfit.sampler.normals`): the columns at turned normals, and the
per-pixel Metropolis sweep.

A pixel's normal is ``n' = (n + dx t1 + dy t2) / sqrt(1 + dx^2 + dy^2)``, ``(t1, t2)`` the tangent frame of its
given normal n, so with the observation's ``(l.t1, l.t2, h.t1, h.t2)`` (``tangent``)

    <l.n'> = (<l.n> + dx l.t1 + dy l.t2) / sqrt(1 + dx^2 + dy^2),   <h.n'> likewise,

and the problem's columns at n' are ``C' = C <l.n'> / <l.n>`` (E / s unchanged) and ``log <h.n'>``, both rounded to
float32 as the problem stores them (:func:`turned`): the sweep's target and the statistics the region moves see
are computed from the same numbers.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from rjfit.sampler.passes.densities import coefficients

__all__ = ["turned", "normal_columns", "normal_sweep"]

#: the floor of ``<h.n>`` before its log, as the problem's own (rjfit.sampler.forward._columns)
_COS_FLOOR = 1e-300


@njit(inline="always")
def turned(C0, cos_ln0, cos_hn0, tangent, i, dx, dy, inv_norm):
    """``(C', log <h.n'>, <l.n'>)`` of observation ``i`` at the turned normal, C' and the log rounded to float32."""
    ln = (cos_ln0[i] + dx * tangent[i, 0] + dy * tangent[i, 1]) * inv_norm
    hn = (cos_hn0[i] + dx * tangent[i, 2] + dy * tangent[i, 3]) * inv_norm
    c = np.float32(C0[i] * (ln / cos_ln0[i]))
    lh = np.float32(math.log(max(hn, _COS_FLOOR)))
    return np.float64(c), np.float64(lh), ln


@njit(cache=True, nogil=True, parallel=True)
def normal_columns(C0, cos_ln0, cos_hn0, tangent, pixel_start, d):
    """``(C, log_cos_hn)`` float32 of every observation at its pixel's turned normal (``d`` (P, 2) per pixel)."""
    n = C0.shape[0]
    C = np.empty(n, np.float32)
    log_cos_hn = np.empty(n, np.float32)
    for p in prange(pixel_start.shape[0] - 1):
        dx, dy = d[p, 0], d[p, 1]
        inv_norm = 1.0 / math.sqrt(1.0 + dx * dx + dy * dy)
        for i in range(pixel_start[p], pixel_start[p + 1]):
            c, lh, _ = turned(C0, cos_ln0, cos_hn0, tangent, i, dx, dy, inv_norm)
            C[i] = c
            log_cos_hn[i] = lh
    return C, log_cos_hn


@njit(cache=True, nogil=True)
def _pixel_log_lik(y, C0, cos_ln0, cos_hn0, tangent, start, end, dx, dy, coef, r):
    """The untempered Gaussian log-likelihood (up to its constant) of a pixel's observations at (dx, dy) in region r;
    -inf where a kept observation would face away from its light."""
    inv_norm = 1.0 / math.sqrt(1.0 + dx * dx + dy * dy)
    total = 0.0
    for i in range(start, end):
        c, lh, ln = turned(C0, cos_ln0, cos_hn0, tangent, i, dx, dy, inv_norm)
        # The data were selected as lit (<l.n> > 0 at the given normal, rjfit.data.observations.MIN_COS): a normal
        # that turns one of them away from its light makes that observation an unlit one, which the model
        # (E <l.n> with <l.n> > 0) does not describe and the selection would have left out. The prior is
        # truncated to the normals under which every kept observation is lit.
        if ln <= 0.0:
            return -np.inf
        resid = y[i] - coef[r, 0] * c - coef[r, 1] * c * math.exp(coef[r, 2] * lh)
        total -= coef[r, 4] * resid * resid
    return total


@njit(cache=True, nogil=True, parallel=True)
def normal_sweep(y, C0, cos_ln0, cos_hn0, tangent, pixel_start, pixel_region, theta, power, prior_var, d, step,
                 noise, log_u):
    """One random-walk Metropolis test per pixel with observations: ``d' = d + step z``; returns ``(d_new, accepted)``.

    The target of pixel p is ``power * loglik_p(d) - |d|^2 / (2 prior_var)`` given its region ``pixel_region[p]``'s
    row of ``theta`` (pixels are conditionally independent given labels and region parameters, so each test is
    exact on its own). ``noise`` (P, 2) standard normals and ``log_u`` (P,) log uniforms are drawn by the caller
    from the chain's generator, so the result does not depend on the threads.
    """
    coef = coefficients(theta)
    n_pix = pixel_start.shape[0] - 1
    d_new = d.copy()
    accepted = np.zeros(n_pix, np.int8)
    for p in prange(n_pix):
        start, end = pixel_start[p], pixel_start[p + 1]
        if end == start:
            continue
        r = pixel_region[p]
        dx, dy = d[p, 0], d[p, 1]
        px, py = dx + step[p] * noise[p, 0], dy + step[p] * noise[p, 1]
        new = _pixel_log_lik(y, C0, cos_ln0, cos_hn0, tangent, start, end, px, py, coef, r)
        if new == -np.inf:
            continue
        old = _pixel_log_lik(y, C0, cos_ln0, cos_hn0, tangent, start, end, dx, dy, coef, r)
        log_ratio = power * (new - old) - 0.5 * (px * px + py * py - dx * dx - dy * dy) / prior_var
        if log_u[p] < log_ratio:
            d_new[p, 0], d_new[p, 1] = px, py
            accepted[p] = 1
    return d_new, accepted
