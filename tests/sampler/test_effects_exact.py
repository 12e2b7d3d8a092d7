"""Exactness of the kernel with effects inside the likelihood (issue 26), as the plain kernel's is tested.

- **Incremental statistics** against a full recompute: after every step of a chain with one
  effect of each kind and busy structure moves (change points; material labels), the cached statistics, log-likelihood and
  log-Jacobian equal those recomputed on the problem transformed at the state's effect
  parameters (and the oracle), to 1e-9 of their scale.
- **Quadrature** on the tiny problem of ``test_exact_rj.py`` (one region, fixed segmentation):
  for a light gain (two lights: one Helmert coordinate), the sRGB and power-law cameras (with
  their log-Jacobians: the noise before the curve) and ambient light, the effect parameter's marginal and the region's
  (I0, kd, gamma) marginals against the exact posterior: a grid over the effect parameter,
  the quadrature of ``test_exact_rj.Quadrature`` at each of its values (sigma^2 integrated
  analytically), the log-Jacobian added. One-sample KS on draws thinned to about one per
  effective sample, level 0.001 (fixed seeds).
- **Enumeration** with ambient light: model and change-point frequencies (ESS-scaled
  chi-square) and the ambient term's marginal (KS) against the exact posterior, the
  enumeration of ``builders.exact_changepoint_posterior`` integrated over the ambient term;
  for the material model, the frequencies of the 15 partitions of the 2 x 2 image and of K
  (``builders.exact_partition_posterior`` integrated over the ambient term).
- **SBC** (Talts et al. 2018) with a light gain, ambient light and the sRGB camera at once,
  data simulated from the extended model (noise on the linearised scale, as the fit's
  likelihood has it): the ranks of all seven true parameters among 19 thinned draws must be
  uniform (chi-square of 5 bins, level 0.001); the same with a dielectric coating alone (its share and
  index with the region's four parameters), and with a rough coating alone (share, index and roughness).

A control shows the tests bite: leaving the camera's log-Jacobian out of the effect move's
ratio moves the white level's marginal far from the exact one (p < 1e-6).
"""
import dataclasses

import numpy as np
import pytest
from scipy import stats
from test_effect_passes import every_effect, lobe_shapes
from threadpoolctl import threadpool_limits

from rjfit.data.observations import Observations
from rjfit.data.synthetic import sphere_stack
from rjfit.model.blinn import radiance
from rjfit.effects.ambient import ALBEDO_LOG_GAMMA, AmbientLight, albedo_table, cos_v_weights, lobe_albedo
from rjfit.effects.base import Param
from rjfit.effects.camera_gamma import GammaCurve
from rjfit.effects.camera_srgb import SRGBCurve, srgb_decode, srgb_decode_log_slope
from rjfit.effects.coating import CoatingFactors
from rjfit.effects.rough_coating import RoughCoatingFactors
from rjfit.effects.light_calibration import LightGains
from rjfit.model.priors import LogitNormal, LogNormal, Normal
from rjfit.sampler.forward import LambertBlinnPhong, transformed
from rjfit.sampler.kernel import ChainContext, initial_state, step
from rjfit.sampler.likelihood import oracle_log_likelihood, region_stats
from rjfit.sampler.moves import effects as effect_moves
from rjfit.sampler.state import SamplerConfig

from builders import (
    Quadrature,
    canonical,
    ess_scaled_chi2,
    exact_changepoint_posterior,
    exact_partition_posterior,
    tiny_problem,
)

LEVEL = 1e-3           # per test: the suite's many exactness tests stay unlikely to fail by chance together
GRID = np.array([ALBEDO_LOG_GAMMA[0], ALBEDO_LOG_GAMMA[-1], ALBEDO_LOG_GAMMA[1] - ALBEDO_LOG_GAMMA[0]])
Z_POINTS = 31


STRUCTURE_MOVES = {
    "changepoints": dict(max_u=2, max_v=2, jump_prob=0.7, block_prob=0.4, vector_prob=0.7, cp_uniform_prob=0.3),
    # the material model: Gibbs sweeps, cluster, merge/split and segment moves
    "materials": dict(region_model="materials", max_materials=5, cluster_moves=2, merge_split_moves=1,
                      segment_moves=2, potts_beta=1.0),
}


