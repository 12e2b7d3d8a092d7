"""The checkerboard Gibbs sweep of material labels (material region model).

Given the materials' parameters, pixel p's label has the conditional

    log P(z_p = k | rest) = zeta log p(y_p | theta_k) + beta #{4-neighbours of p labelled k} + const

over the K materials in use, restricted so that no material becomes empty: a pixel that is
the last of its material keeps its label (the target gives states with an empty material
no mass). Pixels of one checkerboard colour are not neighbours, so one colour is updated
given the other; the per-pixel log-likelihoods under every material come from one compiled
pass over the observations (:func:`rjfit.sampler.regions.materials.passes.labels.pixel_log_lik`), which the
labels do not change. Every update is an exact Gibbs draw (accepted always); the step
counts how many pixels changed label. With the edge term (:mod:`rjfit.sampler.regions.materials.edges`) a new
label is then kept with probability ``min(1, exp(delta Phi))``
(:func:`~rjfit.sampler.regions.materials.passes.edges.keep_new_label`). The relabelled pixels' observations then move
between the materials' sufficient statistics (:func:`~rjfit.sampler.regions.materials.passes.labels.relabel_pixels`).
A joint colour fit sums a pixel's channels under the material's rows and moves each
observation between its channel's rows (the ``_colour`` passes).
"""
from __future__ import annotations

import numpy as np

from rjfit.sampler.likelihood import log_likelihood_from_stats
from rjfit.sampler.regions.materials.passes.labels import (
    gibbs_sweep,
    pixel_log_lik,
    pixel_log_lik_colour,
    relabel_pixels,
    relabel_pixels_colour,
)

__all__ = ["sweep_labels"]


def sweep_labels(work, rng, problem, potts, info) -> int:
    """One checkerboard sweep (colour 0, then colour 1) of the labels in ``work`` (in place); returns pixels changed.

    Draws one uniform per pixel and colour (``rng.random(H W)`` twice), whatever K; with the target's
    edge term (``work.edges``, :mod:`rjfit.sampler.regions.materials.edges`) a second one per pixel and colour, for
    the delayed acceptance of a new label.
    """
    layout = work.layout
    height, width = problem.image_shape
    n_pix = height * width
    old = layout.pixels.ravel().astype(np.int64)
    labelled = old >= 0
    n_ch = problem.n_channels
    if n_ch == 1:
        log_lik = pixel_log_lik(problem.y, problem.C, problem.log_cos_hn, problem.pixel, work.theta, n_pix,
                                problem.lobe)
    else:       # a joint colour fit: a pixel's log-likelihood sums its channels' under the material's rows
        log_lik = pixel_log_lik_colour(problem.y, problem.C, problem.log_cos_hn, problem.channel_start, work.theta,
                                       n_ch, n_pix)
    pixels = old.copy()
    counts = np.bincount(old[labelled], minlength=layout.n_materials).astype(np.int64)
    changed = 0
    edge_arrays = None if work.edges is None else work.edges.sweep_arrays(work.theta)
    for parity in (0, 1):
        uniforms = rng.random(n_pix)
        if edge_arrays is None:
            changed += gibbs_sweep(pixels, labelled, log_lik, float(problem.likelihood_power), float(potts.beta),
                                   height, width, counts, uniforms, parity)
        else:       # the edge term by delayed acceptance: a second uniform per pixel
            changed += gibbs_sweep(pixels, labelled, log_lik, float(problem.likelihood_power), float(potts.beta),
                                   height, width, counts, uniforms, parity, rng.random(n_pix), edge_arrays)
    info.count("label_gibbs", changed, proposed=int(np.count_nonzero(labelled)))
    moved = np.flatnonzero(pixels != old)
    if moved.size:
        labels = work.labels if work.labels_owned else work.labels.copy()
        if n_ch == 1:
            relabel_pixels(problem.y, problem.C, problem.log_cos_hn, problem.pixel_start, moved, old[moved],
                           pixels[moved], np.ascontiguousarray(work.theta[:, 2]), work.stats,
                           float(problem.likelihood_power), labels, problem.lobe)
        else:
            relabel_pixels_colour(problem.y, problem.C, problem.log_cos_hn, problem.pixel_start, problem.channel,
                                  n_ch, moved, old[moved], pixels[moved], np.ascontiguousarray(work.theta[:, 2]),
                                  work.stats, float(problem.likelihood_power), labels)
        work.labels, work.labels_owned, work.region_index = labels, True, None
        work.layout = layout.with_pixels(pixels.reshape(height, width).astype(layout.pixels.dtype),
                                         layout.n_materials)
        work.log_lik = log_likelihood_from_stats(work.stats, work.theta)
    return int(moved.size)
