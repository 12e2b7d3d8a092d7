"""Each pixel's normal as an unknown (issue 45, item 1; ``rjfit fit --normals sample``).

Model. Pixel p's normal is ``n'_p = (n_p + dx t1 + dy t2) / sqrt(1 + dx^2 + dy^2)``: ``n_p`` the given
(measured) normal, ``(t1, t2)`` a tangent frame of it (:func:`rjfit.data.lights.tangent_frame`) and
``(dx, dy)`` its gnomonic tangent coordinates (the tangent of the turn's angle, along each axis).
Prior: ``dx, dy`` iid ``N(0, s^2)``, ``s = tan(sigma_n)``, a density in the coordinates ``(dx, dy)``
themselves (Lebesgue measure on the tangent plane; the same prior written on the sphere would carry
the Jacobian ``(1 + dx^2 + dy^2)^(-3/2)``, which we do not use: a Gaussian in the plane is the
stated prior). sigma_n is the normal-error estimate of :mod:`rjfit.data.normal_error` (or the
user's). The likelihood of an observation is the problem's at ``n'_p`` (``C`` and ``log <h.n>``
from :mod:`rjfit.sampler.passes.normals`), tempered by the problem's power like every log density.

The move. One per-pixel random-walk Metropolis sweep per iteration, given the labels and the region
parameters (pixels are then conditionally independent, so each pixel's test is an exact MH step
of its own conditional): ``d' = d + step_p z``, ``z`` standard normal, accepted by the tempered
log-likelihood of the pixel's observations plus the log prior. ``step_p`` (per pixel) adapts
during burn-in only (Robbins-Monro on its log towards :data:`TARGET_ACCEPT`); afterwards the
kernel is a fixed MH kernel. After the sweep the problem's normal-dependent columns (``C`` and
``log_cos_hn``) are new arrays and every region's statistics and log-likelihood are recomputed
from scratch (as :func:`rjfit.sampler.kernel.refresh` does), so every later move sees the current
normals. The material model's edge term is built once from the given normals and keeps them.

The noise model. Under ``--noise normals`` the normal-error noise inflation (``var_i = sigma_r^2 (1 + k
g_i^2)``) is kept as estimated and its sigma_n is the prior's scale (:mod:`rjfit.pipeline.fit_power`). Were the
sampled normals to carry the normals' error, the inflation would count it twice; at the measured default's
likelihood powers (0.004 to 0.03) they do not (each normal's posterior is its prior), and dropping it (k = 0)
split the DiLiGenT ball into 2 to 8 materials where the kept inflation leaves it one, as with fixed normals
(docs/results/2026-11-28-normals.md). The scales are computed at the given normals and held. At a power near 1
the sampled normals do carry their error, and the inflation then counts part of it twice (``--noise constant``
is the choice there).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from rjfit.sampler.forward import Problem
from rjfit.sampler.likelihood import log_likelihood_from_stats, region_stats
from rjfit.sampler.passes.normals import normal_columns, normal_sweep

__all__ = ["NormalState", "TARGET_ACCEPT", "initial_normal_state", "normal_problem", "move_normals",
           "normal_log_prior", "pixel_regions", "normal_moments", "normals_summary",
           "normal_direction_maps"]

#: the acceptance each pixel's step adapts to (a 2-D random walk's near-optimal rate)
TARGET_ACCEPT = 0.35
#: the starting step, in prior sds, and the bounds of the adapted one
START_STEP, STEP_BOUNDS = 0.5, (1e-4, 5.0)


@dataclass(frozen=True, eq=False)
class NormalState:
    """The sampled normals of a chain state: ``d`` (H W, 2) each pixel's tangent coordinates (0 at pixels
    without observations, and at the given normals), ``log_step`` (H W,) each pixel's random-walk step."""

    d: np.ndarray
    log_step: np.ndarray


def initial_normal_state(problem: Problem) -> NormalState:
    """The given normals (``d = 0``) with every step at :data:`START_STEP` prior sds."""
    n_pix = problem.height * problem.width
    return NormalState(d=np.zeros((n_pix, 2)),
                       log_step=np.full(n_pix, math.log(START_STEP * problem.normals.prior_sd)))


def normal_problem(problem: Problem, d) -> Problem:
    """``problem`` with ``C`` and ``log_cos_hn`` at the normals ``d`` (new arrays; from its :class:`NormalData`)."""
    data = problem.normals
    C, log_cos_hn = normal_columns(data.C, data.cos_ln, data.cos_hn, data.tangent,
                                   np.asarray(problem.pixel_start, np.int64), np.asarray(d, float))
    return replace(problem, C=C, log_cos_hn=log_cos_hn)


def normal_log_prior(problem: Problem, normals: NormalState) -> float:
    """Log prior density of the sampled normals (up to its constant): ``-sum |d_p|^2 / (2 s^2)``."""
    return -0.5 * float(np.sum(normals.d * normals.d)) / problem.normals.prior_sd ** 2


def pixel_regions(problem: Problem, labels) -> np.ndarray:
    """The region of every pixel (int64; 0 where it has no observation): the label of its first observation."""
    starts = np.asarray(problem.pixel_start, np.int64)
    has = starts[1:] > starts[:-1]
    out = np.zeros(starts.size - 1, np.int64)
    out[has] = np.asarray(labels)[starts[:-1][has]]
    return out