@pytest.mark.parametrize("regions, lobes", [("changepoints", False), ("materials", False), ("changepoints", True),
                                            ("materials", True)])
def test_incremental_statistics_equal_a_full_recompute_with_effects(regions, lobes):
    """``lobes``: the lobe shapes (a GGX lobe mixed in, a second lobe) on top of every effect."""
    obs, _, _ = sphere_stack(12, n_lights=5, seed=4)
    forms = every_effect(obs, seed=2) + (lobe_shapes(obs, seed=2) if lobes else [])
    problem = LambertBlinnPhong(forms).problem(obs, likelihood_power=0.7)
    from rjfit.sampler.priors import make_prior

    prior = make_prior("default", y=problem.y, diffuse_scale=problem.A)
    config = SamplerConfig.from_flat(burn_in=60, anneal=0, refresh_every=0, **STRUCTURE_MOVES[regions])
    rng = np.random.default_rng(11)
    # change points start with vectors to move (from one region no birth is accepted on this stack)
    state = initial_state(problem, prior, config, rng, **({"model": (1, 1)} if regions == "changepoints" else {}))
    context = ChainContext()
    accepted, relabelled = 0, 0
    with threadpool_limits(1):
        # 240 steps: accepted effect and structure moves well above 20 on every parametrisation
        for _ in range(240):
            labels_before = state.labels
            state, info = step(state, rng, problem, prior, config, context)
            accepted += sum(v for k, v in info.accepted.items() if k.startswith("effect_"))
            relabelled += int(np.any(state.labels != labels_before))
            current, log_jacobian = transformed(problem, state.effects.z)
            stats = region_stats(current, state.labels, state.theta[:, 2], state.n_regions)
            scale = np.maximum(1.0, np.abs(stats))
            assert np.max(np.abs(state.stats - stats) / scale) < 1e-9
            assert state.total_log_lik == pytest.approx(oracle_log_likelihood(current, state.labels, state.theta),
                                                        rel=1e-9, abs=1e-6)
            assert state.effects.log_jacobian == pytest.approx(log_jacobian, rel=1e-12, abs=1e-9)
    assert accepted > 20, "the effect moves must be accepted for the test to bite"
    assert relabelled > 20, "the structure moves must relabel observations for the test to bite"


def test_camera_log_jacobian_is_the_log_slope_of_the_inverse():
    """The camera curves' log-Jacobian against central differences of their inverses (relative step 1e-6)."""
    y = np.array([0.001, 0.02, 0.3, 0.7, 1.0, 1.4]) * 10.0
    for curve, theta in ((SRGBCurve, 1.3), (GammaCurve, 2.2)):
        effect = curve(params=(Param("p", LogNormal(0.0, 1.0), 1.0),), white_level=10.0)
        problem = LambertBlinnPhong([effect]).problem(_observations(y))
        z = np.array([np.log(theta)])
        columns = problem.effects.columns(z)
        h = 1e-6 * problem.effects.y
        plus, minus = (LambertBlinnPhong([effect]).problem(_observations(y + d)).effects.columns(z).y for d in (h, -h))
        slope = (plus - minus) / (2 * h)
        assert columns.log_jacobian == pytest.approx(float(np.sum(np.log(slope))), rel=1e-6, abs=1e-6)


def _observations(y):
    n = len(y)
    return Observations(image_shape=(1, n), n_lights=1, pixel=np.arange(n), light=np.zeros(n, np.int32), y=np.asarray(y),
                        cos_ln=np.full(n, 0.5), cos_hn=np.full(n, 0.9), irradiance=np.ones(n),
                        object_mask=np.ones((1, n), bool))


# -- exact posteriors with an effect: a grid over the effect parameter, the quadrature at each value ----------------

