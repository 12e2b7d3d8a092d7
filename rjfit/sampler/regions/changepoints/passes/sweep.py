"""The element sweep's proposals: one element per moved line, with the log ratio of the proposal densities.

Compiled because a sweep proposes for every other line at once and the mixture density
(uniform redraw, random walk, normal around a neighbouring line's same-rank element) and
the smooth prior's terms of each line take a loop per line
(:mod:`rjfit.sampler.regions.changepoints.sweeps`).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from rjfit.sampler.passes.special import log_normal, logaddexp

__all__ = ["sweep_proposal"]


@njit(cache=True, nogil=True)
def _element_log_q(x_to, x_from, nb_up, nb_down, size, p_unif, p_nb, step, nb_sd):
    """Log density of proposing element position ``x_to`` from ``x_from`` (NaN marks a missing neighbour).

    Mixture of a uniform redraw over [-1, size + 1], a normal random walk (sd ``step``) and a
    normal (sd ``nb_sd``) around the same-rank element of a neighbouring line, chosen
    uniformly among the existing neighbours.
    """
    p_rw = 1.0 - p_unif - p_nb
    out = -np.inf
    if p_unif > 0:
        out = math.log(p_unif) - math.log(size + 2.0)
    if p_rw > 0:
        out = logaddexp(out, math.log(p_rw) + log_normal(x_to, x_from, step))
    if p_nb > 0:
        dens, n_have = 0.0, 0
        for nb in (nb_up, nb_down):
            if np.isfinite(nb):
                dens += math.exp(log_normal(x_to, nb, nb_sd))
                n_have += 1
        if n_have > 0 and dens > 0:
            out = logaddexp(out, math.log(p_nb) + math.log(dens / n_have))
    return out


@njit(cache=True, nogil=True)
def _smooth_terms(row, cps, neighbour, sd):
    """Sum over ranks of log N(row[k] - cps[neighbour, k]; 0, sd); 0 without that neighbour."""
    if neighbour < 0:
        return 0.0
    total = 0.0
    for k in range(row.shape[0]):
        total += log_normal(row[k], cps[neighbour, k], sd)
    return total


@njit(cache=True, nogil=True)
def sweep_proposal(cps, lines, k, kind, z, pick_up, unif, size, p_unif, p_nb, step, nb_sd, smooth_sd):
    """Element proposals of one sweep: ``(x_new, inside, log_q_ratio)`` per moved line.

    Compiled twin of the proposal half of :func:`rjfit.sampler.regions.changepoints.sweeps.sweep_changepoints`
    (same random inputs, same mixture; ``smooth_sd`` <= 0 for the 'paper' prior, whose
    terms cancel): element ``k[j]`` of line ``lines[j]`` is redrawn uniformly
    (``kind < p_unif``), around a neighbouring line's same-rank element (``kind < p_unif +
    p_nb``; the upper one if ``pick_up`` and it exists) or by a random walk; the ratio holds
    the reverse and forward proposal densities and the smooth prior's terms of the line.
    """
    n_all, n_cp = cps.shape
    n_lines = lines.shape[0]
    x_new = np.empty(n_lines)
    inside = np.empty(n_lines, np.bool_)
    log_q_ratio = np.empty(n_lines)
    row_old = np.empty(n_cp)
    row_new = np.empty(n_cp)
    for j in range(n_lines):
        line = lines[j]
        up = line - 1 if line > 0 else -1
        down = line + 1 if line < n_all - 1 else -1
        x_old = cps[line, k[j]]
        nb_up = cps[up, k[j]] if up >= 0 else np.nan
        nb_down = cps[down, k[j]] if down >= 0 else np.nan
        centre = nb_up if pick_up[j] else nb_down
        if not np.isfinite(centre):
            centre = nb_down if pick_up[j] else nb_up
        if kind[j] < p_unif:
            x = unif[j]
        elif kind[j] < p_unif + p_nb and np.isfinite(centre):
            x = centre + nb_sd * z[j]
        else:
            x = x_old + step * z[j]
        inside[j] = -1.0 <= x <= size + 1.0
        if not inside[j]:
            x = x_old
        x_new[j] = x
        # rank of the moved element after the move (the reverse move picks that rank)
        k_new = 0
        for m in range(n_cp):
            if cps[line, m] < x:
                k_new += 1
        if x_old < x:
            k_new -= 1
        back_up = cps[up, k_new] if up >= 0 else np.nan
        back_down = cps[down, k_new] if down >= 0 else np.nan
        ratio = (_element_log_q(x_old, x, back_up, back_down, size, p_unif, p_nb, step, nb_sd)
                 - _element_log_q(x, x_old, nb_up, nb_down, size, p_unif, p_nb, step, nb_sd))
        if smooth_sd > 0:
            for m in range(n_cp):
                row_old[m] = cps[line, m]
                row_new[m] = cps[line, m]
            row_new[k[j]] = x
            row_new.sort()
            ratio += (_smooth_terms(row_new, cps, up, smooth_sd) + _smooth_terms(row_new, cps, down, smooth_sd)
                      - _smooth_terms(row_old, cps, up, smooth_sd) - _smooth_terms(row_old, cps, down, smooth_sd))
        log_q_ratio[j] = ratio
    return x_new, inside, log_q_ratio
