"""NumPy references of the compiled passes: the same quantities, written plainly, for the tests to compare against.

Each function here is the twin of a pass in :mod:`rjfit.sampler.passes` (or of what a
move computes with one), written for clarity over speed: per-observation arrays in
float64, ``math.fsum`` for exact sums, Python loops along the lines. Where a pass draws
random numbers the twin takes a generator and consumes it in the order the move feeds
the pass its uniforms, so the two draw the same values from the same seed. A problem with effects' lobe terms gets
its lobe column from :func:`rjfit.sampler.likelihood.lobe_column`.
``tests/sampler/test_passes.py`` holds the comparisons. The sampler itself never calls this
module.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.signal import fftconvolve
from scipy.special import ndtr, ndtri

from rjfit.sampler.forward import CHUNK, Problem
from rjfit.sampler.likelihood import LOG_2PI, STAT_N, STAT_YY, ab_from_theta, lobe_column

__all__ = ["region_stats", "b_sums", "b_sums_newton", "obs_log_density", "forward_filter", "cell_step_logits",
           "path_log_prob", "backward_sample", "normal_mass", "within_cell_log_density", "draw_within_cells",
           "rank_chain", "pixel_log_lik", "pixel_log_lik_colour", "gibbs_sweep", "edge_uniform", "grow_cluster",
           "allocate_split"]


# ----------------------------------------------------------------------------- sufficient statistics

def _stat_columns(problem: Problem, idx, gamma_per_obs):
    """The six per-observation terms (Syy .. SBB) of observations ``idx``, float64, unweighted."""
    y = problem.y[idx].astype(np.float64)
    C = problem.C[idx].astype(np.float64)
    B = lobe_column(problem, idx, gamma_per_obs)
    A = np.divide(C, np.pi, out=C)
    return y * y, y * A, A * A, y * B, A * B, B * B


def region_stats(problem: Problem, labels, gammas, n_regions: int):
    """Twin of :func:`rjfit.sampler.likelihood.region_stats` (chunked bincounts over the observations)."""
    labels = np.asarray(labels)
    gammas = np.asarray(gammas, float)
    out = np.zeros((n_regions, 7))
    for start in range(0, problem.n_obs, CHUNK):
        chunk = slice(start, start + CHUNK)
        lab = labels[chunk].astype(np.intp)
        out[:, STAT_N] += np.bincount(lab, minlength=n_regions)[:n_regions]
        for k, weights in enumerate(_stat_columns(problem, chunk, gammas[lab]), start=STAT_YY):
            out[:, k] += np.bincount(lab, weights=weights, minlength=n_regions)[:n_regions]
    return out * problem.likelihood_power


def _b_terms_of(problem: Problem, idx, gamma):
    y, C = problem.y[idx].astype(float), problem.C[idx].astype(float)
    B = lobe_column(problem, idx, gamma)
    return y * B, C / math.pi * B, B * B


def b_sums(problem: Problem, idx, gamma: float) -> np.ndarray:
    """Twin of :meth:`RegionData.b_sums <rjfit.sampler.likelihood.RegionData.b_sums>`: ``(SyB, SAB, SBB)``, by fsum."""
    return problem.likelihood_power * np.array([math.fsum(t) for t in _b_terms_of(problem, idx, gamma)])


def b_sums_newton(problem: Problem, idx, gamma: float) -> np.ndarray:
    """Twin of :meth:`RegionData.b_sums_newton <rjfit.sampler.likelihood.RegionData.b_sums_newton>`: the B sums
    weighted by 1, ``log <h.n>`` and its square (9 values, ``math.fsum``)."""
    lh = problem.log_cos_hn[idx].astype(float)
    terms = _b_terms_of(problem, idx, gamma)
    return problem.likelihood_power * np.array([math.fsum(t * w) for w in (1.0, lh, lh * lh) for t in terms])


def obs_log_density(problem: Problem, idx, theta_obs) -> np.ndarray:
    """Gaussian log density of observations ``idx``, each under its own parameters ``theta_obs`` (n, 4).

    Unweighted (the passes of :mod:`rjfit.sampler.passes.densities` return it so; their
    callers scale by the likelihood power).
    """
    a, b = ab_from_theta(theta_obs)
    C = problem.C[idx].astype(float)
    mu = a / math.pi * C + b * lobe_column(problem, idx, theta_obs[:, 2])
    s2 = theta_obs[:, 3]
    return -0.5 * (LOG_2PI + np.log(s2)) - 0.5 * (problem.y[idx] - mu) ** 2 / s2


# ----------------------------------------------------------------------------- chains along the lines

def forward_filter(log_emit, log_kernel):
    """Twin of :func:`rjfit.sampler.regions.changepoints.passes.paths.forward_filter` (FFT convolution of linear weights).

    ``log_kernel`` (2 S - 1 or more entries, centred) holds the log weights of cell steps.
    """
    n_cells = log_emit.shape[1]
    kernel = np.exp(log_kernel)
    alpha = np.empty_like(log_emit)
    previous = None
    for r in range(log_emit.shape[0]):
        a = log_emit[r].copy()
        if previous is not None:
            a += np.log(np.maximum(fftconvolve(previous, kernel)[n_cells - 1: 2 * n_cells - 1], 1e-300))
        top = np.max(a)
        linear = np.exp(a - top)
        alpha[r] = a - top - np.log(linear.sum())
        previous = linear / linear.sum()
    return alpha


def cell_step_logits(log_kernel):
    """Backward logits of the cell chain: line r's cells given line r + 1's cell, as a function ``(alpha, r, next)``.

    ``log_kernel`` (2 K + 1,) holds the log weights of steps -K..K; cells further than K
    from line r + 1's cell get -inf (None: independent lines).
    """
    def logits(alpha, r, cell_next):
        if log_kernel is None:
            return alpha[r]
        reach = (log_kernel.size - 1) // 2
        steps = np.arange(alpha.shape[1]) - cell_next
        inside = np.abs(steps) <= reach
        out = np.full(alpha.shape[1], -np.inf)
        out[inside] = alpha[r, inside] + log_kernel[reach + steps[inside]]
        return out
    return logits


def path_log_prob(alpha, path, logits_given_next):
    """Twin of :func:`~rjfit.sampler.regions.changepoints.passes.paths.cell_path_log_prob` and
    :func:`~rjfit.sampler.regions.changepoints.passes.paths.rank_path_log_prob`: the log probability that
    :func:`backward_sample` draws ``path``."""
    total = float(alpha[-1, path[-1]])            # alpha rows are normalised
    for r in range(alpha.shape[0] - 2, -1, -1):
        logits = logits_given_next(alpha, r, path[r + 1])
        if not np.isfinite(logits[path[r]]):
            return -np.inf
        top = np.max(logits)
        total += float(logits[path[r]] - top - np.log(np.sum(np.exp(logits - top))))
    return total


def _draw_index(logits, rng):
    weights = np.cumsum(np.exp(logits - np.max(logits)))
    return min(int(np.searchsorted(weights, rng.random() * weights[-1], side="right")), logits.size - 1)


def backward_sample(alpha, logits_given_next, rng):
    """Twin of :func:`~rjfit.sampler.regions.changepoints.passes.paths.cell_backward_sample` and
    :func:`~rjfit.sampler.regions.changepoints.passes.paths.rank_backward_sample`: a path drawn from the chain
    whose normalised forward log alphas are ``alpha``, last line first, one uniform per line."""
    path = np.empty(alpha.shape[0], np.int64)
    path[-1] = _draw_index(alpha[-1], rng)
    for r in range(alpha.shape[0] - 2, -1, -1):
        path[r] = _draw_index(logits_given_next(alpha, r, path[r + 1]), rng)
    return path


def normal_mass(a, b):
    """P(a < Z < b) for a standard normal, accurate in both tails."""
    upper = a > 0                       # both in the upper tail: use the mirrored lower tail
    return np.where(upper, ndtr(-a) - ndtr(-b), ndtr(b) - ndtr(a))


def within_cell_log_density(x, x_next, lo, hi, sd):
    """Log density of positions x (L,) inside their cells [lo, hi) of the backward draw, per line.

    Twin of :func:`rjfit.sampler.regions.changepoints.passes.paths.within_cells_log_density` (which sums it).
    Line L - 1 is uniform in its cell; line r < L - 1 follows the prior's step, a normal
    around the next line's position x_next truncated to the cell (uniform where the cell
    holds less than 1e-12 of that normal's mass, or without a step model, ``sd`` None).
    """
    out = -np.log(hi - lo)
    if sd is None:
        return out
    a, b = (lo[:-1] - x_next) / sd, (hi[:-1] - x_next) / sd
    mass = normal_mass(a, b)
    normal = mass > 1e-12
    with np.errstate(divide="ignore"):
        log_trunc = -0.5 * ((x[:-1] - x_next) / sd) ** 2 - math.log(sd) - 0.5 * LOG_2PI - np.log(mass)
    out[:-1] = np.where(normal, log_trunc, out[:-1])
    return out


def draw_within_cells(lo, hi, sd, rng):
    """Twin of :func:`rjfit.sampler.regions.changepoints.passes.paths.within_cells_draw`: positions inside the cells [lo, hi),
    drawn from line L - 1 backwards, one uniform per line (see :func:`within_cell_log_density`)."""
    n_lines = lo.size
    x = np.empty(n_lines)
    x[-1] = lo[-1] + (hi[-1] - lo[-1]) * rng.random()
    for r in range(n_lines - 2, -1, -1):
        u = rng.random()
        if sd is not None:
            a, b = (lo[r] - x[r + 1]) / sd, (hi[r] - x[r + 1]) / sd
            if float(normal_mass(np.array(a), np.array(b))) > 1e-12:
                if a > 0:        # mirrored, so the inverse CDF works away from 1
                    z = -ndtri(ndtr(-a) - u * (ndtr(-a) - ndtr(-b)))
                else:
                    z = ndtri(ndtr(a) + u * (ndtr(b) - ndtr(a)))
                x[r] = min(max(x[r + 1] + sd * z, lo[r]), np.nextafter(hi[r], lo[r]))
                continue
        x[r] = lo[r] + (hi[r] - lo[r]) * u
    return x


def rank_chain(log_emit, log_t):
    """Twin of :func:`rjfit.sampler.regions.changepoints.passes.paths.rank_forward`: forward alphas, and the backward logits function.

    ``log_t[from, to]`` are the chain's log transitions between ranks
    (:func:`rjfit.sampler.regions.changepoints.birth_death_free.rank_transitions`); the logits function is
    what :func:`path_log_prob` and :func:`backward_sample` take.
    """
    n_lines, n = log_emit.shape
    alpha = np.empty_like(log_emit)
    previous = None
    for r in range(n_lines):
        a = log_emit[r].copy()
        if previous is not None:
            a += np.logaddexp.reduce(previous[:, None] + log_t, axis=0)
        a -= np.logaddexp.reduce(a)
        alpha[r] = previous = a

    def logits(alpha, r, rank_next):
        return alpha[r] + log_t[:, rank_next]
    return alpha, logits


# ----------------------------------------------------------------------------- material labels

def pixel_log_lik(problem: Problem, theta) -> np.ndarray:
    """Twin of :func:`rjfit.sampler.regions.materials.passes.labels.pixel_log_lik`: (K, H W) per-pixel sums of log densities (fsum)."""
    theta = np.asarray(theta, float)
    n_pix = problem.height * problem.width
    out = np.zeros((theta.shape[0], n_pix))
    idx = np.arange(problem.n_obs)
    for k in range(theta.shape[0]):
        density = obs_log_density(problem, idx, np.repeat(theta[k][None], problem.n_obs, axis=0))
        for p in range(n_pix):
            out[k, p] = math.fsum(density[problem.pixel_start[p]:problem.pixel_start[p + 1]])
    return out


def pixel_log_lik_colour(problem: Problem, theta) -> np.ndarray:
    """Twin of :func:`rjfit.sampler.regions.materials.passes.labels.pixel_log_lik_colour`: (K, H W), material k's channel c in row
    ``k C + c`` (fsum per pixel)."""
    theta = np.asarray(theta, float)
    n_ch = problem.n_channels
    n_pix = problem.height * problem.width
    out = np.zeros((theta.shape[0] // n_ch, n_pix))
    idx = np.arange(problem.n_obs)
    for k in range(out.shape[0]):
        density = obs_log_density(problem, idx, theta[k * n_ch + problem.channel.astype(np.int64)])
        for p in range(n_pix):
            out[k, p] = math.fsum(density[problem.pixel_start[p]:problem.pixel_start[p + 1]])
    return out


def gibbs_sweep(pixel_labels, labelled, log_lik, power, beta, image_shape, counts, uniforms, parity) -> int:
    """Twin of :func:`rjfit.sampler.regions.materials.passes.labels.gibbs_sweep` (pixel by pixel, NumPy per pixel); in place."""
    height, width = image_shape
    changed = 0
    for r in range(height):
        for c in range((r + parity) % 2, width, 2):
            p = r * width + c
            old = pixel_labels[p]
            if not labelled[p] or counts[old] <= 1:
                continue
            logits = power * log_lik[:, p].copy()
            for q, inside in ((p - width, r > 0), (p + width, r < height - 1), (p - 1, c > 0), (p + 1, c < width - 1)):
                if inside and labelled[q]:
                    logits[pixel_labels[q]] += beta
            weights = np.exp(logits - logits.max())
            running = np.cumsum(weights)
            new = int(np.searchsorted(running, uniforms[p] * running[-1], side="right"))
            new = min(new, logits.size - 1)
            if new != old:
                counts[old] -= 1
                counts[new] += 1
                pixel_labels[p] = new
                changed += 1
    return changed


_MASK64 = (1 << 64) - 1


def edge_uniform(key: int, edge: int) -> float:
    """Twin of :func:`rjfit.sampler.regions.materials.passes.labels.edge_uniform` (SplitMix64 in Python integers)."""
    z = (key + edge + 0x9E3779B97F4A7C15) & _MASK64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _MASK64
    z ^= z >> 31
    return (z >> 11) / float(1 << 53)


def grow_cluster(pixel_labels, labelled, bond_q, key, seed, image_shape, n_labels):
    """Twin of :func:`rjfit.sampler.regions.materials.passes.labels.grow_cluster`: the on-bond component by a breadth-first search."""
    height, width = image_shape

    def neighbours(p):
        r, c = divmod(p, width)
        if c < width - 1:
            yield p + 1, 2 * p
        if r < height - 1:
            yield p + width, 2 * p + 1
        if c > 0:
            yield p - 1, 2 * (p - 1)
        if r > 0:
            yield p - width, 2 * (p - width) + 1

    label = pixel_labels[seed]
    cluster, frontier = {int(seed)}, [int(seed)]
    while frontier:
        p = frontier.pop()
        for q, edge in neighbours(p):
            if (q not in cluster and labelled[q] and pixel_labels[q] == label
                    and edge_uniform(int(key), edge) < bond_q[edge]):
                cluster.add(q)
                frontier.append(q)
    n_to = np.zeros(n_labels, np.int64)
    log_cut_to = np.zeros(n_labels)
    for p in cluster:
        for q, edge in neighbours(p):
            if q not in cluster and labelled[q]:
                n_to[pixel_labels[q]] += 1
                log_cut_to[pixel_labels[q]] += math.log1p(-bond_q[edge])
    return np.array(sorted(cluster), np.int64), n_to, log_cut_to


def allocate_split(members, guide_log_lik, power, beta, image_shape, uniforms, forced):
    """Twin of :func:`rjfit.sampler.regions.materials.passes.labels.allocate_split`: the same allocation with a softmax per pixel."""
    height, width = image_shape
    part_of = {}
    parts = np.empty(len(members), np.int8)
    log_prob = 0.0
    for j, p in enumerate(members):
        r, c = divmod(int(p), width)
        logits = power * np.asarray(guide_log_lik)[:, j].astype(float)
        for q, inside in ((p - width, r > 0), (p + width, r < height - 1), (p - 1, c > 0), (p + 1, c < width - 1)):
            if inside and int(q) in part_of:
                logits[part_of[int(q)]] += beta
        log_probs = logits - np.logaddexp.reduce(logits)
        part = int(forced[j]) if forced[j] >= 0 else (0 if uniforms[j] < math.exp(log_probs[0]) else 1)
        parts[j] = part
        part_of[int(p)] = part
        log_prob += log_probs[part]
    return parts, float(log_prob)