class EffectQuadrature:
    """The exact posterior of a tiny problem with one effect of one parameter ``z`` (unconstrained).

    At each value of ``z`` on a grid, a :class:`test_exact_rj.Quadrature` whose squared
    residuals are those of the extended model (computed here from eq. 2 and
    :mod:`rjfit.effects`' physics, independently of the sampler); the log-Jacobian of a camera
    adds to the evidence of the whole data set. The z grid: 17 points over the prior centre
    +- 6 prior sd, then :data:`Z_POINTS` over where the posterior is above e^-25 of its
    largest value (a spacing of about a third of the posterior sd: the trapezoid rule on the
    smooth posterior is far more accurate than the KS tests can see). ``points`` per axis of the region parameters: 81 for marginal CDFs (their
    piecewise-linear interpolation between the nodes is off by up to 0.03 at 41 points, by
    under 0.005 at 81), 41 for evidences (within 1e-4 of 81's, ``test_exact_rj``).
    """

    def __init__(self, obs, prior, kind, z_prior, cos_v=None, white=None, points=81):
        self.kind, self.z_prior, self.white = kind, z_prior, white
        self.obs = obs
        self.quad = Quadrature(obs, prior, points=points)
        g0, g1, g2 = np.meshgrid(*self.quad.axes, indexing="ij")
        I0, kd, g = np.exp(g0), 1 / (1 + np.exp(-g1)), np.exp(g2)
        self.mu = np.stack([radiance(I0, kd, g, obs.cos_ln[i], obs.cos_hn[i], obs.irradiance[i])
                            for i in range(obs.n_obs)])
        if kind == "ambient":
            self.amb = np.stack([I0 * (kd + (1 - kd) * lobe_albedo(g, cos_v[i])) for i in range(obs.n_obs)])
        self.z = np.linspace(z_prior.loc - 6 * z_prior.scale, z_prior.loc + 6 * z_prior.scale, 17)

    def at(self, z):
        """The quadrature at ``z`` (its squared residuals replaced) and the log-Jacobian there."""
        value = float(self.z_prior.to_constrained(z))
        y, log_jacobian = self.obs.y[:, None, None, None], 0.0
        if self.kind == "gain":
            gains = np.exp(np.array([1.0, -1.0]) / np.sqrt(2.0) * value)      # Helmert basis of two lights
            mean = self.mu * gains[self.obs.light][:, None, None, None]
        elif self.kind == "ambient":
            mean = self.mu + value * self.amb
        elif self.kind == "camera_gamma":        # y = W (mu / W)^(1/k): linearised, W (y / W)^k
            u = self.obs.y / self.white
            y = (self.white * u ** value)[:, None, None, None]
            log_jacobian = float(np.sum(np.log(value) + (value - 1.0) * np.log(u)))
            mean = self.mu
        else:
            white = value * self.white
            y = white * srgb_decode(self.obs.y / white)[:, None, None, None]
            log_jacobian = float(np.sum(srgb_decode_log_slope(self.obs.y / white)))
            mean = self.mu
        self.quad.sq = (y - mean) ** 2
        self.quad._cache = {}
        return self.quad, log_jacobian

    def _log_posterior(self, log_evidence_at):
        log_w = []
        for z in self.z:
            quad, log_jacobian = self.at(z)
            log_w.append(log_evidence_at(quad, z) + log_jacobian + float(self.z_prior.log_prob_unconstrained(z)))
        return np.array(log_w)

    def z_weights(self, log_evidence_at):
        """Normalised posterior weights (trapezoid) of the z grid, refined where the posterior is, from
        ``log_evidence_at(quad, z) -> float``; ``self.z`` is that grid afterwards."""
        log_w = self._log_posterior(log_evidence_at)
        inside = self.z[log_w > log_w.max() - 25.0]
        step = self.z[1] - self.z[0]
        self.z = np.linspace(inside.min() - step, inside.max() + step, Z_POINTS)
        log_w = self._log_posterior(log_evidence_at) + np.log(np.gradient(self.z))
        return np.exp(log_w - np.logaddexp.reduce(log_w))

    def z_cdf(self, weights):
        cdf = np.concatenate([[0.0], np.cumsum(0.5 * (weights[1:] + weights[:-1]))])
        cdf /= cdf[-1]
        return lambda x: np.interp(x, self.z, cdf)

    def region_cdfs(self, weights, pixels):
        """The region's (I0, kd, gamma) marginal CDFs: mixtures over the z grid."""
        per_z = []
        for z, w in zip(self.z, weights):
            if w > 1e-6:
                quad, _ = self.at(z)
                per_z.append((w, quad.marginal_cdfs(pixels, with_sigma2=False)))
        total = sum(w for w, _ in per_z)
        return [lambda x, k=k: sum(w * cdfs[k](x) for w, cdfs in per_z) / total for k in range(3)]


