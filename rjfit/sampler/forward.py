"""The forward model: what an observation is modelled as, and the :class:`Problem` the sampler runs on.

The region sampler works on one structure of the likelihood: given a region's lobe exponent
gamma, the mean of every observation in it is linear in two region amplitudes,

    mu_i = a A_i + b B_i(gamma),   A_i = C_i / pi,   B_i(gamma) = C_i <h.n>_i^gamma,
    a = I0 kd,                     b = I0 (1 - kd) N(gamma)

(eq. 2, Lambert plus Blinn-Phong with Giesen's normalisation N), with Gaussian noise of a
per-region variance. From three per-observation columns, ``y``, ``C = E <l.n>`` and
``log <h.n>``, the sufficient statistics of any region follow
(:mod:`rjfit.sampler.likelihood`), so every move of the sampler is cheap. A forward model
turns observations into those columns: sorted by pixel, compacted (:class:`Problem`).

Extension points (effects with global parameters inside the likelihood, issue 26). An
:class:`Effect` is "parameters -> transformed columns + a log-Jacobian constant": a per-light
gain scales ``C`` of that light's observations; a camera response ``f`` replaces ``y`` by
``f^-1(y)`` and adds ``sum log |(f^-1)'(y_i)|``; a known additive feature ``F_i`` times a weight
``w`` replaces ``y`` by ``y - w F_i`` (Jacobian 1). A forward model with effects keeps the
untransformed problem (and whatever per-observation index its effects need, such as the
light of each observation, in the problem's sorted order) and builds, for any effect
parameters, the transformed :class:`Problem` and the constant
(:meth:`ForwardModel.transformed`). A global move then proposes new effect parameters,
recomputes every region's statistics on the transformed problem
(:func:`rjfit.sampler.likelihood.region_stats`), and accepts by the full log-likelihood plus
the log-Jacobian plus the effect's log prior. Effects whose mean is not linear in (a, b)
given gamma (a second lobe) do not fit this seam: they need a new family of statistics.

Only the plain model, :class:`LambertBlinnPhong` (no effects), exists today.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from rjfit.data.observations import Observations

__all__ = ["Problem", "ForwardModel", "Effect", "LambertBlinnPhong", "CHUNK"]

# Observations are processed in chunks of this many: the float64 temporaries of a chunk stay
# in cache, and memory does not grow with the image (2048 x 2048 x 18 lights is 28M rows).
CHUNK = 1 << 17


@dataclass(frozen=True, eq=False)
class Problem:
    """Observations prepared for the sampler: sorted by pixel, with the constant per-observation terms.

    Built by a :class:`ForwardModel` (:meth:`from_observations`: the plain one). Arrays are
    flat over observations sorted by flat pixel index (row-major), so the observations of a
    run of pixels in one row are one contiguous slice; ``colmajor_order`` gives the same for
    a run of pixels in one column.

    Storage is compact (about 25 bytes per observation): ``y``, ``C`` = E <l.n> and
    ``log_cos_hn`` are float32, which loses nothing the data had (images are float32 EXR
    or 16-bit PNG, geometry float32 EXR); ``A`` = C / pi is not stored but derived where
    needed; index arrays use the smallest integer type that holds them. Every sum over
    observations is accumulated in float64 (see :func:`rjfit.sampler.likelihood.region_stats`):
    SSR is a difference of sums about 1e5 times larger than itself, so float32 accumulation
    would lose it.

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
    def from_observations(cls, obs: Observations, likelihood_power: float = 1.0, noise_scale=None) -> Problem:
        """The plain forward model's problem: :meth:`LambertBlinnPhong.problem` (see there)."""
        return LambertBlinnPhong().problem(obs, likelihood_power=likelihood_power, noise_scale=noise_scale)


class Effect(ABC):
    """One effect with global parameters inside the likelihood (issue 26): parameters -> columns + log-Jacobian.

    An effect changes what the sampler's columns are, never the region structure: it maps
    the columns of a :class:`Problem` (``y``, ``C``, ``log_cos_hn``, in the problem's sorted
    order; as the effects listed before it left them) and its parameters to transformed
    columns, and gives the log-Jacobian of the transformation of ``y`` (0 when ``y`` is not
    transformed), summed over observations and weighted by the likelihood power like every
    log density. An index the Problem does not hold (the light of each observation, for
    per-light gains) the effect keeps itself, in the problem's sorted order: the forward
    model that builds the problem builds it too. No effect is implemented yet; this is the
    contract a first one fulfils.

    Attributes
    ----------
    name : str
        The effect's name (``summary.json`` records it with its posterior).
    n_params : int
        Number of global parameters.
    """

    name: str = ""
    n_params: int = 0

    @abstractmethod
    def log_prior(self, params) -> float:
        """Log prior density of the effect's parameters (-inf outside their support)."""

    @abstractmethod
    def transform(self, problem: Problem, params) -> tuple[np.ndarray, np.ndarray, float]:
        """``(y, C, log_jacobian)``: the transformed float32 columns and the log-Jacobian constant."""


