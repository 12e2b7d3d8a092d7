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

Effects with global parameters inside the likelihood (issue 26). An effect's fit form
(:class:`rjfit.effects.base.FitForm`; each effect of :mod:`rjfit.effects` states its own)
changes the columns (:class:`rjfit.effects.base.Columns`), never the region structure, at
given parameters: a per-light gain or a shadowing factor scales ``C``; a camera response
``f`` replaces ``y`` by ``f^-1(y)`` and adds ``sum log |(f^-1)'(y_i)|`` (the log-Jacobian); a
known additive feature ``F_i`` (indirect light) times a weight replaces ``y`` by
``y - w F_i``; a Fresnel factor scales the lobe's own ``C`` (``CB``); a GGX lobe mixed in,
masking, a second lobe and ambient light make the lobe column gamma-dependent per
observation (:mod:`rjfit.sampler.passes.lobe`). With effects the mean stays linear in (a, b)
given gamma,

    mu_i = a A_i + b B_i(gamma),   A_i = C_i / pi,
    B_i(gamma) = CB_i L_i(gamma) M_i(gamma) + (second_i + amb_i alb(gamma, v_i)) / N(gamma),
    L_i(gamma) = (1 - u) <h.n>_i^gamma + u f_GGX,i(alpha(gamma)) / N(gamma),