def _thinned(values):
    import arviz as az

    ess = float(az.ess(np.asarray(values)[None], method="bulk"))
    return np.asarray(values)[::max(1, int(np.ceil(len(values) / ess)))]


def _fixed_chain(problem, prior, iterations, seed, burn=600, **flat):
    config = SamplerConfig.from_flat(max_u=0, max_v=0, update_changepoints=False, jumps=False, burn_in=burn, anneal=0,
                                     **flat)
    rng = np.random.default_rng(seed)
    state = initial_state(problem, prior, config, rng)
    z, theta = np.zeros(iterations), np.zeros((iterations, 4))
    context = ChainContext()
    with threadpool_limits(1):
        for t in range(iterations):
            state, _ = step(state, rng, problem, prior, config, context)
            z[t], theta[t] = state.effects.z[0], state.theta[0]
    return z[burn:], theta[burn:]


def _subset(obs, keep, n_lights):
    return Observations(image_shape=obs.image_shape, n_lights=n_lights, pixel=obs.pixel[keep], light=obs.light[keep],
                        y=obs.y[keep], cos_ln=obs.cos_ln[keep], cos_hn=obs.cos_hn[keep],
                        irradiance=obs.irradiance[keep], object_mask=obs.object_mask)


def _case(kind):
    """(observations, region prior, sampler effect, its prior, EffectQuadrature keywords) of a one-effect tiny problem."""
    obs, prior = tiny_problem()
    if kind == "gain":
        obs = _subset(obs, obs.light < 2, n_lights=2)
        z_prior = Normal(0.0, 0.3)
        return obs, prior, LightGains(params=(Param("h1", z_prior, 0.0),), n_lights=2), z_prior, {}
    if kind == "ambient":
        z_prior = LogNormal(np.log(0.3), 0.5)
        cos_v = np.random.default_rng(8).uniform(0.3, 1.0, obs.n_obs)
        column, weight = cos_v_weights(cos_v)
        effect = AmbientLight(params=(Param("ambient", z_prior, 0.3),), column=column.astype(np.int32),
                              weight=weight, table=albedo_table(), grid=GRID)
        return obs, prior, effect, z_prior, {"cos_v": cos_v}
    if kind == "camera_gamma":
        obs = _subset(obs, obs.y > 0, n_lights=obs.n_lights)        # the power law's inverse needs y > 0
        z_prior = LogNormal(np.log(1.2), 0.3)
        white = float(np.max(obs.y))
        return obs, prior, GammaCurve(params=(Param("k", z_prior, 1.2),), white_level=white), z_prior, {"white": white}
    z_prior = LogNormal(np.log(1.2), 0.3)
    white = float(np.max(obs.y))
    effect = SRGBCurve(params=(Param("white_rel", z_prior, 1.2),), white_level=white)
    return obs, prior, effect, z_prior, {"white": white}


@pytest.fixture(scope="module")
def exact_marginals():
    """``get(kind)``: the exact posterior of the one-region case ``kind`` (its quadrature and z weights), once per kind."""
    cache = {}

    def get(kind):
        if kind not in cache:
            obs, prior, _, z_prior, extra = _case(kind)
            exact = EffectQuadrature(obs, prior, kind, z_prior, **extra)
            cache[kind] = exact, exact.z_weights(lambda quad, z: quad.log_evidence([0, 1, 2, 3]))
        return cache[kind]
    return get


@pytest.mark.parametrize("kind", ["gain", "camera_srgb", "camera_gamma", "ambient"])
def test_effect_and_region_marginals_match_quadrature(kind, exact_marginals):
    obs, prior, effect, z_prior, extra = _case(kind)
    problem = LambertBlinnPhong([effect]).problem(obs)
    exact, weights = exact_marginals(kind)
    pixels = [0, 1, 2, 3]
    z, theta = _fixed_chain(problem, prior, 3000, seed=3)
    assert stats.kstest(_thinned(z), exact.z_cdf(weights)).pvalue > LEVEL
    for k, cdf in enumerate(exact.region_cdfs(weights, pixels)):
        draws = _thinned(theta[:, k])
        assert stats.kstest(draws, cdf).pvalue > LEVEL, (k, len(draws))