def move_normals(work, normals: NormalState, rng, problem: Problem, iteration: int, burn_in: int, info):
    """One sweep of every pixel's normal on ``work`` (its labels and parameters held); returns the new
    :class:`NormalState` and ``problem`` at the new normals, ``work``'s statistics recomputed on it.

    ``problem`` is the one the step runs on (its power tempered during an annealed warm-up), with
    ``C`` and ``log_cos_hn`` at ``normals``; the result keeps its power.
    """
    n_pix = normals.d.shape[0]
    noise = rng.standard_normal((n_pix, 2))
    log_u = np.log(rng.random(n_pix))
    data = problem.normals
    d, accepted = normal_sweep(problem.y, data.C, data.cos_ln, data.cos_hn, data.tangent,
                               np.asarray(problem.pixel_start, np.int64), pixel_regions(problem, work.labels),
                               np.ascontiguousarray(work.theta, float), float(problem.likelihood_power),
                               data.prior_sd ** 2, normals.d, np.exp(normals.log_step), noise, log_u)
    observed = np.diff(problem.pixel_start) > 0
    info.count("normals", accepted[observed], int(observed.sum()))
    log_step = normals.log_step
    if iteration < burn_in:
        gain = 1.0 / (iteration + 1.0) ** 0.6
        low, high = (math.log(bound * data.prior_sd) for bound in STEP_BOUNDS)
        log_step = np.clip(log_step + gain * (accepted - TARGET_ACCEPT), low, high)
    moved = normal_problem(problem, d)
    work.stats = region_stats(moved, work.labels, work.theta[:, 2], work.theta.shape[0])
    work.log_lik = log_likelihood_from_stats(work.stats, work.theta)
    work.region_index = None
    return NormalState(d=d, log_step=log_step), moved


def normal_moments(records, problem: Problem) -> dict:
    """The sampled normals' posterior per pixel, pooled over the chains' kept draws.

    Returns the posterior mean tangent coordinates ``d_mean`` (H W, 2) and (H, W) maps, NaN at pixels
    without observations: ``shift_deg``, the angle between the given normal and the posterior mean
    normal (the normal at ``d_mean``), and ``sd_deg``, ``sqrt(var dx + var dy)`` in degrees (the
    tangent coordinates are the turn's angle in radians to first order).

    Raises
    ------
    ValueError
        If no chain recorded a kept draw of the normals.
    """
    draws = sum(record.normal_draws for record in records if record.normal_sum is not None)
    if draws == 0:
        raise ValueError("no kept draw of the sampled normals: run more iterations than the burn-in")
    total = sum(record.normal_sum for record in records if record.normal_sum is not None)
    squares = sum(record.normal_sq for record in records if record.normal_sum is not None)
    mean = total / draws
    variance = np.maximum(squares / draws - mean * mean, 0.0)
    observed = (np.diff(problem.pixel_start) > 0).reshape(problem.image_shape)
    shift = np.degrees(np.arctan(np.hypot(mean[:, 0], mean[:, 1]))).reshape(problem.image_shape)
    sd = np.degrees(np.sqrt(variance.sum(axis=1))).reshape(problem.image_shape)
    return {"d_mean": mean, "shift_deg": np.where(observed, shift, np.nan), "sd_deg": np.where(observed, sd, np.nan),
            "draws": int(draws)}


def normals_summary(moments: dict, problem: Problem, acceptance: float | None) -> dict:
    """summary.json's ``normals`` entry of a fit that sampled them (``moments`` of :func:`normal_moments`)."""
    shift, sd = moments["shift_deg"], moments["sd_deg"]
    kept = np.isfinite(shift)
    return {"mode": "sample", "prior_sd_deg": float(np.degrees(np.arctan(problem.normals.prior_sd))),
            "shift_median_deg": float(np.median(shift[kept])), "shift_p95_deg": float(np.percentile(shift[kept], 95)),
            "sd_median_deg": float(np.median(sd[kept])), "draws": moments["draws"], "acceptance": acceptance,
            "maps": "maps.exr channels normal_shift_deg (the posterior mean normal's angle from the given one) and "
                    "normal_sd_deg (its posterior sd), degrees; normal_dx, normal_dy (the posterior mean tangent "
                    "coordinates in the frame of rjfit.data.lights.tangent_frame)",
            "prior": "tangent coordinates (dx, dy) of n' ~ n + dx t1 + dy t2, iid N(0, tan(sigma_n)^2) in the plane"}


def normal_direction_maps(moments: dict, problem: Problem) -> dict:
    """``normal_dx``, ``normal_dy``: (H, W) maps of the posterior mean tangent coordinates, in the frame of
    :func:`rjfit.data.lights.tangent_frame` of the given normals (NaN at pixels without observations)."""
    observed = np.isfinite(moments["shift_deg"])
    return {name: np.where(observed, moments["d_mean"][:, k].reshape(problem.image_shape), np.nan)
            for k, name in enumerate(("normal_dx", "normal_dy"))}