class ForwardModel(ABC):
    """The BRDF family plus effects: builds the :class:`Problem` the region sampler runs on.

    Subclasses implement :meth:`problem` (observations -> sorted, compacted columns). A model
    with effects lists them in :attr:`effects` and inherits :meth:`transformed`, which
    applies them in order for given parameters; a global move of the kernel (not written
    yet) proposes the parameters and compares the full log-likelihoods of the two
    transformed problems plus their log-Jacobians and the effects' log priors.
    """

    effects: tuple = ()

    @abstractmethod
    def problem(self, observations: Observations, *, likelihood_power: float = 1.0, noise_scale=None) -> Problem:
        """The untransformed :class:`Problem` of ``observations``."""

    def transformed(self, problem: Problem, effect_params=()) -> tuple[Problem, float]:
        """``(problem with every effect applied, total log-Jacobian)`` for one parameter vector per effect.

        Raises
        ------
        ValueError
            If ``effect_params`` does not hold one parameter vector of the right length per effect.
        """
        effect_params = list(effect_params)
        if len(effect_params) != len(self.effects):
            raise ValueError(f"{len(effect_params)} effect parameter vectors for {len(self.effects)} effects")
        log_jacobian = 0.0
        for effect, params in zip(self.effects, effect_params):
            if np.size(params) != effect.n_params:
                raise ValueError(f"effect {effect.name!r} takes {effect.n_params} parameters, got {np.size(params)}")
            y, C, log_jac = effect.transform(problem, params)
            problem = _with_columns(problem, y, C)
            log_jacobian += log_jac
        return problem, log_jacobian


def _with_columns(problem: Problem, y, C) -> Problem:
    return replace(problem, y=np.asarray(y, np.float32), C=np.asarray(C, np.float32))


class LambertBlinnPhong(ForwardModel):
    """The paper's model (eq. 2): Lambert plus energy-normalised Blinn-Phong, no effects."""

    def problem(self, observations: Observations, *, likelihood_power: float = 1.0, noise_scale=None) -> Problem:
        """Sort, compact and (optionally) weight the observations.

        Parameters
        ----------
        observations : Observations
        likelihood_power : float
            zeta in (0, 1].
        noise_scale : array_like (N,), optional
            Known noise scales ``s_i > 0`` in the order of ``observations`` (see
            :mod:`rjfit.data.noise`); None: homoscedastic noise (every ``s_i = 1``).

        Raises
        ------
        ValueError
            For a likelihood power outside (0, 1], no observation, ``<l.n> <= 0``, or a
            noise scale of the wrong shape or not finite and positive.
        """
        obs = observations
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
        y, C, log_cos_hn, scale = _columns(obs, order, noise_scale)
        del order
        line_dtype = np.int16 if max(height, width) <= np.iinfo(np.int16).max else np.int32
        row, col = (pixel // width).astype(line_dtype), (pixel % width).astype(line_dtype)
        pixel_start = np.searchsorted(pixel, np.arange(n_pix + 1)).astype(obs_dtype)
        colmajor_key = col.astype(pix_dtype) * height + row
        colmajor_order = np.argsort(colmajor_key, kind="stable").astype(obs_dtype)
        colmajor_start = np.searchsorted(colmajor_key[colmajor_order], np.arange(n_pix + 1)).astype(obs_dtype)
        return Problem(image_shape=(int(height), int(width)), y=y, C=C, log_cos_hn=log_cos_hn, row=row, col=col,
                       pixel=pixel, pixel_start=pixel_start, colmajor_order=colmajor_order,
                       colmajor_start=colmajor_start, object_mask=np.asarray(obs.object_mask, bool),
                       likelihood_power=float(likelihood_power), noise_scale=scale)


def _columns(obs: Observations, order, noise_scale):
    """``(y, C, log_cos_hn, scale)`` in the sorted order, float32; y and C divided by the noise scales if any."""
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
        C = (np.asarray(obs.irradiance, float)[order] * np.asarray(obs.cos_ln, float)[order] / s64).astype(np.float32)
    return y, C, log_cos_hn, scale