def test_a_move_without_the_camera_s_log_jacobian_samples_another_posterior(monkeypatch, exact_marginals):
    """Negative control: the sRGB camera's white level, the log-Jacobian dropped from the ratio."""
    obs, prior, effect, _, _ = _case("camera_srgb")
    problem = LambertBlinnPhong([effect]).problem(obs)
    exact, weights = exact_marginals("camera_srgb")
    original = effect_moves.transformed
    monkeypatch.setattr(effect_moves, "transformed", lambda p, z: (original(p, z)[0], 0.0))
    z, _ = _fixed_chain(problem, prior, 2000, seed=3)
    assert stats.kstest(_thinned(z), exact.z_cdf(weights)).pvalue < 1e-6


def test_model_changepoint_and_ambient_frequencies_match_enumeration():
    obs, prior, effect, z_prior, extra = _case("ambient")
    problem = LambertBlinnPhong([effect]).problem(obs)
    exact = EffectQuadrature(obs, prior, "ambient", z_prior, points=41, **extra)
    posteriors = {}

    def log_evidence_at(quad, z):
        posteriors[z], log_norm = exact_changepoint_posterior(quad, cp_prior="paper", log_norm=True)
        return log_norm

    weights = exact.z_weights(log_evidence_at)
    keys = posteriors[exact.z[0]]
    joint = {key: sum(w * posteriors[z][key] for z, w in zip(exact.z, weights)) for key in keys}
    config = SamplerConfig.from_flat(max_u=1, max_v=1, split_scale=0.6, jump_prob=1.0, cp_step=1.0, cp_uniform_prob=0.3,
                                     burn_in=500, anneal=0, cp_prior="paper")
    rng = np.random.default_rng(5)
    state = initial_state(problem, prior, config, rng, model=(0, 0))
    iterations, burn = 5000, 500
    models, u0, z = np.zeros((iterations, 2), int), np.full(iterations, -1), np.zeros(iterations)
    context = ChainContext()
    with threadpool_limits(1):
        for t in range(iterations):
            state, _ = step(state, rng, problem, prior, config, context)
            models[t], z[t] = state.layout.model_key, state.effects.z[0]
            if state.layout.n_u:
                u0[t] = int(np.searchsorted([0.5, 1.5], state.layout.u[0, 0], side="right"))
    models, u0, z = models[burn:], u0[burn:], z[burn:]
    cells = [(0, 0), (0, 1), (1, 0), (1, 1)]
    p_model = np.array([sum(p for k, p in joint.items() if k[:2] == m) for m in cells])
    assert min(p_model) > 0.02, "the exact posterior should spread over the models for the test to bite"
    p_value, freq, n_eff = ess_scaled_chi2([0, 1, 2, 3], models[:, 0] * 2 + models[:, 1], p_model)
    assert p_value > LEVEL, (freq, p_model, n_eff)
    with_u = models[:, 0] == 1
    p_u = np.array([sum(p for k, p in joint.items() if k[0] == 1 and k[2] == c) for c in range(3)])
    p_value, freq, n_eff = ess_scaled_chi2([0, 1, 2], u0[with_u], p_u / p_u.sum())
    assert p_value > LEVEL, (freq, p_u / p_u.sum(), n_eff)
    assert stats.kstest(_thinned(z), exact.z_cdf(weights)).pvalue > LEVEL


