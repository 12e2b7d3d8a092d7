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

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from rjfit.data.observations import Observations
from rjfit.model.blinn import blinn_normalisation, radiance
from rjfit.sampler import jit

__all__ = ["Problem", "STAT_N", "region_stats", "stat_terms", "log_likelihood_from_stats",
           "oracle_log_likelihood", "region_stats_numpy", "ab_from_theta", "theta_from_ab", "b_terms", "index_dtype", "RegionData", "label_runs",
           "CHUNK"]

STAT_N, STAT_YY, STAT_YA, STAT_AA, STAT_YB, STAT_AB, STAT_BB = range(7)
LOG_2PI = float(np.log(2.0 * np.pi))


# Observations are processed in chunks of this many: the float64 temporaries of a chunk stay
# in cache, and memory does not grow with the image (2048 x 2048 x 18 lights is 28M rows).
CHUNK = 1 << 17


def index_dtype(n_max: int):
    """The smallest signed integer type holding 0..n_max (compact index arrays)."""
    for dtype in (np.int8, np.int16, np.int32):
        if n_max <= np.iinfo(dtype).max:
            return dtype
    return np.int64


@dataclass(frozen=True, eq=False)
class Problem:
    """Observations prepared for the sampler: sorted by pixel, with the constant per-observation terms.

    Built with :meth:`from_observations`. Arrays are flat over observations sorted by flat
    pixel index (row-major), so the observations of a run of pixels in one row are one
    contiguous slice; ``colmajor_order`` gives the same for a run of pixels in one column.

    Storage is compact (about 25 bytes per observation): ``y``, ``C`` = E <l.n> and
    ``log_cos_hn`` are float32, which loses nothing the data had (images are float32 EXR
    or 16-bit PNG, geometry float32 EXR); ``A`` = C / pi is not stored but derived where
    needed; index arrays use the smallest integer type that holds them. Every sum over
    observations is accumulated in float64 (see :func:`region_stats`): SSR is a difference
    of sums about 1e5 times larger than itself, so float32 accumulation would lose it.

    ``likelihood_power`` (zeta, 0 < zeta <= 1) raises the likelihood to that power, the
    coarsened posterior of Miller and Dunson ("Robust Bayesian inference via coarsening",
    JASA 2019): each observation counts as zeta observations. For a model known to miss
    part of the data (a measured surface whose BRDF is not exactly Lambert + Blinn-Phong),
    with hundreds of thousands of observations, the plain posterior splits a uniform
    material into regions that absorb the misfit; coarsening asks only for agreement up
    to a discrepancy of about 1 / (zeta n) per observation. Every sufficient statistic
    (the count included) and every per-observation log density is scaled by zeta, so all
    moves, conditionals and the oracle see the same tempered likelihood.

    ``noise_scale`` (float32, or None for homoscedastic noise) holds known per-observation
    noise scales ``s_i``: the likelihood is then ``y_i ~ N(mu_i, sigma_r^2 s_i^2)`` (see
    :mod:`rjfit.data.noise`). That is weighted least squares, so ``y`` and ``C`` are stored
    divided by ``s_i`` and every statistic and move is unchanged; the density's remaining
    factor, the constant ``-zeta sum(log s_i)`` (:attr:`log_likelihood_constant`), is the
    same for every segmentation and parameter value, so the sampler leaves it out of
    ``ChainState.log_lik`` and the chain records add it.
    """

    image_shape: tuple
    y: np.ndarray                  # float32
    C: np.ndarray                  # float32, E <l.n>
    log_cos_hn: np.ndarray         # float32
    row: np.ndarray                # int16 (int32 for images over 32767 pixels)
    col: np.ndarray
    pixel: np.ndarray              # int32
    pixel_start: np.ndarray        # (H*W + 1,) first observation of each row-major pixel
    colmajor_order: np.ndarray     # observation indices sorted by (col, row)
    colmajor_start: np.ndarray     # (W*H + 1,) offsets into colmajor_order per c*H + r
    object_mask: np.ndarray
    likelihood_power: float = 1.0  # zeta of the coarsened posterior; 1: the plain likelihood
    noise_scale: np.ndarray | None = None   # float32 s_i (y and C are stored divided by it); None: all 1

    @cached_property
    def log_likelihood_constant(self) -> float:
        """``-zeta * sum(log s_i)`` (0 for homoscedastic noise), from the stored float32 scales."""
        if self.noise_scale is None:
            return 0.0
        total = 0.0
        for start in range(0, self.n_obs, CHUNK):
            total += float(np.sum(np.log(self.noise_scale[start:start + CHUNK].astype(np.float64))))
        return -self.likelihood_power * total

    @property
    def n_obs(self) -> int:
        return int(self.y.shape[0])

    @property
    def height(self) -> int:
        return int(self.image_shape[0])

    @property
    def width(self) -> int:
        return int(self.image_shape[1])

    @property
    def A(self) -> np.ndarray:
        """``E <l.n> / pi`` per observation (float64, computed on each call: not stored)."""
        return np.divide(self.C, np.pi, dtype=np.float64)

    @classmethod
    def from_observations(cls, obs: Observations, likelihood_power: float = 1.0, noise_scale=None) -> "Problem":
        """Sort, compact and (optionally) weight the observations.

        Parameters
        ----------
        obs : Observations
        likelihood_power : float
            zeta in (0, 1].
        noise_scale : array_like (N,), optional
            Known noise scales ``s_i > 0`` in the order of ``obs`` (see :mod:`rjfit.data.noise`);
            None: homoscedastic noise (every ``s_i = 1``).

        Raises
        ------
        ValueError
            For a likelihood power outside (0, 1], no observation, ``<l.n> <= 0``, or a
            noise scale of the wrong shape or not finite and positive.
        """
        if not 0.0 < likelihood_power <= 1.0:
            raise ValueError(f"likelihood_power must lie in (0, 1], got {likelihood_power}")
        if obs.n_obs == 0:
            raise ValueError("no valid observation: nothing to fit (check the object mask and validity thresholds)")
        if np.any(obs.cos_ln <= 0):
            raise ValueError("observations with <l.n> <= 0 are not valid: filter them with valid_observation_mask")
        if noise_scale is not None:
            noise_scale = np.asarray(noise_scale, dtype=np.float64)
            if noise_scale.shape != (obs.n_obs,):
                raise ValueError(f"noise_scale must have one value per observation ({obs.n_obs},), "
                                 f"got shape {noise_scale.shape}")
            if not np.all(np.isfinite(noise_scale)) or np.any(noise_scale <= 0):
                raise ValueError("noise_scale must be finite and positive for every observation")
        height, width = obs.image_shape
        n_obs, n_pix = obs.n_obs, height * width
        # int32 unless an image or stack outgrows it (never int8/int16: offsets are summed)
        obs_dtype, pix_dtype = (np.int32 if n < np.iinfo(np.int32).max else np.int64 for n in (n_obs, n_pix))
        order = np.argsort(obs.pixel, kind="stable").astype(obs_dtype)
        pixel = np.asarray(obs.pixel)[order].astype(pix_dtype)
        # float32 storage: the inputs (float32 EXR, 16-bit PNG, float32 geometry) carry no more.
        y = np.asarray(obs.y)[order].astype(np.float32)
        C = (np.asarray(obs.irradiance, float)[order] * np.asarray(obs.cos_ln, float)[order]).astype(np.float32)
        # <h.n> of a valid observation is positive; the floor only keeps log finite.
        log_cos_hn = np.log(np.clip(np.asarray(obs.cos_hn, float)[order], 1e-300, None)).astype(np.float32)
        scale = None
        if noise_scale is not None:
            # weighted least squares: y / s and C / s, with the stored float32 s (so the
            # oracle, which multiplies back, and the constant see the same numbers)
            scale = noise_scale[order].astype(np.float32)
            s64 = scale.astype(np.float64)
            y = (np.asarray(obs.y, float)[order] / s64).astype(np.float32)
            C = (np.asarray(obs.irradiance, float)[order] * np.asarray(obs.cos_ln, float)[order] / s64
                 ).astype(np.float32)
            del s64
        del order
        line_dtype = np.int16 if max(height, width) <= np.iinfo(np.int16).max else np.int32
        row, col = (pixel // width).astype(line_dtype), (pixel % width).astype(line_dtype)
        pixel_start = np.searchsorted(pixel, np.arange(n_pix + 1)).astype(obs_dtype)
        colmajor_key = col.astype(pix_dtype) * height + row
        colmajor_order = np.argsort(colmajor_key, kind="stable").astype(obs_dtype)
        colmajor_start = np.searchsorted(colmajor_key[colmajor_order], np.arange(n_pix + 1)).astype(obs_dtype)
        return cls(image_shape=(int(height), int(width)), y=y, C=C, log_cos_hn=log_cos_hn, row=row, col=col,
                   pixel=pixel, pixel_start=pixel_start, colmajor_order=colmajor_order,
                   colmajor_start=colmajor_start, object_mask=np.asarray(obs.object_mask, bool),
                   likelihood_power=float(likelihood_power), noise_scale=scale)


def b_terms(C, log_cos_hn, gamma):
    """``B = C <h.n>^gamma`` in float64 from float32 (or float64) inputs."""
    B = np.multiply(log_cos_hn, gamma, dtype=np.float64)
    np.exp(B, out=B)
    B *= C
    return B


def _stat_columns(problem: Problem, idx, gamma_per_obs):
    """The six weighted per-observation terms (Syy .. SBB) of observations ``idx``, float64."""
    y = problem.y[idx].astype(np.float64)
    C = problem.C[idx].astype(np.float64)
    B = b_terms(C, problem.log_cos_hn[idx], gamma_per_obs)
    A = np.divide(C, np.pi, out=C)
    return y * y, y * A, A * A, y * B, A * B, B * B


def stat_terms(problem: Problem, idx, gamma_per_obs):
    """The seven per-observation terms (N, 7), float64, of observations ``idx`` at exponents ``gamma_per_obs``."""
    columns = _stat_columns(problem, idx, gamma_per_obs)
    return problem.likelihood_power * np.stack([np.ones_like(columns[0]), *columns], axis=1)


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
    the runs (:mod:`rjfit.sampler.jit`), every product and sum in float64 without a float64
    copy; the gamma-free sums ``(n, Syy, SyA, SAA)`` (:attr:`fixed`) are computed on first
    use only, since the within-model moves never need them.
    """

    y: np.ndarray
    C: np.ndarray
    log_cos_hn: np.ndarray
    runs: tuple                    # (starts, ends), int64
    weight: float = 1.0            # the Problem's likelihood power: every sum is scaled by it
    gathered_idx: np.ndarray | None = None
    newton_memo: dict = field(default_factory=dict, repr=False)

    @classmethod
    def gather(cls, problem: Problem, idx) -> "RegionData":
        idx = np.asarray(idx)
        return cls(gathered_idx=idx, y=problem.y[idx], C=problem.C[idx], log_cos_hn=problem.log_cos_hn[idx],
                   runs=(np.zeros(1, np.int64), np.full(1, idx.size, np.int64)), weight=problem.likelihood_power)

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
                    runs=(starts[a:b], ends[a:b]))
                for a, b in zip(offsets[:-1], offsets[1:])]

    def positions(self, every: int = 1) -> np.ndarray:
        """Every ``every``-th of the region's observations, as positions in its arrays."""
        return jit.run_indices(*self.runs, every)

    @cached_property
    def idx(self) -> np.ndarray:
        """The region's observation indices in the problem, ascending for :meth:`split`'s."""
        positions = self.positions()
        return positions if self.gathered_idx is None else self.gathered_idx[positions]

    @cached_property
    def n(self) -> int:
        return int(np.sum(self.runs[1] - self.runs[0]))

    def thinned(self, every: int) -> "RegionData":
        """Every ``every``-th observation gathered into contiguous arrays of its own, sums scaled by ``every``.

        Contiguous: the compiled passes vectorise only over contiguous arrays.
        """
        take = self.positions(every)
        return RegionData(gathered_idx=take if self.gathered_idx is None else self.gathered_idx[take],
                          y=self.y[take], C=self.C[take], log_cos_hn=self.log_cos_hn[take],
                          runs=(np.zeros(1, np.int64), np.full(1, take.size, np.int64)),
                          weight=self.weight * self.n / max(take.size, 1))

    @cached_property
    def fixed(self) -> np.ndarray:
        """``(n, Syy, SyA, SAA)`` in float64."""
        yy, yc, cc = jit.fixed_sums(self.y, self.C, *self.runs)
        return self.weight * np.array([self.n, yy, yc / np.pi, cc / np.pi ** 2])

    def b_sums(self, gamma: float) -> np.ndarray:
        """``(SyB, SAB, SBB)`` at exponent ``gamma`` (float64; one compiled pass, :func:`rjfit.sampler.jit.b_sums`)."""
        return self.weight * jit.b_sums(self.y, self.C, self.log_cos_hn, *self.runs, float(gamma))

    def b_sums_newton(self, gamma: float) -> np.ndarray:
        """:meth:`b_sums` and their weightings by ``log <h.n>`` and its square (9,); the last two gammas asked are memoised.

        A function of the region's data and ``gamma`` only, so the memo (which lets a gamma
        move reuse the sums of the point it starts from) never changes a result.
        """
        gamma = float(gamma)
        hit = self.newton_memo.get(gamma)
        if hit is None:
            hit = self.weight * jit.b_sums_newton(self.y, self.C, self.log_cos_hn, *self.runs, gamma)
            if len(self.newton_memo) >= 2:
                self.newton_memo.pop(next(iter(self.newton_memo)))
            self.newton_memo[gamma] = hit
        return hit

    def stats_at(self, gamma: float) -> np.ndarray:
        """The seven sufficient statistics at exponent ``gamma``."""
        return np.concatenate([self.fixed, self.b_sums(gamma)])

    def stats_at_many(self, gammas) -> np.ndarray:
        """:meth:`stats_at` at each of ``gammas``: (G, 7), the passes in one compiled call."""
        gammas = np.ascontiguousarray(gammas, dtype=float)
        b_sums = self.weight * jit.b_sums_many(self.y, self.C, self.log_cos_hn, *self.runs, gammas)
        return np.hstack([np.broadcast_to(self.fixed, (gammas.size, self.fixed.size)), b_sums])


def region_stats(problem: Problem, labels, gammas, n_regions: int):
    """Sufficient statistics (R, 7) of every region from scratch (O(N), float64 sums: one compiled pass over its runs)."""
    labels = np.asarray(labels)
    gammas = np.ascontiguousarray(gammas, dtype=float)
    if labels.shape != problem.y.shape:
        raise ValueError(f"labels has shape {labels.shape}, the problem has {problem.n_obs} observations")
    if labels.size and (int(labels.min()) < 0 or int(labels.max()) >= n_regions or gammas.size < n_regions):
        raise ValueError(f"labels must lie in [0, {n_regions}) with a gamma per region")
    offsets, starts, ends = label_runs(labels, int(n_regions))
    return problem.likelihood_power * jit.region_stats_runs(problem.y, problem.C, problem.log_cos_hn, offsets, starts,
                                                            ends, gammas)


def region_stats_numpy(problem: Problem, labels, gammas, n_regions: int):
    """:func:`region_stats` in plain NumPy (chunked bincounts): the test oracle of the compiled pass."""
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
    """Eq. 1-2 evaluated directly per observation (the plain full recompute), in float64.

    Reads the Problem's own float32 arrays, the same data the sufficient statistics see:
    ``radiance`` with ``<l.n> E`` as one factor (``C``) and ``<h.n> = exp(log_cos_hn)``.
    With known noise scales it undoes the weighting (``y s``, ``C s``) and evaluates the
    heteroscedastic density ``N(y; mu, sigma^2 s^2)`` term by term, so it includes the
    constant :attr:`Problem.log_likelihood_constant` that the sampler's statistics leave out.
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
    cos_hn = np.exp(problem.log_cos_hn.astype(np.float64))
    mu = radiance(theta[:, 0], theta[:, 1], theta[:, 2], C, cos_hn, 1.0)
    resid = y - mu
    return problem.likelihood_power * float(np.sum(-0.5 * (LOG_2PI + np.log(var)) - 0.5 * resid * resid / var))
