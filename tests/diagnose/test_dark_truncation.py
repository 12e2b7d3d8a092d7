"""A declared dark threshold truncates the criticism's likelihood (issue 44, the gamma row).

An observation at or below a data set's ``dark`` never enters the fit, so those kept are a
sample truncated at ``dark``: where the mean is within a few noise sd of it, the kept values
are biased upward. The refits' likelihood of a kept observation is the truncated normal
(:mod:`rjfit.diagnose.objective`). Data: the power-law camera stack
(:mod:`rjfit.render.hidden` ``camera_gamma_sensor``: read noise before ``W (x/W)^(1/2.2)``,
negative sums clipped at 0, ``dark: 0``), real Mitsuba at 32 x 32 (a few seconds), truth labels.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.stats import norm

from rjfit.diagnose.context import build_context, declared_dark
from rjfit.diagnose.objective import RefitObjective
from rjfit.diagnose.refit import refit
from rjfit.effects import EFFECTS

LN_100 = math.log(100.0)


@pytest.fixture(scope="module")
def power_law_stack(tmp_path_factory):
    from rjfit.render.datasets import load_dataset
    from rjfit.render.hidden import render_hidden

    return load_dataset(render_hidden("camera_gamma_sensor", tmp_path_factory.mktemp("dark") / "d", resolution=32))


def _untruncated(ctx):
    return dataclasses.replace(ctx, dark=None, features={})


def test_declared_dark_is_a_value_in_the_data_s_units():
    class Meta:
        def __init__(self, meta):
            self.meta = meta
    assert declared_dark(Meta({"dark": 0})) == 0.0 and declared_dark(Meta({"dark": 0.25})) == 0.25
    assert declared_dark(Meta({})) is None and declared_dark(Meta({"dark": None})) is None
    # a photometric-stereo folder's threshold is on raw codes (per light once its intensity is divided out)
    assert declared_dark(Meta({"dark": {"raw_threshold": 350}})) is None


def test_the_truncation_term_is_minus_log_p_kept(power_law_stack):
    """The pointwise log-likelihood with the threshold minus without it is -log P(kept) =
    -log Phi((m_lin - f^-1(dark)) / (sigma G)), computed here from the camera's functions with
    scipy's normal. Tolerance 1e-9 absolute (the same float64 formula by another path)."""
    ctx = build_context(power_law_stack, power_law_stack.truth_labels)
    assert ctx.dark == 0.0 and ctx.noise["truncated_at_dark"] == 0.0      # diagnosis.json records it
    camera = EFFECTS["camera_gamma"]
    plain_ctx = _untruncated(ctx)
    fit = refit(plain_ctx, [camera], n_draws=2)
    plain = fit.objective
    truncated = RefitObjective(ctx, [camera], plain_ctx.features["region_priors"])
    difference = truncated.log_lik_pointwise(fit.z) - plain.log_lik_pointwise(fit.z)
    mu = plain.mean(fit.z)[0]
    theta, white = fit.effect_thetas()[0], camera.prepare(ctx)
    sd = np.sqrt(fit.region_params()[ctx.region, 3]) * math.exp(float(np.mean(camera.inverse_log_slope(ctx.y, theta,
                                                                                                        white))))
    expected = -norm.logcdf((camera.inverse(mu, theta, white) - camera.inverse(0.0, theta, white)) / sd)
    np.testing.assert_allclose(difference, expected, rtol=0, atol=1e-9)
    assert expected.max() > 0.1, "some kept observations should lie near the threshold for the test to bite"


def test_the_truncated_likelihood_keeps_the_power_law(power_law_stack):
    """With the truncation the true power law beats ambient + sRGB decisively and ambient adds
    nothing decisive to it; the plain normal on the same kept observations prefers ambient +
    sRGB (the bias the term removes: the test's stack shows it). Measured at 32 x 32: log BF of
    ambient + sRGB over camera_gamma -32.7 truncated, +29.1 plain; of ambient + camera_gamma
    -3.5 truncated. Tolerance: the decision rule's ln 100 for each."""
    ctx = build_context(power_law_stack, power_law_stack.truth_labels)
    models = {"gamma": ["camera_gamma"], "ambient+gamma": ["ambient", "camera_gamma"],
              "ambient+srgb": ["ambient", "camera_srgb"]}

    def log_bf(context):
        evidence = {name: refit(context, [EFFECTS[e] for e in effects], n_draws=2).log_evidence
                    for name, effects in models.items()}
        return {name: value - evidence["gamma"] for name, value in evidence.items()}

    truncated = log_bf(ctx)
    assert truncated["ambient+srgb"] < -LN_100 and truncated["ambient+gamma"] < LN_100, truncated
    plain = log_bf(_untruncated(ctx))
    assert plain["ambient+srgb"] > LN_100, plain