def test_material_partition_and_ambient_frequencies_match_enumeration():
    """The material model with ambient light sampled: all 15 partitions of the 2 x 2 image (K_max 4;
    Gibbs sweeps, cluster and merge/split moves, the effect move), their frequencies and K's
    against the exact posterior (the enumeration of ``builders.exact_partition_posterior``
    integrated over the ambient term), and the ambient term's marginal (KS)."""
    obs, prior, effect, z_prior, extra = _case("ambient")
    # the data hold ambient light 0.3 (the prior's centre), so its lobe term (up to about 4 noise sd here)
    # weighs in every material's likelihood: label moves that left it out would sample another posterior
    right = (obs.pixel % 2 == 1)
    I0, kd, gamma = 10.0, np.where(right, 0.3, 0.75), np.where(right, 15.0, 4.0)
    obs = dataclasses.replace(obs, y=obs.y + 0.3 * I0 * (kd + (1 - kd) * lobe_albedo(gamma, extra["cos_v"])))
    problem = LambertBlinnPhong([effect]).problem(obs)
    exact = EffectQuadrature(obs, prior, "ambient", z_prior, points=41, **extra)
    beta, rho = 1.0, 0.5
    posteriors = {}

    def log_evidence_at(quad, z):
        posteriors[z], log_norm = exact_partition_posterior(quad, (2, 2), beta, rho, log_norm=True)
        return log_norm

    weights = exact.z_weights(log_evidence_at)
    joint = {part: sum(w * posteriors[z][part] for z, w in zip(exact.z, weights)) for part in posteriors[exact.z[0]]}
    config = SamplerConfig.from_flat(region_model="materials", max_materials=4, potts_beta=beta, potts_rho=rho,
                                     cluster_moves=2, merge_split_moves=1, burn_in=300, anneal=0)
    rng = np.random.default_rng(6)
    state = initial_state(problem, prior, config, rng)
    iterations, burn = 4000, 300
    parts, z = [], np.zeros(iterations)
    context = ChainContext()
    with threadpool_limits(1):
        for t in range(iterations):
            state, _ = step(state, rng, problem, prior, config, context)
            parts.append(canonical(state.layout.pixels.ravel()))
            z[t] = state.effects.z[0]
    parts, z = parts[burn:], z[burn:]
    cells = list(joint)
    p_value, freq, n_eff = ess_scaled_chi2(list(range(len(cells))), np.array([cells.index(p) for p in parts]),
                                           np.array([joint[c] for c in cells]))
    assert p_value > LEVEL, (freq, n_eff)
    ks = sorted({max(p) + 1 for p in cells})
    p_k = np.array([sum(v for p, v in joint.items() if max(p) + 1 == k) for k in ks])
    assert np.sort(p_k)[-2] > 0.05, "the exact posterior should spread over K for the test to bite"
    p_value, freq, n_eff = ess_scaled_chi2(ks, np.array([max(p) + 1 for p in parts]), p_k)
    assert p_value > LEVEL, (freq, p_k, n_eff)
    assert stats.kstest(_thinned(z), exact.z_cdf(weights)).pvalue > LEVEL


# -- SBC with three effects at once --------------------------------------------------------------------------------

def _sbc_effects(obs, cos_v):
    column, weight = cos_v_weights(cos_v)
    return [LightGains(params=(Param("h1", Normal(0.0, 0.3), 0.0),), n_lights=2),
            AmbientLight(params=(Param("ambient", LogNormal(np.log(0.3), 0.5), 0.3),),
                         column=column.astype(np.int32), weight=weight, table=albedo_table(), grid=GRID),
            SRGBCurve(params=(Param("white_rel", LogNormal(np.log(1.5), 0.2), 1.5),), white_level=12.0)]


def _simulate(base, effects, theta, z, rng):
    """Raw data from the extended model: ``f(mu + e)``, e ~ N(0, sigma^2) on the linearised scale."""
    problem = LambertBlinnPhong(effects).problem(base)
    current, _ = transformed(problem, z)
    from rjfit.sampler.likelihood import ab_from_theta, lobe_column

    a, b = ab_from_theta(theta)
    mean = a * current.C.astype(float) / np.pi + b * lobe_column(current, slice(None), np.full(base.n_obs, theta[2]))
    linear = mean + rng.normal(0.0, np.sqrt(theta[3]), mean.shape)
    y = np.empty(base.n_obs)
    y[np.argsort(base.pixel, kind="stable")] = problem.effects.columns(z).data_scale(linear)
    return Observations(image_shape=base.image_shape, n_lights=2, pixel=base.pixel, light=base.light, y=y,
                        cos_ln=base.cos_ln, cos_hn=base.cos_hn, irradiance=base.irradiance,
                        object_mask=base.object_mask)


def _sbc_base(rng, H=4, W=4, L=2):
    """A 4 x 4 image under 2 lights with random geometry: the observations SBC simulates on."""
    pixel = np.repeat(np.arange(H * W), L).astype(np.int64)
    return Observations(image_shape=(H, W), n_lights=L, pixel=pixel, light=np.tile(np.arange(L), H * W).astype(np.int32),
                        y=np.ones(pixel.size), cos_ln=rng.uniform(0.3, 1.0, pixel.size),
                        cos_hn=rng.uniform(0.6, 1.0, pixel.size), irradiance=rng.uniform(0.5, 1.5, pixel.size),
                        object_mask=np.ones((H, W), bool))


