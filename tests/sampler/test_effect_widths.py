"""The effect move's widths follow the annealed likelihood power between refreshes (issue 44, item 3).

Under the kernel's annealed warm-up the power grows geometrically, so Laplace widths measured
``curvature_every`` iterations earlier do not fit the tempered conditional they propose on;
the move uses a width measured at power ``p_w`` at power ``p`` times ``sqrt(p_w / p)``
(:mod:`rjfit.sampler.moves.effects`). Checked on a real chain (a 12 x 12 sphere stack, 5
lights, the light gains' 4 Helmert coordinates, no structure moves): the state records the
power of each refresh, and the refreshed widths themselves scale as ``1 / sqrt(power)`` (the
rule's premise). A few seconds.
"""
import numpy as np
from threadpoolctl import threadpool_limits

from rjfit.data.synthetic import sphere_stack
from rjfit.effects.light_calibration import LightGains
from rjfit.sampler.forward import LambertBlinnPhong
from rjfit.sampler.kernel import ChainContext, anneal_power, initial_state, step
from rjfit.sampler.priors import make_prior
from rjfit.sampler.state import SamplerConfig

from test_effect_passes import every_effect

ANNEAL = 200
EVERY = 50          # EffectSettings.curvature_every's default


def test_the_widths_record_their_power_and_scale_as_its_inverse_square_root():
    obs, _, _ = sphere_stack(12, n_lights=5, seed=4)
    gains = [effect for effect in every_effect(obs, seed=2) if isinstance(effect, LightGains)]
    problem = LambertBlinnPhong(gains).problem(obs)
    prior = make_prior("default", y=problem.y, diffuse_scale=problem.A)
    config = SamplerConfig.from_flat(burn_in=ANNEAL, anneal=ANNEAL, max_u=0, max_v=0, update_changepoints=False,
                                     jumps=False)
    rng = np.random.default_rng(3)
    state = initial_state(problem, prior, config, rng)
    context = ChainContext()
    refreshed = {}
    with threadpool_limits(1):
        for t in range(ANNEAL):
            state, _ = step(state, rng, problem, prior, config, context)
            power = anneal_power(config.kernel, t - t % EVERY)        # the power at the last refresh
            assert state.effects.widths_power == power
            if t % EVERY == 0:
                refreshed[t] = (power, state.effects.widths.copy())
    # the premise of sqrt(p_w / p): a width times sqrt(its power) stays put as the power grows
    # 32-fold (0.0056 at t = 50 to 0.18 at t = 150; the widths themselves shrink 6.7 to 7.8-fold).
    # Tolerance: a factor 1.5, for the prior's share of the curvature at the smallest power and
    # the chain's moves between refreshes (measured ratios 0.72 to 0.84)
    p_low, w_low = refreshed[50]
    p_high, w_high = refreshed[150]
    ratio = (w_high * np.sqrt(p_high)) / (w_low * np.sqrt(p_low))
    assert np.all((ratio > 1 / 1.5) & (ratio < 1.5)), ratio
    assert np.all(w_high < w_low / 4)
