"""Tests of the ``rjfit_blinn`` Mitsuba BSDF (rjfit/render/plugin.py).

The independent reference is the numpy closed form ``rjfit.model.blinn.brdf`` (and, for the
sampling density, the textbook pdf written out again below in numpy). Every random number is
drawn from a fixed seed, so each statistical test is deterministic; the significance levels
and Monte Carlo tolerances say how likely a *correct* implementation would be to fail with a
fresh seed.
"""
from __future__ import annotations

import contextlib
import math

import numpy as np
import pytest

mi = pytest.importorskip("mitsuba")
dr = pytest.importorskip("drjit")
integrate = pytest.importorskip("scipy.integrate")

from rjfit.model.blinn import blinn_normalisation, brdf  # noqa: E402
from rjfit.render.plugin import PLUGIN_NAME, register  # noqa: E402

VARIANTS = ["llvm_ad_mono", "llvm_ad_rgb", "scalar_rgb"]

# (kd, gamma, scale) used by the point-wise comparisons
MATERIALS = [(0.5, 5.0, 1.0), (0.1, 50.0, 2.5), (1.0, 10.0, 1.0), (0.0, 1.0, 0.7)]


@contextlib.contextmanager
def use_variant(name):
    """Activate a Mitsuba variant (and register the plugin there), restore the old one after."""
    if name not in mi.variants():
        pytest.skip(f"Mitsuba variant {name} not available")
    previous = mi.variant()
    mi.set_variant(name)
    try:
        register()
        yield
    finally:
        if previous is not None and previous != name:
            mi.set_variant(previous)


def load_bsdf(kd, gamma, scale=1.0):
    return mi.load_dict({"type": PLUGIN_NAME, "kd": kd, "gamma": gamma, "scale": scale})


def spherical(theta, phi):
    theta, phi = np.broadcast_arrays(np.asarray(theta, float), np.asarray(phi, float))
    return np.stack(
        [np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1
    )


# --------------------------------------------------------------------------- references
def ref_eval(kd, gamma, scale, wi, wo):
    """Mitsuba's eval: scale * f(wi, wo) * cos(theta_o), zero below either horizon."""
    with np.errstate(invalid="ignore", divide="ignore"):  # wi = -wo: masked out below
        h = wi + wo
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    value = scale * brdf(kd, gamma, h[..., 2]) * wo[..., 2]
    return np.where((wi[..., 2] > 0) & (wo[..., 2] > 0), value, 0.0)


def ref_pdf(kd, gamma, wi, wo):
    """Mixture pdf: kd * cos(theta_o)/pi + (1-kd) * (g+1)/(2 pi) cos^g(theta_h) / (4 <wo.h>)."""
    with np.errstate(invalid="ignore", divide="ignore"):  # wi = -wo: masked out below
        h = wi + wo
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
        cos_h = np.maximum(h[..., 2], 0.0)
        pdf_s = (gamma + 1) / (2 * np.pi) * cos_h**gamma / (4 * np.sum(wo * h, axis=-1))
    pdf_d = wo[..., 2] / np.pi
    pdf = kd * pdf_d + (1 - kd) * pdf_s
    return np.where((wi[..., 2] > 0) & (wo[..., 2] > 0), pdf, 0.0)


def sweep(n_theta, n_phi):
    """(wi, wo) pairs over incident and outgoing angles, a few of them below the horizon."""
    th_i = np.linspace(0.0, 1.55, n_theta)
    th_o = np.linspace(0.0, 1.55, n_theta)
    phi_o = np.linspace(0.0, 2 * np.pi, n_phi, endpoint=False) + 0.1
    ti, to, po = np.meshgrid(th_i, th_o, phi_o, indexing="ij")
    wi = spherical(ti, 0.0).reshape(-1, 3)
    wo = spherical(to, po).reshape(-1, 3)
    wo[::7, 2] *= -1.0  # below the horizon: must give zero
    wi[::11, 2] *= -1.0
    return wi, wo


def plugin_eval_pdf(bsdf, wi, wo):
    """Call eval, pdf and eval_pdf on arrays of local directions (any variant)."""
    ctx = mi.BSDFContext()
    if mi.variant().startswith("scalar"):
        out = {"eval": [], "pdf": [], "eval_pdf_v": [], "eval_pdf_p": []}
        for a, b in zip(wi, wo):
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.wi = mi.Vector3f(*map(float, a))
            w = mi.Vector3f(*map(float, b))
            out["eval"].append(bsdf.eval(ctx, si, w)[0])
            out["pdf"].append(bsdf.pdf(ctx, si, w))
            v, p = bsdf.eval_pdf(ctx, si, w)
            out["eval_pdf_v"].append(v[0])
            out["eval_pdf_p"].append(p)
        return {k: np.array(v, dtype=float) for k, v in out.items()}
    n = len(wi)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*(mi.Float(c) for c in wi.T.astype(np.float32)))
    w = mi.Vector3f(*(mi.Float(c) for c in wo.T.astype(np.float32)))
    v, p = bsdf.eval_pdf(ctx, si, w)
    return {
        "eval": np.array(bsdf.eval(ctx, si, w), dtype=float)[0],
        "pdf": np.array(bsdf.pdf(ctx, si, w), dtype=float),
        "eval_pdf_v": np.array(v, dtype=float)[0],
        "eval_pdf_p": np.array(p, dtype=float),
    }


