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

A problem with effects (:mod:`rjfit.sampler.forward`) has a lobe column of its own
(``Problem.lobe``): ``B`` is then :func:`lobe_column`'s, and every pass is handed the lobe
terms (:mod:`rjfit.sampler.passes.lobe`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numba import njit

from rjfit.model.blinn import blinn_normalisation, radiance
from rjfit.effects.masking import beckmann_alpha, smith_g1_tan
from rjfit.effects.ggx import LOG_COS_H_ZERO, ggx_over_norm
from rjfit.sampler.forward import Problem
from rjfit.sampler.passes import sums

__all__ = ["STAT_N", "STAT_YY", "STAT_YA", "STAT_AA", "STAT_YB", "STAT_AB", "STAT_BB", "LOG_2PI", "region_stats",
           "log_likelihood_from_stats", "log_lik_large_ab", "AB_PLAIN_MAX", "MEAN_NORM_MAX", "oracle_log_likelihood",
           "observation_log_likelihood", "ab_from_theta", "b_terms", "index_dtype", "RegionData", "label_runs", "lobe_column", "memoised"]

STAT_N, STAT_YY, STAT_YA, STAT_AA, STAT_YB, STAT_AB, STAT_BB = range(7)
LOG_2PI = float(np.log(2.0 * np.pi))
#: |a| and |b| up to which a region's quadratic form is summed as written: every product stays
#: below 1e300 for statistics below 1e100 (a data set's are some 1e20 at most)
AB_PLAIN_MAX = 1e100
#: a mean's norm beyond which the density underflows (its square and the residual's overflow float64)
MEAN_NORM_MAX = 1e150


def index_dtype(n_max: int):
    """The smallest signed integer type holding 0..n_max (compact index arrays)."""
    for dtype in (np.int8, np.int16, np.int32):
        if n_max <= np.iinfo(dtype).max:
            return dtype
    return np.int64


def b_terms(C, log_cos_hn, gamma):
    """``B = C <h.n>^gamma`` in float64 from float32 (or float64) inputs."""
    B = np.multiply(log_cos_hn, gamma, dtype=np.float64)
    np.exp(B, out=B)
    B *= C
    return B


def lobe_column(problem: Problem, idx, gamma_per_obs) -> np.ndarray:
    """The lobe column ``B`` of observations ``idx`` at their exponents, float64 (NumPy).

    ``C <h.n>^gamma`` (:func:`b_terms`) for the plain model; with effects, the lobe terms of
    :mod:`rjfit.sampler.passes.lobe` (the compiled passes' twin).
    """
    lobe = problem.lobe
    if lobe is None:
        return b_terms(problem.C[idx], problem.log_cos_hn[idx], gamma_per_obs)
    gamma = np.broadcast_to(np.asarray(gamma_per_obs, dtype=float), problem.log_cos_hn[idx].shape)
    B = b_terms(lobe.cb[idx].astype(np.float64), problem.log_cos_hn[idx], gamma)
    if lobe.ggx_w != 0.0:
        lh = problem.log_cos_hn[idx].astype(float)
        cos2_h = np.where(lh > LOG_COS_H_ZERO, np.exp(2.0 * lh), 0.0)
        ggx = ggx_over_norm(cos2_h, lobe.tan_v[idx].astype(float), lobe.tan_l[idx].astype(float), gamma)
        B = (1.0 - lobe.ggx_w) * B + lobe.ggx_w * (lobe.cb[idx].astype(np.float64) * ggx)
    if lobe.mask_w != 0.0:
        alpha = beckmann_alpha(gamma)
        g = smith_g1_tan(lobe.tan_v[idx].astype(float), alpha) * smith_g1_tan(lobe.tan_l[idx].astype(float), alpha)
        B *= (1.0 - lobe.mask_w) + lobe.mask_w * g
    if lobe.second.size:
        B += lobe.second[idx].astype(float) / blinn_normalisation(gamma)
    if lobe.amb.size:
        low, high, step = lobe.grid
        x = (np.clip(np.log(gamma), low, high) - low) / step
        i = np.minimum(x.astype(int), lobe.table.shape[0] - 2)
        fx = x - i
        j, fy = lobe.amb_j[idx], lobe.amb_fy[idx].astype(float)
        row_j = (1.0 - fx) * lobe.table[i, j] + fx * lobe.table[i + 1, j]
        row_next = (1.0 - fx) * lobe.table[i, j + 1] + fx * lobe.table[i + 1, j + 1]
        B += lobe.amb[idx].astype(float) * ((1.0 - fy) * row_j + fy * row_next) / blinn_normalisation(gamma)
    return B


def label_runs(labels, n_regions: int):
    """Every region's observations as runs of consecutive indices with that label.

    Returns ``offsets`` (R + 1,), ``starts`` and ``ends`` (int64): region r's runs are
    ``[starts[k], ends[k])`` for k in ``[offsets[r], offsets[r + 1])``, ascending.
    Observations are sorted by pixel and a region is a union of pixel runs along the image
    rows, so a few runs per row hold all of a region: passes over it read the problem's
    arrays in place, and a new labelling costs one vectorised comparison of the labels
    instead of a copy of every region's observations.
    """
    labels = np.asarray(labels)
    if labels.size == 0:
        return np.zeros(n_regions + 1, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    change = np.flatnonzero(labels[1:] != labels[:-1]) + 1
    starts = np.concatenate([[0], change]).astype(np.int64)
    ends = np.concatenate([change, [labels.size]]).astype(np.int64)
    run_label = labels[starts]
    order = np.argsort(run_label, kind="stable")
    offsets = np.searchsorted(run_label[order], np.arange(n_regions + 1)).astype(np.int64)
    return offsets, starts[order], ends[order]


@dataclass(frozen=True, eq=False)
class RegionData:
    """One region's observations, as runs ``[starts[k], ends[k])`` of float32 arrays, with float64 sums at any gamma.

    :meth:`split` makes every region of a labelling as runs of the problem's own arrays,
    read in place; :meth:`gather` copies chosen observations into arrays of their own (one
    run, ``gathered_idx`` their indices in the problem). Each sum is one compiled pass over
    the runs (:mod:`rjfit.sampler.passes.sums`), every product and sum in float64 without a float64
    copy; the gamma-free sums ``(n, Syy, SyA, SAA)`` (:attr:`fixed`) are computed on first
    use only, since the within-model moves never need them. ``memo`` holds what other modules
    derive from these observations alone (:func:`memoised`).
    """

    y: np.ndarray
    C: np.ndarray
    log_cos_hn: np.ndarray
    runs: tuple                    # (starts, ends), int64
    weight: float = 1.0            # the Problem's likelihood power: every sum is scaled by it
    gathered_idx: np.ndarray | None = None
    lobe: object = None            # the Problem's lobe terms (rjfit.sampler.passes.lobe), None for the plain model
    newton_memo: dict = field(default_factory=dict, repr=False)
    b_memo: dict = field(default_factory=dict, repr=False)
    memo: dict = field(default_factory=dict, repr=False)

    @classmethod
    def gather(cls, problem: Problem, idx) -> RegionData:
        idx = np.asarray(idx)
        return cls(gathered_idx=idx, y=problem.y[idx], C=problem.C[idx], log_cos_hn=problem.log_cos_hn[idx],
                   runs=(np.zeros(1, np.int64), np.full(1, idx.size, np.int64)), weight=problem.likelihood_power,
                   lobe=None if problem.lobe is None else problem.lobe.take(idx))

    @classmethod
    def split(cls, problem: Problem, labels, n_regions: int) -> list:
        """Every region's :class:`RegionData` from one read of the labels (runs of the problem's arrays)."""
        labels = np.asarray(labels)
        if labels.shape != problem.y.shape:
            raise ValueError(f"labels has shape {labels.shape}, the problem has {problem.n_obs} observations")
        if labels.size and (int(labels.min()) < 0 or int(labels.max()) >= n_regions):
            raise ValueError(f"labels must lie in [0, {n_regions})")
        offsets, starts, ends = label_runs(labels, int(n_regions))
        return [cls(y=problem.y, C=problem.C, log_cos_hn=problem.log_cos_hn, weight=problem.likelihood_power,
                    runs=(starts[a:b], ends[a:b]), lobe=problem.lobe)
                for a, b in zip(offsets[:-1], offsets[1:])]

    def positions(self, every: int = 1) -> np.ndarray:
        """Every ``every``-th of the region's observations, as positions in its arrays."""
        return sums.run_indices(*self.runs, every)

    @cached_property
    def idx(self) -> np.ndarray:
        """The region's observation indices in the problem, ascending for :meth:`split`'s."""
        positions = self.positions()
        return positions if self.gathered_idx is None else self.gathered_idx[positions]

    @cached_property
    def n(self) -> int:
        return int(np.sum(self.runs[1] - self.runs[0]))

    def thinned(self, every: int) -> RegionData:
        """Every ``every``-th observation gathered into contiguous arrays of its own, sums scaled by ``every``.

        Contiguous: the compiled passes vectorise only over contiguous arrays.
        """
        take = self.positions(every)
        return RegionData(gathered_idx=take if self.gathered_idx is None else self.gathered_idx[take],
                          y=self.y[take], C=self.C[take], log_cos_hn=self.log_cos_hn[take],
                          runs=(np.zeros(1, np.int64), np.full(1, take.size, np.int64)),
                          weight=self.weight * self.n / max(take.size, 1),
                          lobe=None if self.lobe is None else self.lobe.take(take))

    @cached_property
    def fixed(self) -> np.ndarray:
        """``(n, Syy, SyA, SAA)`` in float64."""
        yy, yc, cc = sums.fixed_sums(self.y, self.C, *self.runs)
        return self.weight * np.array([self.n, yy, yc / np.pi, cc / np.pi ** 2])

    def b_sums(self, gamma: float) -> np.ndarray:
        """``(SyB, SAB, SBB)`` at exponent ``gamma`` (float64; one compiled pass, :func:`rjfit.sampler.passes.sums.b_sums`).

        The last two gammas asked are memoised, as in :meth:`b_sums_newton`: a
        region proposal's draw and the move that made it ask for the drawn gamma's sums twice.
        """
        return _remembered(self.b_memo, float(gamma), lambda g: self.weight * sums.b_sums(
            self.y, self.C, self.log_cos_hn, *self.runs, g, self.lobe))

    def b_sums_newton(self, gamma: float) -> np.ndarray:
        """:meth:`b_sums` and their weightings by ``log <h.n>`` and its square (9,); the last two gammas asked are memoised.

        A function of the region's data and ``gamma`` only, so the memo (which lets a gamma
        move reuse the sums of the point it starts from) never changes a result.
        """
        return _remembered(self.newton_memo, float(gamma), lambda g: self.weight * sums.b_sums_newton(
            self.y, self.C, self.log_cos_hn, *self.runs, g, self.lobe))

    def stats_at(self, gamma: float) -> np.ndarray:
        """The seven sufficient statistics at exponent ``gamma``."""
        return np.concatenate([self.fixed, self.b_sums(gamma)])

    def stats_at_many(self, gammas) -> np.ndarray:
        """:meth:`stats_at` at each of ``gammas``: (G, 7), the passes in one compiled call."""
        gammas = np.ascontiguousarray(gammas, dtype=float)
        b_sums = self.weight * sums.b_sums_many(self.y, self.C, self.log_cos_hn, *self.runs, gammas, self.lobe)
        return np.hstack([np.broadcast_to(self.fixed, (gammas.size, self.fixed.size)), b_sums])


def _remembered(memo: dict, gamma: float, compute) -> np.ndarray:
    """``compute(gamma)``, kept in ``memo`` with the previous gamma's (callers share it: they only read it)."""
    hit = memo.get(gamma)
    if hit is None:
        hit = compute(gamma)
        if len(memo) >= 2:
            memo.pop(next(iter(memo)))
        memo[gamma] = hit
    return hit


def memoised(data, name: str, key: tuple, compute):
    """``compute()`` for a pixel set's ``data`` (anything with a ``memo`` dict), kept there under ``name``.

    For what is a function of the data and of the objects in ``key`` alone (a proposal's
    Laplace fit given the prior, a split's guide): recomputed only when ``key`` holds other
    objects (compared by identity), so a memoised value is the value computed afresh.
    """
    held = data.memo.get(name)
    if held is not None and len(held[0]) == len(key) and all(a is b for a, b in zip(held[0], key)):
        return held[1]
    value = compute()
    data.memo[name] = (key, value)
    return value


def region_stats(problem: Problem, labels, gammas, n_regions: int):
    """Sufficient statistics (R, 7) of every region from scratch (O(N), float64 sums: one compiled pass over its runs)."""
    labels = np.asarray(labels)
    gammas = np.ascontiguousarray(gammas, dtype=float)
    if labels.shape != problem.y.shape:
        raise ValueError(f"labels has shape {labels.shape}, the problem has {problem.n_obs} observations")
    if labels.size and (int(labels.min()) < 0 or int(labels.max()) >= n_regions or gammas.size < n_regions):
        raise ValueError(f"labels must lie in [0, {n_regions}) with a gamma per region")
    offsets, starts, ends = label_runs(labels, int(n_regions))
    return problem.likelihood_power * sums.region_stats_runs(problem.y, problem.C, problem.log_cos_hn, offsets, starts,
                                                            ends, gammas, problem.lobe)


def ab_from_theta(theta):
    """``(a, b) = (I0 kd, I0 (1 - kd) N(g))`` for theta (..., 4)."""
    theta = np.asarray(theta, float)
    I0, kd, g = theta[..., 0], theta[..., 1], theta[..., 2]
    return I0 * kd, I0 * (1.0 - kd) * blinn_normalisation(g)


def log_likelihood_from_stats(stats, theta):
    """Per-region log-likelihood from sufficient statistics (R, 7) and parameters (R, 4).

    Regions with no observation contribute 0. Regions whose |a| or |b| exceeds
    :data:`AB_PLAIN_MAX` take :func:`log_lik_large_ab` (their quadratic form would overflow).

    The SSR is floored at 0, here and in every sum of it from statistics: a sum of squares is
    never negative, but its expansion ``Syy - 2 a SyA - ... + b^2 SBB`` cancels, and where the fit
    is exact (a colour material's channel with two observations of a rim pixel) rounding leaves it
    slightly below 0; the likelihood then grew without bound as sigma^2 fell, and a chain's
    sigma^2 walk followed it (a joint colour fit of psm-horse reached a log posterior of 1.7e156,
    docs/results/2026-11-30-colour-noise.md). Where the sum is >= 0 the floor changes nothing.
    """
    stats = np.asarray(stats, float)
    theta = np.asarray(theta, float)
    if stats.ndim == 2 and theta.shape == (stats.shape[0], 4) and stats.shape[1] == 7:
        # the moves' case, a few regions: one compiled call (the array expressions below cost ~0.1 ms on any size)
        out = np.empty(stats.shape[0])
        if _log_lik_rows(stats, theta, out):
            return out
    a, b = ab_from_theta(theta)
    large = (np.abs(a) > AB_PLAIN_MAX) | (np.abs(b) > AB_PLAIN_MAX)
    if np.any(large):       # summed as written with 0 in their place, then replaced
        a, b = np.where(large, 0.0, a), np.where(large, 0.0, b)
    s2 = theta[..., 3]
    ssr = (stats[..., STAT_YY] - 2.0 * a * stats[..., STAT_YA] - 2.0 * b * stats[..., STAT_YB]
           + a * a * stats[..., STAT_AA] + 2.0 * a * b * stats[..., STAT_AB] + b * b * stats[..., STAT_BB])
    ssr = np.maximum(ssr, 0.0)      # a sum of squares: rounding's negative sums floored (NaN stays NaN)
    n = stats[..., STAT_N]
    out = -0.5 * n * (LOG_2PI + np.log(s2)) - 0.5 * ssr / s2
    if np.any(large):
        big_a, big_b = ab_from_theta(theta)
        out = np.array(out, float)
        for index in zip(*np.nonzero(np.atleast_1d(large))):
            index = index if np.ndim(large) else ()
            out[index] = log_lik_large_ab(stats[index], big_a[index], big_b[index], s2[index])
    return out


@njit(cache=True, nogil=True)
def _log_lik_rows(stats, theta, out) -> bool:
    """:func:`log_likelihood_from_stats` of (R, 7) statistics and (R, 4) parameters into ``out``; False (``out``
    unfinished) where a row's |a| or |b| exceeds :data:`AB_PLAIN_MAX` (the caller's general path handles it).
    The same arithmetic as the array form (``2 ** x`` for ``np.exp2``: within rounding, as ``giesen_norm``)."""
    for r in range(stats.shape[0]):
        I0, kd, g, s2 = theta[r, 0], theta[r, 1], theta[r, 2], theta[r, 3]
        a = I0 * kd
        b = I0 * (1.0 - kd) * ((g + 2.0) * (g + 4.0) / (8.0 * np.pi * (2.0 ** (-g / 2.0) + g)))
        if abs(a) > AB_PLAIN_MAX or abs(b) > AB_PLAIN_MAX:
            return False
        ssr = (stats[r, STAT_YY] - 2.0 * a * stats[r, STAT_YA] - 2.0 * b * stats[r, STAT_YB]
               + a * a * stats[r, STAT_AA] + 2.0 * a * b * stats[r, STAT_AB] + b * b * stats[r, STAT_BB])
        if ssr < 0.0:       # floored as in log_likelihood_from_stats
            ssr = 0.0
        out[r] = -0.5 * stats[r, STAT_N] * (LOG_2PI + np.log(s2)) - 0.5 * ssr / s2
    return True


def log_lik_large_ab(stats_r, a, b, s2) -> float:
    """One region's log-likelihood where |a| or |b| exceeds :data:`AB_PLAIN_MAX`, without overflow.

    Such amplitudes come from proposals where a column of the region has all but vanished:
    at a gamma where ``<h.n>^gamma`` underflows over the region, SBB is ~1e-300 and the (a, b)
    conditional's sd of b ~1e150, so b^2 overflows while b^2 SBB need not. The quadratic form
    is summed in the columns' own scale, ``p = a sqrt(SAA)``, ``q = b sqrt(SBB)``:
    ``SSR = Syy - 2 p SyA/sqrt(SAA) - 2 q SyB/sqrt(SBB) + p^2 + 2 p q r + q^2`` with
    ``r = SAB / sqrt(SAA SBB)``. For a, b >= 0 (what the priors allow) and A, B >= 0 the
    mean's norm is at least max(p, q); beyond :data:`MEAN_NORM_MAX` the density underflows
    and the result is -inf, as it is for a NaN amplitude. Python floats, checked on their
    results.
    """
    n, syy, sya, saa, syb, sab, sbb = (float(x) for x in stats_r)
    a, b, s2 = float(a), float(b), float(s2)
    sa, sb = math.sqrt(max(saa, 0.0)), math.sqrt(max(sbb, 0.0))
    p = a * sa if sa > 0 else 0.0          # a column without observations (sum 0): its amplitude does not enter
    q = b * sb if sb > 0 else 0.0
    if not (abs(p) <= MEAN_NORM_MAX and abs(q) <= MEAN_NORM_MAX):     # also False for NaN
        return -math.inf
    ya = sya / sa if sa > 0 else 0.0
    yb = syb / sb if sb > 0 else 0.0
    r = sab / (sa * sb) if sa * sb > 0 else 0.0
    ssr = syy - 2.0 * p * ya - 2.0 * q * yb + p * p + 2.0 * p * q * r + q * q
    if ssr < 0.0:       # floored as in log_likelihood_from_stats
        ssr = 0.0
    log_lik = -0.5 * n * (LOG_2PI + math.log(s2)) - 0.5 * ssr / s2
    return log_lik if math.isfinite(log_lik) else -math.inf


def oracle_log_likelihood(problem: Problem, labels, theta) -> float:
    """Eq. 1-2 evaluated directly per observation (the plain full recompute), in float64, summed and
    tempered by the problem's likelihood power (:func:`observation_log_likelihood`)."""
    return problem.likelihood_power * float(np.sum(observation_log_likelihood(problem, labels, theta)))


def observation_log_likelihood(problem: Problem, labels, theta) -> np.ndarray:
    """Each observation's log density under eq. 1-2, untempered, in float64: observation i under row
    ``labels[i]`` of ``theta``.

    Reads the Problem's own float32 arrays, the same data the sufficient statistics see:
    ``radiance`` with ``<l.n> E`` as one factor (``C``) and ``<h.n> = exp(log_cos_hn)``.
    With known noise scales it undoes the weighting (``y s``, ``C s``) and evaluates the
    heteroscedastic density ``N(y; mu, sigma^2 s^2)`` term by term, so it includes the
    constant :attr:`Problem.log_likelihood_constant` that the sampler's statistics leave out.
    A problem with effects' lobe terms: the mean is ``a A + b B`` with :func:`lobe_column`'s B
    (in the units of the transformed problem; the noise-scale weighting is undone as above).
    """
    theta = np.asarray(theta, float)[np.asarray(labels)]
    C = problem.C.astype(np.float64)
    y = problem.y.astype(np.float64)
    var = theta[:, 3].copy()
    if problem.noise_scale is not None:
        s = problem.noise_scale.astype(np.float64)
        C *= s
        y *= s
        var *= s * s
    if problem.lobe is None:
        cos_hn = np.exp(problem.log_cos_hn.astype(np.float64))
        mu = radiance(theta[:, 0], theta[:, 1], theta[:, 2], C, cos_hn, 1.0)
    else:
        a, b = ab_from_theta(theta)
        B = lobe_column(problem, slice(None), theta[:, 2])
        if problem.noise_scale is not None:
            B *= problem.noise_scale.astype(np.float64)
        mu = a * C / np.pi + b * B
    resid = y - mu
    return -0.5 * (LOG_2PI + np.log(var)) - 0.5 * resid * resid / var
