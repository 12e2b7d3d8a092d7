"""Compiled passes of the scatter moves (:mod:`rjfit.sampler.regions.materials.scatter_move`).

- :func:`allocate_birth`: every labelled pixel, in raster order, keeps its material or joins a new one;
- :func:`allocate_dissolve`: every pixel of a dying material, in raster order, joins one of the others.

Both draw an allocation (``forced`` empty) or evaluate the probability of a given one (the reverse move's), and
both read a pixel's 4-neighbours in the partial state: earlier pixels with their allocated labels, later ones with
their labels before the move (``labels`` is updated in place as the scan goes). Pixels are flat row-major indices
``r * W + c``; -1 marks an unlabelled pixel.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["allocate_birth", "allocate_dissolve"]


@njit(cache=True, nogil=True)
def _neighbours_with(labels, p, label, height, width) -> int:
    """How many of pixel p's 4-neighbours carry ``label``."""
    r, c = p // width, p % width
    n = 0
    if r > 0 and labels[p - width] == label:
        n += 1
    if r < height - 1 and labels[p + width] == label:
        n += 1
    if c > 0 and labels[p - 1] == label:
        n += 1
    if c < width - 1 and labels[p + 1] == label:
        n += 1
    return n


@njit(cache=True, nogil=True)
def allocate_birth(labels, own_log_lik, new_log_lik, power, beta, height, width, new_label, uniforms, forced):
    """Each labelled pixel p, in raster order, joins material ``new_label`` with probability

        sigma(power (new_log_lik[p] - own_log_lik[p]) + beta (n_new - n_own)),

    n_new and n_own its 4-neighbours carrying the new label and its own in the partial state; else it keeps its
    label. ``labels`` (H W,) holds no pixel of ``new_label`` on entry and the allocation on return. Drawn with
    ``uniforms[p]`` (one per pixel), or, with ``forced`` (H W,) not empty, given: ``forced[p] == 1`` joins.
    Returns the allocation's log probability.
    """
    log_prob = 0.0
    given = forced.shape[0] > 0
    for p in range(labels.shape[0]):
        own = labels[p]
        if own < 0:
            continue
        d = (power * (new_log_lik[p] - own_log_lik[p])
             + beta * (_neighbours_with(labels, p, new_label, height, width)
                       - _neighbours_with(labels, p, own, height, width)))
        # log sigma(d) and log sigma(-d), stable on both sides
        log_join = -math.log1p(math.exp(-d)) if d > 0 else d - math.log1p(math.exp(d))
        log_keep = -math.log1p(math.exp(d)) if d < 0 else -d - math.log1p(math.exp(-d))
        join = forced[p] == 1 if given else uniforms[p] < math.exp(log_join)
        if join:
            labels[p] = new_label
            log_prob += log_join
        else:
            log_prob += log_keep
    return log_prob


@njit(cache=True, nogil=True)
def allocate_dissolve(labels, members, dying, log_lik, power, beta, height, width, uniforms, forced):
    """Each pixel ``members[j]`` (all of material ``dying``, ascending), in turn, joins material k != ``dying`` with
    probability proportional to ``exp(power log_lik[k, p] + beta n_k)``, n_k its 4-neighbours carrying k in the
    partial state. ``labels`` (H W,) is updated in place; drawn with ``uniforms[j]``, or, with ``forced`` not
    empty, given: ``forced[j]`` the label it joins. Returns the allocation's log probability.
    """
    n_labels = log_lik.shape[0]
    logits = np.empty(n_labels)
    log_prob = 0.0
    given = forced.shape[0] > 0
    for j in range(members.shape[0]):
        p = members[j]
        top = -math.inf
        for k in range(n_labels):
            if k == dying:
                continue
            logits[k] = power * log_lik[k, p] + beta * _neighbours_with(labels, p, k, height, width)
            top = max(top, logits[k])
        total = 0.0
        for k in range(n_labels):
            if k != dying:
                total += math.exp(logits[k] - top)
        choice = -1
        if given:
            choice = forced[j]
        else:
            target, running = uniforms[j] * total, 0.0
            for k in range(n_labels):
                if k == dying:
                    continue
                running += math.exp(logits[k] - top)
                choice = k
                if target < running:
                    break
        labels[p] = choice
        log_prob += logits[choice] - top - math.log(total)
    return log_prob