# --------------------------------------------------------------------------- registration
def test_register_is_idempotent_per_variant():
    with use_variant("llvm_ad_rgb"):
        assert register() is register()
        assert register("llvm_ad_rgb") is register()
        bsdf = load_bsdf(0.5, 5.0)
        assert mi.has_flag(bsdf.flags(), mi.BSDFFlags.DiffuseReflection)
        assert mi.has_flag(bsdf.flags(), mi.BSDFFlags.GlossyReflection)
        assert mi.has_flag(bsdf.flags(), mi.BSDFFlags.FrontSide)
        assert not mi.has_flag(bsdf.flags(), mi.BSDFFlags.BackSide)
        assert bsdf.component_count() == 2


@pytest.mark.parametrize("bad", [{"kd": 1.5}, {"kd": -0.1}, {"gamma": 0.0}, {"scale": -1.0}])
def test_rejects_invalid_parameters(bad):
    with use_variant("llvm_ad_rgb"):
        params = {"type": PLUGIN_NAME, "kd": 0.5, "gamma": 5.0, "scale": 1.0, **bad}
        with pytest.raises(Exception, match=list(bad)[0]):
            mi.load_dict(params)


# --------------------------------------------------------------------------- point-wise
@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("kd,gamma,scale", MATERIALS)
def test_eval_pdf_match_closed_form(variant, kd, gamma, scale):
    with use_variant(variant):
        scalar = variant.startswith("scalar")
        # scalar variants run the Python plugin once per direction: keep that sweep small
        wi, wo = sweep(4, 3) if scalar else sweep(24, 12)
        if not scalar:  # the JIT variants work in float32: compare on the rounded inputs
            wi = wi.astype(np.float32).astype(float)
            wo = wo.astype(np.float32).astype(float)
        got = plugin_eval_pdf(load_bsdf(kd, gamma, scale), wi, wo)
        want_f = ref_eval(kd, gamma, scale, wi, wo)
        want_p = ref_pdf(kd, gamma, wi, wo)

        # Tolerances: scalar_rgb computes in double precision (Python floats): 1e-12.
        # The JIT variants compute in float32; <h.n>^g amplifies the ~1e-7 relative rounding
        # of <h.n> by g, so 1e-7 * g * (a few) relative, plus an absolute floor at 1e-6 of the
        # largest value for cancellation near zero.
        rtol = 1e-12 if scalar else 4e-7 * max(gamma, 10.0)
        np.testing.assert_allclose(got["eval"], want_f, rtol=rtol, atol=1e-6 * want_f.max())
        np.testing.assert_allclose(got["pdf"], want_p, rtol=rtol, atol=1e-6 * want_p.max())
        below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
        assert below.any() and np.all(got["eval"][below] == 0) and np.all(got["pdf"][below] == 0)
        # eval_pdf is the pair (eval, pdf), bit for bit
        np.testing.assert_array_equal(got["eval_pdf_v"], got["eval"])
        np.testing.assert_array_equal(got["eval_pdf_p"], got["pdf"])


def test_mono_and_rgb_agree():
    wi, wo = sweep(8, 4)
    results = {}
    for variant in ("llvm_ad_mono", "llvm_ad_rgb"):
        with use_variant(variant):
            results[variant] = plugin_eval_pdf(load_bsdf(0.3, 20.0, 2.0), wi, wo)
    for key in ("eval", "pdf"):
        np.testing.assert_array_equal(results["llvm_ad_mono"][key], results["llvm_ad_rgb"][key])


