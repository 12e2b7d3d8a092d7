"""The Gaussian likelihood of eq. 1-2 via per-region sufficient statistics, and its oracle.

Write the mean of an observation in region r as

    mu = a * A + b * B_g,   A = E <l.n> / pi,   B_g = E <l.n> <h.n>^g,
    a = I0 kd,              b = I0 (1 - kd) N(g)

with N(g) Giesen's normalisation. For fixed g the residual sum of squares is a quadratic
form in (a, b), so the seven sums ``n, Syy, SyA, SAA, SyB, SAB, SBB`` of a region (the
``STAT_*`` columns) give its log-likelihood in O(1) for any I0, kd and sigma^2. Only a
change of g needs the region's observations again (the B sums).

:func:`oracle_log_likelihood` evaluates eq. 1-2 directly from the observations with
:func:`rjfit.model.blinn.radiance`; it is the test oracle of the incremental bookkeeping.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rjfit.data.observations import Observations
from rjfit.model.blinn import blinn_normalisation, radiance

__all__ = ["Problem", "STAT_N", "region_stats", "stat_terms", "log_likelihood_from_stats",
           "oracle_log_likelihood", "ab_from_theta", "theta_from_ab"]

STAT_N, STAT_YY, STAT_YA, STAT_AA, STAT_YB, STAT_AB, STAT_BB = range(7)
LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass(frozen=True, eq=False)
class Problem:
    """Observations prepared for the sampler: sorted by pixel, with the constant per-observation terms.

    Built with :meth:`from_observations`. Arrays are flat over observations sorted by flat
    pixel index (row-major), so the observations of a run of pixels in one row are one
    contiguous slice; ``colmajor_order`` gives the same for a run of pixels in one column.
    """

    image_shape: tuple
    y: np.ndarray
    A: np.ndarray
    C: np.ndarray
    log_cos_hn: np.ndarray
    yy: np.ndarray
    yA: np.ndarray
    AA: np.ndarray
    row: np.ndarray
    col: np.ndarray
    pixel: np.ndarray
    pixel_start: np.ndarray        # (H*W + 1,) first observation of each row-major pixel
    colmajor_order: np.ndarray     # observation indices sorted by (col, row)
    colmajor_start: np.ndarray     # (W*H + 1,) offsets into colmajor_order per c*H + r
    object_mask: np.ndarray
    observations: Observations

    @property
    def n_obs(self) -> int:
        return int(self.y.shape[0])

    @property
    def height(self) -> int:
        return int(self.image_shape[0])

    @property
    def width(self) -> int:
        return int(self.image_shape[1])

    @classmethod
    def from_observations(cls, obs: Observations) -> "Problem":
        if obs.n_obs == 0:
            raise ValueError("no valid observation: nothing to fit (check the object mask and validity thresholds)")
        if np.any(obs.cos_ln <= 0):
            raise ValueError("observations with <l.n> <= 0 are not valid: filter them with valid_observation_mask")
        height, width = obs.image_shape
        order = np.argsort(obs.pixel, kind="stable")
        pixel = np.asarray(obs.pixel)[order].astype(np.int64)
        y = np.asarray(obs.y, float)[order]
        cos_ln = np.asarray(obs.cos_ln, float)[order]
        cos_hn = np.asarray(obs.cos_hn, float)[order]
        irradiance = np.asarray(obs.irradiance, float)[order]
        C = irradiance * cos_ln
        A = C / np.pi
        # <h.n> of a valid observation is positive; the floor only keeps log finite.
        log_cos_hn = np.log(np.clip(cos_hn, 1e-300, None))
        row, col = pixel // width, pixel % width
        pixel_start = np.searchsorted(pixel, np.arange(height * width + 1))
        colmajor_key = col * height + row
        colmajor_order = np.argsort(colmajor_key, kind="stable")
        colmajor_start = np.searchsorted(colmajor_key[colmajor_order], np.arange(width * height + 1))
        return cls(image_shape=(int(height), int(width)), y=y, A=A, C=C, log_cos_hn=log_cos_hn,
                   yy=y * y, yA=y * A, AA=A * A, row=row, col=col, pixel=pixel, pixel_start=pixel_start,
                   colmajor_order=colmajor_order, colmajor_start=colmajor_start,
                   object_mask=np.asarray(obs.object_mask, bool), observations=obs)


def stat_terms(problem: Problem, idx, gamma_per_obs):
    """The seven per-observation terms (N, 7) of observations ``idx`` at exponents ``gamma_per_obs``."""
    B = problem.C[idx] * np.exp(gamma_per_obs * problem.log_cos_hn[idx])
    y, A = problem.y[idx], problem.A[idx]
    return np.stack([np.ones_like(y), problem.yy[idx], problem.yA[idx], problem.AA[idx], y * B, A * B, B * B], axis=1)


def region_stats(problem: Problem, labels, gammas, n_regions: int):
    """Sufficient statistics (R, 7) of every region from scratch (O(N))."""
    labels = np.asarray(labels)
    gamma_per_obs = np.asarray(gammas, float)[labels]
    B = problem.C * np.exp(gamma_per_obs * problem.log_cos_hn)
    columns = (None, problem.yy, problem.yA, problem.AA, problem.y * B, problem.A * B, B * B)
    out = np.empty((n_regions, 7))
    for k, weights in enumerate(columns):
        out[:, k] = np.bincount(labels, weights=weights, minlength=n_regions)[:n_regions]
    return out


def ab_from_theta(theta):
    """``(a, b) = (I0 kd, I0 (1 - kd) N(g))`` for theta (..., 4)."""
    theta = np.asarray(theta, float)
    I0, kd, g = theta[..., 0], theta[..., 1], theta[..., 2]
    return I0 * kd, I0 * (1.0 - kd) * blinn_normalisation(g)


def theta_from_ab(a, b, g):
    """Inverse of :func:`ab_from_theta` at fixed g: ``I0 = a + b / N(g)``, ``kd = a / I0``."""
    I0 = a + b / blinn_normalisation(g)
    return I0, a / I0


def log_likelihood_from_stats(stats, theta):
    """Per-region log-likelihood from sufficient statistics (R, 7) and parameters (R, 4).

    Regions with no observation contribute 0.
    """
    stats = np.asarray(stats, float)
    theta = np.asarray(theta, float)
    a, b = ab_from_theta(theta)
    s2 = theta[..., 3]
    ssr = (stats[..., STAT_YY] - 2.0 * a * stats[..., STAT_YA] - 2.0 * b * stats[..., STAT_YB]
           + a * a * stats[..., STAT_AA] + 2.0 * a * b * stats[..., STAT_AB] + b * b * stats[..., STAT_BB])
    n = stats[..., STAT_N]
    return -0.5 * n * (LOG_2PI + np.log(s2)) - 0.5 * ssr / s2


def oracle_log_likelihood(problem: Problem, labels, theta) -> float:
    """Eq. 1-2 evaluated directly per observation (the plain full recompute)."""
    theta = np.asarray(theta, float)[np.asarray(labels)]
    obs = problem.observations
    order = np.argsort(obs.pixel, kind="stable")
    mu = radiance(theta[:, 0], theta[:, 1], theta[:, 2], obs.cos_ln[order], obs.cos_hn[order], obs.irradiance[order])
    s2 = theta[:, 3]
    resid = obs.y[order] - mu
    return float(np.sum(-0.5 * (LOG_2PI + np.log(s2)) - 0.5 * resid * resid / s2))