def _sbc_ranks(base, effects, rng, replicates=60, draws=19, thin=8, burn=120):
    """Ranks of the true region and effect parameters among ``draws`` thinned draws of a chain on data
    simulated from the extended model, per replicate: (replicates, 4 + effect parameters)."""
    _, prior = tiny_problem()
    config = SamplerConfig.from_flat(max_u=0, max_v=0, update_changepoints=False, jumps=False, burn_in=burn, anneal=0)
    n_effect = sum(e.n_params for e in effects)
    ranks = np.zeros((replicates, 4 + n_effect), int)
    with threadpool_limits(1):
        for i in range(replicates):
            theta = prior.sample(rng)
            z_of = {e.name: np.array([p.prior.loc + p.prior.scale * rng.normal() for p in e.params]) for e in effects}
            order = [e.name for e in LambertBlinnPhong(effects).effects]       # the problem's (stage) order
            z_true = np.concatenate([z_of[name] for name in order])
            problem = LambertBlinnPhong(effects).problem(_simulate(base, effects, theta, z_true, rng))
            state = initial_state(problem, prior, config, rng, theta=prior.sample(rng)[None])
            kept, context = [], ChainContext()
            for t in range(burn + draws * thin):
                state, _ = step(state, rng, problem, prior, config, context)
                if t >= burn and (t - burn) % thin == thin - 1:
                    kept.append(np.concatenate([state.theta[0], state.effects.z]))
            ranks[i] = (np.array(kept) < np.concatenate([theta, z_true])).sum(axis=0)
    return ranks


def _uniform_rank_p_values(ranks):
    """Chi-square p-value of each parameter's ranks (0..19) in 5 bins."""
    return [stats.chisquare(np.bincount(ranks[:, k] // 4, minlength=5)).pvalue for k in range(ranks.shape[1])]


def test_sbc_ranks_are_uniform_with_three_effects():
    rng = np.random.default_rng(2026)
    base = _sbc_base(rng)
    ranks = _sbc_ranks(base, _sbc_effects(base, rng.uniform(0.3, 1.0, base.n_obs)), rng)
    p_values = _uniform_rank_p_values(ranks)
    assert ranks.shape[1] == 7 and min(p_values) > LEVEL, (p_values, ranks)


def _coating_ranks(form, extra_params, seed):
    """SBC ranks with a coating's fit form ``form`` alone: its share and index, with ``extra_params`` after them."""
    rng = np.random.default_rng(seed)
    base = _sbc_base(rng)
    coating = form(params=(Param("w_coat", LogitNormal(0.0, 2.0), 0.5),
                           Param("eta", LogitNormal(-0.5, 1.5, low=1.2, high=2.0), 1.5)) + extra_params,
                   cos_l=base.cos_ln, cos_v=rng.uniform(0.2, 1.0, base.n_obs), cos_hv=rng.uniform(0.4, 1.0, base.n_obs))
    return _sbc_ranks(base, [coating], rng)


def test_sbc_ranks_are_uniform_with_a_coating():
    """The coating's two parameters (share w, index eta) with the region's four: its factors on both columns
    are sampled exactly (same design and level as the test above)."""
    ranks = _coating_ranks(CoatingFactors, (), 2027)
    p_values = _uniform_rank_p_values(ranks)
    assert ranks.shape[1] == 6 and min(p_values) > LEVEL, (p_values, ranks)


def test_sbc_ranks_are_uniform_with_a_rough_coating():
    """The rough coating's three parameters (share w, index eta, the interface's roughness) with the region's four:
    its factors, a table per (alpha, eta), are sampled exactly (same design and level as the tests above)."""
    ranks = _coating_ranks(RoughCoatingFactors, (Param("alpha_coat", LogitNormal(-0.9, 1.5, low=0.02, high=1.0), 0.3),),
                           2028)
    p_values = _uniform_rank_p_values(ranks)
    assert ranks.shape[1] == 7 and min(p_values) > LEVEL, (p_values, ranks)