so every statistic and move of the region sampler serves them unchanged. A forward model
with effects (:class:`LambertBlinnPhong` with ``effects``) builds the untransformed problem
with an :class:`EffectData` (the raw values and the effects, their per-observation features
in the problem's order); :func:`transformed` builds, for any effect parameters, the
transformed :class:`Problem` and the log-Jacobian. The kernel's effect move
(:mod:`rjfit.sampler.moves.effects`) proposes the parameters and accepts by the full
log-likelihood of the transformed problem plus the log-Jacobian, the effects' log prior
and the proposal densities. Effects whose mean is not linear in (a, b) given gamma (a
second lobe with a weight and roughness of its own per region) do not fit: they need a new
family of statistics; a second lobe whose weight and roughness are global, relative to the
region's lobe amplitude, is linear and fits.

The noise: the criticism writes a camera response as ``y = f(mu) + e`` (noise after the
response); the fit, which needs the sufficient statistics of a Gaussian linear in (a, b),
writes ``f^-1(y) = mu + e`` (noise on the linearised scale). Both have the mean ``f(mu)``
to first order in the noise; the fit's density of ``y`` carries the Jacobian.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from rjfit.data.observations import Observations
from rjfit.effects.base import STAGES, Columns, stage_key
from rjfit.sampler.passes.lobe import LobeTerms

__all__ = ["Problem", "ForwardModel", "EffectData", "NormalData", "LambertBlinnPhong", "transformed", "CHUNK"]

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

    ``channel`` and ``n_channels``: a joint colour fit (``rjfit fit --channel rgb``) holds
    each colour channel's observations, a pixel's sorted by channel (``channel``, int8); a
    region (material) then has one parameter row per channel sharing gamma
    (:mod:`rjfit.sampler.colour`). None and 1 for a single channel.

    ``normals`` (a :class:`NormalData`, or None: the normals are the given ones) holds what a fit
    that samples each pixel's normal needs (:mod:`rjfit.sampler.normals`); ``C`` and
    ``log_cos_hn`` are then those at the normals of the state the problem was made for (the
    given ones in the problem a forward model builds).

    ``lobe`` (a :class:`~rjfit.sampler.passes.lobe.LobeTerms`, or None for the plain lobe
    ``C <h.n>^gamma``) holds the lobe column's own terms of a problem with effects applied;
    ``effects`` (an :class:`EffectData`, or None) the forward model's effects with the
    untransformed data they start from (:func:`transformed`).
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
    lobe: LobeTerms | None = None          # the lobe column's terms with effects applied; None: C <h.n>^gamma
    effects: EffectData | None = None      # the effects sampled with the regions, and their raw data
    channel: np.ndarray | None = None      # int8 colour channel per observation (joint colour fit); None: one
    n_channels: int = 1
    light: np.ndarray | None = None        # int16 light of each observation (the edge term's matches); None: unknown
    normals: NormalData | None = None      # the given normals' terms of a fit that samples them; None: fixed

    @cached_property
    def channel_start(self) -> np.ndarray:
        """(H W C + 1,) the first observation of pixel p's channel c at ``p C + c`` (a joint colour fit).

        A pixel's observations are sorted by channel (:meth:`LambertBlinnPhong.problem`
        sorts stably by pixel the channels stacked one after the other), so each
        (pixel, channel) is one run.
        """
        key = self.pixel.astype(np.int64) * self.n_channels + (0 if self.channel is None else self.channel)
        return np.searchsorted(key, np.arange(self.height * self.width * self.n_channels + 1)).astype(np.int64)

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
    def from_observations(cls, obs: Observations, likelihood_power: float = 1.0, noise_scale=None,
                          normal_prior_sd: float | None = None) -> Problem:
        """The plain forward model's problem: :meth:`LambertBlinnPhong.problem` (see there)."""
        return LambertBlinnPhong().problem(obs, likelihood_power=likelihood_power, noise_scale=noise_scale,
                                           normal_prior_sd=normal_prior_sd)


@dataclass(frozen=True, eq=False)
class EffectData:
    """A forward model's effects and the untransformed data they start from (in the problem's order).

    ``effects`` are in stage order with their features in the problem's order; ``y`` and
    ``C`` are the raw float64 values and ``E <l.n>``; ``light`` the light of each observation;
    ``scale`` the known noise scales (float64 of the problem's float32 ones; None: all 1).
    Parameters of all effects are one flat vector ``z`` in their unconstrained coordinates,
    effect after effect.
    """

    effects: tuple
    y: np.ndarray
    C: np.ndarray
    light: np.ndarray
    scale: np.ndarray | None = None

    @property
    def n_params(self) -> int:
        return sum(effect.n_params for effect in self.effects)

    @property
    def names(self) -> list:
        """``effect.param`` of every parameter, in the order of ``z``."""
        return [f"{effect.name}.{param.name}" for effect in self.effects for param in effect.params]

    def blocks(self) -> list:
        """Each effect's slice of ``z``."""
        out, start = [], 0
        for effect in self.effects:
            out.append(slice(start, start + effect.n_params))
            start += effect.n_params
        return out

    def priors(self) -> list:
        return [param.prior for effect in self.effects for param in effect.params]

    def constrained(self, z) -> np.ndarray:
        """The constrained parameters of unconstrained ``z`` (flat)."""
        return np.array([float(prior.to_constrained(value))
                         for prior, value in zip(self.priors(), np.asarray(z, float))])

    def initial_z(self) -> np.ndarray:
        """Each parameter's ``init`` in the unconstrained coordinates."""
        return np.array([float(p.prior.to_unconstrained(p.init)) for e in self.effects for p in e.params])

    def log_prior(self, z) -> float:
        """Log prior density of ``z`` (each parameter Gaussian in its unconstrained coordinate)."""
        return float(sum(float(prior.log_prob_unconstrained(value)) for prior, value in zip(self.priors(), z)))

    def columns(self, z) -> Columns:
        """The :class:`Columns` with every effect applied at unconstrained ``z``.

        Raises
        ------
        ValueError
            If ``z`` does not hold one value per parameter.
        """
        z = np.asarray(z, dtype=float)
        if z.shape != (self.n_params,):
            raise ValueError(f"{z.size} effect parameters for effects taking {self.n_params} "
                             f"({', '.join(self.names)})")
        theta = self.constrained(z)
        columns = Columns(y=self.y, C=self.C, CB=self.C, light=self.light)
        for effect, block in zip(self.effects, self.blocks()):
            effect.apply(columns, theta[block])
        return columns


@dataclass(frozen=True, eq=False)
class NormalData:
    """The given normals' terms of a problem whose pixels' normals are sampled (:mod:`rjfit.sampler.normals`).

    In the problem's order: ``C`` (float32, the problem's ``E <l.n> / s`` at the given normals),
    ``cos_ln`` and ``cos_hn`` (float32, at the given normals) and ``tangent`` ((N, 4) float32,
    :attr:`rjfit.data.observations.Observations.tangent`); ``prior_sd`` is ``tan(sigma_n)``, the
    sd of each tangent coordinate's Gaussian prior.
    """

    C: np.ndarray
    cos_ln: np.ndarray
    cos_hn: np.ndarray
    tangent: np.ndarray
    prior_sd: float


def transformed(problem: Problem, z) -> tuple[Problem, float]:
    """``(problem with its effects applied at unconstrained z, log-Jacobian)``.

    The log-Jacobian is ``sum_i log |(f^-1)'(y_i)|`` of a camera response, at likelihood
    power 1 (the caller weighs it by the power, as every log density). The new columns are
    float32, like the problem's own; the noise scales divide ``y`` (after the offset), ``C``,
    ``CB`` and the ambient radiance.

    Raises
    ------
    ValueError
        If ``problem`` has no effects, or ``z`` is of the wrong length.
    """
    data = problem.effects
    if data is None:
        raise ValueError("the problem has no effects to apply")
    columns = data.columns(z)
    y = columns.y if columns.offset is None else columns.y - columns.offset
    C, CB = columns.C, columns.CB
    inverse_scale = None if data.scale is None else 1.0 / data.scale
    if inverse_scale is not None:
        y, C, CB = y * inverse_scale, C * inverse_scale, CB * inverse_scale
    lobe = _lobe_terms(columns, CB, inverse_scale)
    return replace(problem, y=y.astype(np.float32), C=C.astype(np.float32), lobe=lobe), float(columns.log_jacobian)


def _lobe_terms(columns: Columns, CB, inverse_scale) -> LobeTerms:
    empty = np.zeros(0, np.float32)
    second = empty
    if columns.second_lobe is not None:
        second = columns.second_lobe if inverse_scale is None else columns.second_lobe * inverse_scale
        second = second.astype(np.float32)
    tan_v, tan_l = (empty, empty) if columns.tan is None else (np.asarray(t, np.float32) for t in columns.tan)
    amb, amb_j, amb_fy, table, grid = empty, np.zeros(0, np.int32), empty, np.zeros((2, 2)), np.array([0.0, 1.0, 1.0])
    if columns.ambient is not None:
        amb_j, amb_fy, table, grid = columns.ambient_terms
        amb = np.full(CB.shape, columns.ambient) if inverse_scale is None else columns.ambient * inverse_scale
        amb = amb.astype(np.float32)
    return LobeTerms(cb=CB.astype(np.float32), mask_w=float(columns.mask_w), tan_v=tan_v, tan_l=tan_l, amb=amb,
                     amb_j=np.asarray(amb_j, np.int32), amb_fy=np.asarray(amb_fy, np.float32),
                     table=np.asarray(table, float), grid=np.asarray(grid, float), ggx_w=float(columns.ggx_w),
                     second=second)


class ForwardModel(ABC):
    """The BRDF family plus effects: builds the :class:`Problem` the region sampler runs on.

    Subclasses implement :meth:`problem` (observations -> sorted, compacted columns; with
    effects, the problem carries them in an :class:`EffectData`, and :func:`transformed`
    applies them at given parameters).
    """

    effects: tuple = ()

    @abstractmethod
    def problem(self, observations: Observations, *, likelihood_power: float = 1.0, noise_scale=None,
                normal_prior_sd: float | None = None) -> Problem:
        """The untransformed :class:`Problem` of ``observations``."""


class LambertBlinnPhong(ForwardModel):
    """The paper's model (eq. 2): Lambert plus energy-normalised Blinn-Phong, with ``effects`` (none: the paper's).

    ``effects``: :class:`~rjfit.effects.base.FitForm` objects whose features are in the order of the observations
    the problem is built from; they are applied in stage order.

    Raises
    ------
    ValueError
        For an effect of an unknown stage, two effects of one name, or two camera responses.
    """

    def __init__(self, effects=()):
        unknown = [e.stage for e in effects if e.stage not in STAGES]
        if unknown:
            raise ValueError(f"effect stages {unknown}: choose from {', '.join(STAGES)}")
        names = [e.name for e in effects]
        if len(set(names)) != len(names):
            raise ValueError(f"an effect is named twice: {names}")
        cameras = [e.name for e in effects if e.stage == "camera"]
        if len(cameras) > 1:        # two curves would need their inverses in reverse order: one response per camera
            raise ValueError(f"one camera response per fit, got {', '.join(cameras)}")
        self.effects = tuple(sorted(effects, key=stage_key))

    def problem(self, observations: Observations, *, likelihood_power: float = 1.0, noise_scale=None,
                normal_prior_sd: float | None = None) -> Problem:
        """Sort, compact and (optionally) weight the observations.

        Parameters
        ----------
        observations : Observations
        likelihood_power : float
            zeta in (0, 1].
        noise_scale : array_like (N,), optional
            Known noise scales ``s_i > 0`` in the order of ``observations`` (see
            :mod:`rjfit.data.noise`); None: homoscedastic noise (every ``s_i = 1``).
        normal_prior_sd : float, optional
            The pixels' normals are sampled (:mod:`rjfit.sampler.normals`) with this prior sd of
            each tangent coordinate (``tan(sigma_n)``): the problem carries their
            :class:`NormalData`. None: the normals are the given ones.

        Raises
        ------
        ValueError
            For a likelihood power outside (0, 1], no observation, ``<l.n> <= 0``, or a
            noise scale of the wrong shape or not finite and positive; for sampled normals
            with effects, with several channels, without the observations' ``tangent`` or
            with a prior sd that is not positive.
        """
        obs = observations
        if not 0.0 < likelihood_power <= 1.0:
            raise ValueError(f"likelihood_power must lie in (0, 1], got {likelihood_power}")
        if obs.n_obs == 0:
            raise ValueError("no valid observation: nothing to fit (check the object mask and validity thresholds)")
        if np.any(obs.cos_ln <= 0):
            raise ValueError("observations with <l.n> <= 0 are not valid: filter them with valid_observation_mask")
        if obs.n_channels > 1 and self.effects:
            raise ValueError("effects inside the fit are for single-channel fits; a joint colour fit (--channel rgb) "
                             "takes none")
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
        effects = None
        if self.effects:
            effects = EffectData(effects=tuple(e.in_order(order) for e in self.effects),
                                 y=np.asarray(obs.y, float)[order],
                                 C=np.asarray(obs.irradiance, float)[order] * np.asarray(obs.cos_ln, float)[order],
                                 light=np.asarray(obs.light)[order].astype(np.int32),
                                 scale=None if scale is None else scale.astype(np.float64))
        normals = None if normal_prior_sd is None else _normal_data(obs, order, C, normal_prior_sd, self.effects)
        channel = None if obs.channel is None else np.asarray(obs.channel)[order].astype(np.int8)
        light = np.asarray(obs.light)[order].astype(np.int16 if obs.n_lights <= np.iinfo(np.int16).max else np.int32)
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
                       likelihood_power=float(likelihood_power), noise_scale=scale, effects=effects,
                       channel=channel, n_channels=int(obs.n_channels), light=light, normals=normals)


def _normal_data(obs: Observations, order, C, prior_sd, effects) -> NormalData:
    """The :class:`NormalData` of sampled normals, in the problem's ``order``; ``C`` the problem's own column."""
    if effects or obs.n_channels > 1:
        raise ValueError("sampled normals (--normals sample) are for a single channel without effects")
    if obs.tangent is None:
        raise ValueError("sampled normals need each observation's tangent-frame components (Observations.tangent): "
                         "build the observations with tangents=True")
    if not (np.isfinite(prior_sd) and prior_sd > 0):
        raise ValueError(f"the normals' prior sd must be positive, got {prior_sd}")
    return NormalData(C=C, cos_ln=np.asarray(obs.cos_ln)[order].astype(np.float32),
                      cos_hn=np.asarray(obs.cos_hn)[order].astype(np.float32),
                      tangent=np.ascontiguousarray(np.asarray(obs.tangent)[order], dtype=np.float32),
                      prior_sd=float(prior_sd))


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
