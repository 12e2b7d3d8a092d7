"""The compiled passes on a problem with effects (issue 26) against their NumPy references.

The tests of ``test_passes.py`` that read the problem's columns, run here on a problem whose
lobe column carries every effect's terms (a lobe factor of its own, Smith-Beckmann masking
and ambient light: :mod:`rjfit.sampler.passes.lobe`), transformed by every kind of effect
(light gains, shadowing factor, indirect offset, sRGB camera) at a likelihood power 0.6. The
references compute the lobe column with :func:`rjfit.sampler.likelihood.lobe_column`. Same
tolerances as there. Left out: the Newton rule's finite differences (with masking and
ambient light the Newton sums are the plain lobe's derivative, an approximation that only
places the proposal: :mod:`rjfit.sampler.passes.lobe`).
"""
import numpy as np
import pytest
from test_passes import (  # noqa: F401
    test_b_sums_equal_numpy_reference,
    test_b_sums_newton_equal_numpy_reference,
    test_element_move_delta_and_shift_equal_reference,
    test_per_pixel_two_cases_equal_reference,
    test_region_stats_equal_numpy_reference,
    test_removal_sums_equal_reference,
    test_split_into_runs_equals_one_gather_per_region,
)

from rjfit.data.synthetic import sphere_stack
from rjfit.effects.ambient import ALBEDO_LOG_GAMMA, AmbientLight, albedo_table, cos_v_weights
from rjfit.effects.base import Param
from rjfit.effects.camera_srgb import SRGBCurve
from rjfit.effects.cast_shadows import DirectFactor
from rjfit.effects.coating import CoatingFactors
from rjfit.effects.fresnel import LobeFactor
from rjfit.effects.ggx import LobeGGX
from rjfit.effects.interreflection import IndirectLight
from rjfit.effects.light_calibration import LightGains
from rjfit.effects.masking import LobeMasking
from rjfit.effects.second_lobe import SecondLobeTerm
from rjfit.model.priors import LogitNormal, LogNormal, Normal
from rjfit.sampler import reference
from rjfit.sampler.forward import LambertBlinnPhong, transformed
from rjfit.sampler.likelihood import region_stats
from rjfit.sampler.regions.materials.passes.labels import pixel_log_lik, relabel_pixels


def every_effect(observations, seed=0):
    """One fit form of each kind for ``observations``, with random features (in their order)."""
    rng = np.random.default_rng(seed)
    n, n_lights = observations.n_obs, observations.n_lights
    column, weight = cos_v_weights(rng.uniform(0.05, 1.0, n))
    grid = np.array([ALBEDO_LOG_GAMMA[0], ALBEDO_LOG_GAMMA[-1], ALBEDO_LOG_GAMMA[1] - ALBEDO_LOG_GAMMA[0]])
    unit = LogitNormal(0.0, 2.0)
    return [
        LobeFactor(params=(Param("F0", LogitNormal(0.0, 2.0, low=0.01, high=1.0), 0.5),),
                   fresnel_term=rng.uniform(0.0, 0.3, n) ** 2),
        LobeMasking(params=(Param("w_mask", unit, 0.5),), tan_v=rng.uniform(0.0, 3.0, n),
                    tan_l=rng.uniform(0.0, 3.0, n)),
        DirectFactor(params=(Param("w_shadow", unit, 0.5),), visibility=(rng.random(n) < 0.8).astype(float)),
        IndirectLight(params=(Param("beta", LogNormal(0.0, 1.0), 1.0),),
                      feature=rng.uniform(0.0, 0.05, n) * float(np.max(observations.y))),
        LightGains(params=tuple(Param(f"h{j}", Normal(0.0, 0.2), 0.0) for j in range(1, n_lights)),
                   n_lights=n_lights),
        AmbientLight(params=(Param("ambient", LogNormal(np.log(0.05), 1.0), 0.05),), column=column.astype(np.int32),
                     weight=weight, table=albedo_table(), grid=grid),
        SRGBCurve(params=(Param("white_rel", LogNormal(0.0, 1.0), 1.0),), white_level=float(np.max(observations.y))),
    ]