def test_parameters_editable_through_traverse():
    with use_variant("llvm_ad_rgb"):
        bsdf = load_bsdf(0.5, 5.0, 1.0)
        params = mi.traverse(bsdf)
        assert {"kd", "gamma", "scale"} <= set(params.keys())
        params["kd"] = 0.2
        params["gamma"] = 40.0
        params["scale"] = 3.0
        params.update()
        wi, wo = sweep(10, 4)
        wi = wi.astype(np.float32).astype(float)
        wo = wo.astype(np.float32).astype(float)
        got = plugin_eval_pdf(bsdf, wi, wo)
        want = ref_eval(0.2, 40.0, 3.0, wi, wo)
        np.testing.assert_allclose(got["eval"], want, rtol=2e-5, atol=1e-6 * want.max())
        np.testing.assert_allclose(
            got["pdf"], ref_pdf(0.2, 40.0, wi, wo), rtol=2e-5, atol=1e-6 * want.max()
        )


def test_sample_weight_is_eval_over_pdf():
    with use_variant("llvm_ad_rgb"):
        bsdf = load_bsdf(0.4, 30.0, 1.5)
        rng = np.random.default_rng(1)
        n = 4096
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        wi = spherical(rng.uniform(0, 1.5, n), rng.uniform(0, 2 * np.pi, n)).astype(np.float32)
        si.wi = mi.Vector3f(*(mi.Float(c) for c in wi.T))
        u = rng.random((3, n)).astype(np.float32)
        bs, weight = bsdf.sample(mi.BSDFContext(), si, mi.Float(u[0]), mi.Point2f(u[1], u[2]))
        value, pdf = bsdf.eval_pdf(mi.BSDFContext(), si, bs.wo)
        weight, value, pdf = (np.array(x, dtype=float) for x in (weight, value, pdf))
        bpdf = np.array(bs.pdf, dtype=float)
        ok = bpdf > 0
        assert ok.mean() > 0.9
        np.testing.assert_allclose(bpdf, pdf, rtol=1e-6)
        np.testing.assert_allclose(weight[0][ok], value[0][ok] / pdf[ok], rtol=1e-5)
        assert np.all(weight[:, ~ok] == 0)
        comp = np.array(bs.sampled_component)
        assert set(np.unique(comp)) == {0, 1}
        # lobe selection probability is kd (here 0.4): 4096 draws, binomial sd 0.008
        assert abs((comp == 0).mean() - 0.4) < 0.04


# --------------------------------------------------------------------------- chi-square
# (kd, gamma, theta_i, ires). gamma 1000 needs a finer numerical integration of the pdf per
# histogram cell (ires 16): with Mitsuba's default ires 4 the trapezoid rule misses the peak of
# a lobe that is ~2/sqrt(1000) rad wide and the test rejects a correct sampler.
CHI2_CASES = [
    (0.5, 1.0, 0.3, 4),
    (0.5, 50.0, 1.0, 4),
    (0.0, 1.0, 1.2, 4),
    (0.0, 50.0, 0.3, 4),
    (0.2, 5.0, 0.0, 4),
    (1.0, 10.0, 0.7, 4),
    (0.3, 1000.0, 0.4, 16),
]


@pytest.mark.parametrize("kd,gamma,theta_i,ires", CHI2_CASES)
def test_chi2_sample_matches_pdf(kd, gamma, theta_i, ires, tmp_path, monkeypatch):
    """Pearson chi-square of sample() against pdf() (Mitsuba's own mitsuba.chi2).

    Significance level 0.01 for the whole family of cases, Sidak-corrected by ChiSquareTest
    (test_count=len(CHI2_CASES)): a correct sampler fails one case of this file with
    probability <= 1 % for a fresh seed; the seed is fixed, so the outcome is deterministic.
    """
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain

    monkeypatch.chdir(tmp_path)  # on failure ChiSquareTest writes chi2_data.py into the cwd
    with use_variant("llvm_ad_rgb"):
        wi = [math.sin(theta_i), 0.0, math.cos(theta_i)]
        sample_func, pdf_func = BSDFAdapter(
            PLUGIN_NAME, {"type": PLUGIN_NAME, "kd": kd, "gamma": gamma}, wi=wi
        )
        chi2 = ChiSquareTest(
            domain=SphericalDomain(),
            sample_func=sample_func,
            pdf_func=pdf_func,
            sample_dim=3,
            sample_count=1_000_000,
            res=101,
            ires=ires,
            seed=2,
        )
        assert chi2.run(significance_level=0.01, test_count=len(CHI2_CASES), quiet=True), (
            chi2.messages
        )


# --------------------------------------------------------------------------- Giesen
GIESEN_GAMMAS = [1.0, 2.0, 5.0, 10.0, 50.0, 100.0, 1000.0]