def lobe_shapes(observations, seed=0):
    """The lobe-shape fit forms (a GGX lobe mixed in, a second lobe) and a dielectric coating (factors on both
    columns, after the second lobe), with random geometry (in the observations' order)."""
    rng = np.random.default_rng(seed + 100)
    n = observations.n_obs
    return [LobeGGX(params=(Param("w_ggx", LogitNormal(0.0, 2.0), 0.5),), tan_v=rng.uniform(0.0, 3.0, n),
                    tan_l=rng.uniform(0.0, 3.0, n)),
            SecondLobeTerm(params=(Param("v", LogNormal(np.log(0.25), 1.5), 0.25),
                                   Param("alpha2", LogitNormal(0.0, 1.5, low=0.02, high=1.0), 0.2)),
                           cos2_h=rng.uniform(0.0, 1.0, n), tan_v=rng.uniform(0.0, 3.0, n),
                           tan_l=rng.uniform(0.0, 3.0, n)),
            CoatingFactors(params=(Param("w_coat", LogitNormal(0.0, 2.0), 0.5),
                                   Param("eta", LogitNormal(0.0, 1.5, low=1.2, high=2.0), 1.5)),
                           cos_l=rng.uniform(0.0, 1.0, n), cos_v=rng.uniform(0.05, 1.0, n),
                           cos_hv=rng.uniform(0.3, 1.0, n))]


@pytest.fixture(scope="module", params=["every effect", "every effect and the lobe shapes"])
def problem(request):
    """Every effect's terms at once; and with the lobe shapes too (ggx, whose tangents replace masking's, a
    second lobe, and a coating)."""
    obs, _, _ = sphere_stack(40, n_lights=6, seed=3)
    forms = every_effect(obs) + (lobe_shapes(obs) if request.param != "every effect" else [])
    base = LambertBlinnPhong(forms).problem(obs, likelihood_power=0.6)
    z = base.effects.initial_z() + np.random.default_rng(1).normal(0.0, 0.3, base.effects.n_params)
    effect_problem, _ = transformed(base, z)
    assert effect_problem.lobe.mask_w > 0 and effect_problem.lobe.amb.size == obs.n_obs
    if request.param != "every effect":
        assert effect_problem.lobe.ggx_w > 0 and effect_problem.lobe.second.size == obs.n_obs
    return effect_problem


def test_material_label_passes_carry_the_lobe_terms(problem):
    """The material model's passes with every effect's lobe terms: per-pixel log-likelihoods
    against the NumPy twin (whole, and over a subset of observations as the split guide takes
    them), relabelled statistics against a full recompute. Tolerances as the plain passes'
    (``test_materials.py``): float64 sums in another order."""
    n_pix = problem.height * problem.width
    theta = np.array([[1.2, 0.6, 20.0, 0.02], [0.8, 0.3, 5.0, 0.05], [1.5, 0.9, 60.0, 0.01]])
    got = pixel_log_lik(problem.y, problem.C, problem.log_cos_hn, problem.pixel, theta, n_pix, problem.lobe)
    want = reference.pixel_log_lik(problem, theta)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)
    assert np.max(np.abs(got - pixel_log_lik(problem.y, problem.C, problem.log_cos_hn, problem.pixel, theta,
                                             n_pix))) > 1.0, "the lobe terms must change the densities to bite"
    rng = np.random.default_rng(4)
    members = np.flatnonzero(rng.random(n_pix) < 0.3)
    idx = np.flatnonzero(np.isin(problem.pixel, members))
    subset = pixel_log_lik(problem.y[idx], problem.C[idx], problem.log_cos_hn[idx], problem.pixel[idx], theta, n_pix,
                           problem.lobe.take(idx))
    np.testing.assert_allclose(subset[:, members], want[:, members], rtol=1e-9, atol=1e-9)

    pixel_labels = rng.integers(0, 3, n_pix)
    labels = pixel_labels[problem.pixel].astype(np.int32)
    gammas = np.ascontiguousarray(theta[:, 2])
    stats = region_stats(problem, labels, gammas, 3)
    moved = np.flatnonzero(rng.random(n_pix) < 0.2)
    new = (pixel_labels[moved] + rng.integers(1, 3, moved.size)) % 3
    relabel_pixels(problem.y, problem.C, problem.log_cos_hn, problem.pixel_start, moved, pixel_labels[moved], new,
                   gammas, stats, float(problem.likelihood_power), labels, problem.lobe)
    pixel_labels[moved] = new
    np.testing.assert_array_equal(labels, pixel_labels[problem.pixel])
    want_stats = region_stats(problem, labels, gammas, 3)
    np.testing.assert_allclose(stats, want_stats, rtol=1e-9, atol=1e-9 * np.max(np.abs(want_stats)))