def lobe_integral_normal_incidence(gamma, normalised=True):
    """Integral over the hemisphere of N(g) <h.n>^g cos(theta_o) for wi = n.

    With wi = n, h bisects n and wo, so <h.n> = cos(theta_o / 2); the phi integral gives 2 pi.
    """

    def integrand(theta):
        return math.cos(theta / 2) ** gamma * math.cos(theta) * math.sin(theta)

    # the lobe is ~2/sqrt(g) wide: tell quad where it is
    peak = min(math.pi / 2, 4.0 / math.sqrt(gamma))
    value = sum(
        integrate.quad(integrand, a, b, epsabs=1e-14, epsrel=1e-13, limit=200)[0]
        for a, b in ((0.0, peak), (peak, math.pi / 2))
        if b > a
    )
    norm = float(blinn_normalisation(gamma)) if normalised else 1.0
    return 2 * math.pi * norm * value


@pytest.mark.parametrize("gamma", GIESEN_GAMMAS)
def test_giesen_normalisation_exact_at_normal_incidence(gamma):
    """Giesen (2009) derives N(g) = (g+2)(g+4) / (8 pi (2^(-g/2) + g)) in closed form from this
    very integral with the viewer along the normal, so his claim is exactness there (not an
    approximation): the integral must be 1 up to quadrature error. Tolerance 1e-9, well above
    the ~1e-13 error of adaptive quadrature on this smooth integrand and far below any error
    a wrong factor would make (the widespread simplification (g+8)/(8 pi) is up to ~7 % off).
    """
    assert abs(lobe_integral_normal_incidence(gamma) - 1.0) < 1e-9
    # the same integral with the simplified factor is measurably different (7 % at g = 10):
    # the tolerance can discriminate between normalisations
    simple = lobe_integral_normal_incidence(gamma) * (gamma + 8) / (8 * math.pi) / float(
        blinn_normalisation(gamma)
    )
    assert abs(simple - 1.0) > 1e-4
    # without the normalisation the lobe does not integrate to ~1 (2.86 at g = 1, 0.025 at
    # g = 1000; it only crosses 1 near g = 19, not among the tested values): the test can fail
    assert abs(lobe_integral_normal_incidence(gamma, normalised=False) - 1.0) > 0.3


@pytest.mark.parametrize("gamma", [1.0, 10.0, 50.0, 1000.0])
def test_plugin_lobe_integrates_to_one_at_normal_incidence(gamma):
    """The same integral of the plugin's own eval (kd = 0, float32 kernel), by Gauss-Legendre
    quadrature in (theta_o, phi). Tolerance 1e-4: float32 evaluation (~1e-6) and a cut of the
    theta range at 12/sqrt(g) (6 lobe widths; the tail is < 1e-7 of the total)."""
    with use_variant("llvm_ad_rgb"):
        theta_max = min(math.pi / 2, 12.0 / math.sqrt(gamma))
        x, w = np.polynomial.legendre.leggauss(400)
        theta = 0.5 * theta_max * (x + 1)
        w_theta = 0.5 * theta_max * w
        xp, wp = np.polynomial.legendre.leggauss(8)
        phi = np.pi * (xp + 1)
        w_phi = np.pi * wp
        T, P = np.meshgrid(theta, phi, indexing="ij")
        weights = np.outer(w_theta * np.sin(theta), w_phi).ravel()
        wo = spherical(T, P).reshape(-1, 3)
        wi = np.tile([0.0, 0.0, 1.0], (len(wo), 1))
        got = plugin_eval_pdf(load_bsdf(0.0, gamma, 1.0), wi, wo)
        assert abs(np.sum(got["eval"] * weights) - 1.0) < 1e-4


# --------------------------------------------------------------------------- energy
def specular_albedo(gamma, theta_i, n=600):
    """Directional albedo of N(g) <h.n>^g cos(theta_o) by tensor Gauss-Legendre quadrature."""
    x, w = np.polynomial.legendre.leggauss(n)
    mu, w_mu = 0.5 * (x + 1), 0.5 * w
    phi, w_phi = np.pi * (x + 1), np.pi * w
    M, P = np.meshgrid(mu, phi, indexing="ij")
    wo = spherical(np.arccos(M), P)
    wi = spherical(theta_i, 0.0)
    h = wo + wi
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    f = blinn_normalisation(gamma) * np.maximum(h[..., 2], 0) ** gamma * M
    return float(np.einsum("ij,i,j->", f, w_mu, w_phi))


@pytest.mark.parametrize("kd", [0.0, 0.5, 1.0])
@pytest.mark.parametrize("theta_i", [0.0, 0.7, 1.3])
def test_energy_albedo_at_most_one(kd, theta_i):
    """Albedo = E[weight] of the plugin's own sample() (scale 1), 2^20 samples.

    Checks: albedo <= 1 + 4 SE, and albedo equals kd + (1 - kd) * (quadrature of the specular
    lobe) within 4 SE + 1e-4 (SE = sample standard deviation / sqrt(N); the weights are
    bounded, so the mean is Gaussian to high accuracy and 4 SE has a two-sided false alarm
    rate of 6e-5; 1e-4 absorbs float32 rounding and the quadrature of a gamma-10 lobe). At
    normal incidence Giesen's normalisation makes the albedo exactly 1.
    """
    gamma = 10.0
    with use_variant("llvm_ad_rgb"):
        bsdf = load_bsdf(kd, gamma, 1.0)
        n = 1 << 20
        rng = np.random.default_rng(12345)
        u = rng.random((3, n)).astype(np.float32)
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.wi = mi.Vector3f(math.sin(theta_i), 0.0, math.cos(theta_i))
        _, weight = bsdf.sample(mi.BSDFContext(), si, mi.Float(u[0]), mi.Point2f(u[1], u[2]))
        weight = np.array(weight, dtype=float)[0]
        mean = weight.mean()
        se = weight.std(ddof=1) / math.sqrt(n)
        assert mean <= 1.0 + 4 * se + 1e-6
        expected = kd + (1 - kd) * specular_albedo(gamma, theta_i)
        assert expected <= 1.0 + 1e-9
        assert abs(mean - expected) <= 4 * se + 1e-4, (mean, expected, se)


# --------------------------------------------------------------------------- render
def test_render_matches_closed_form():
    """32x32 llvm_ad_rgb render of a sphere lit by a point light (1 spp, box filter) against
    the closed form at the aov integrator's positions and shading normals, same seed, so the
    same camera rays. Float32 rendering vs float64 closed form: median rel. err. < 1e-5, max
    < 1e-3 on lit pixels (<l.n> > 0.05; design notes measured ~1.5e-7 median)."""
    intensity = 10.0
    kd, gamma, scale = 0.4, 10.0, 2.0
    light = np.array([1.5, 2.0, 4.0])
    camera = np.array([0.0, 0.0, 5.0])
    with use_variant("llvm_ad_rgb"):

        def scene(integrator):
            return mi.load_dict(
                {
                    "type": "scene",
                    "integrator": integrator,
                    "sensor": {
                        "type": "perspective",
                        "fov": 30,
                        "to_world": mi.ScalarTransform4f().look_at(
                            origin=camera.tolist(), target=[0, 0, 0], up=[0, 1, 0]
                        ),
                        "film": {
                            "type": "hdrfilm",
                            "width": 32,
                            "height": 32,
                            "rfilter": {"type": "box"},
                        },
                        "sampler": {"type": "independent", "sample_count": 1},
                    },
                    "sphere": {
                        "type": "sphere",
                        "bsdf": {"type": PLUGIN_NAME, "kd": kd, "gamma": gamma, "scale": scale},
                    },
                    "light": {
                        "type": "point",
                        "position": light.tolist(),
                        "intensity": {"type": "rgb", "value": [intensity] * 3},
                    },
                }
            )

        image = np.array(mi.render(scene({"type": "path", "max_depth": 4}), seed=7), float)
        aov = np.array(
            mi.render(scene({"type": "aov", "aovs": "p:position,n:sh_normal"}), seed=7), float
        )
    p, n = aov[..., 0:3], aov[..., 3:6]
    hit = np.linalg.norm(n, axis=-1) > 0.5
    assert np.all(image[~hit] == 0)
    np.testing.assert_array_equal(image[..., 0], image[..., 1])
    np.testing.assert_array_equal(image[..., 0], image[..., 2])
    p, n = p[hit], n[hit] / np.linalg.norm(n[hit], axis=-1, keepdims=True)
    to_light = light - p
    r2 = np.sum(to_light**2, axis=-1)
    l = to_light / np.sqrt(r2)[:, None]
    v = camera - p
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    h = (l + v) / np.linalg.norm(l + v, axis=-1, keepdims=True)
    cos_ln = np.sum(l * n, axis=-1)
    want = intensity * scale * brdf(kd, gamma, np.sum(h * n, axis=-1)) * cos_ln / r2
    lit = cos_ln > 0.05
    assert lit.sum() > 200
    rel = np.abs(image[hit][lit, 0] - want[lit]) / want[lit]
    assert np.median(rel) < 1e-5, np.median(rel)
    assert rel.max() < 1e-3, rel.max()
    # unlit side is black
    assert np.all(image[hit][cos_ln < 0, 0] == 0)
