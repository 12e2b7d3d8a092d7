"""``rjfit fit --regions materials --channel rgb`` end to end on a small in-code stack (a joint colour fit).

A 10 x 12 image under 6 lights, two paints of one kd and gamma whose channel MEANS are
equal (I0 x (1.5, 0.8, 0.7) left, x (0.75, 0.75, 1.5) right: their grey data follow one
BRDF) and whose hues differ; 2 chains of 150 iterations (about 15 s). Checks what the fit
writes (per-material gamma, per-channel I0, kd and sigma^2 in summary.json, chains.nc's
channel dimension, maps.exr's per-channel maps, the colour reflectance figure) and that the colour fit separates the
paints (label accuracy >= 0.95: the per-channel amplitudes differ by 10 to 20 noise sds per
observation); and that ``--channel rgb`` with the change-point model is refused.
"""
import numpy as np
import pytest

from rjfit.data.exr import read_exr
from rjfit.data.observations import Observations, stack_channels
from rjfit.model.blinn import radiance
from rjfit.pipeline.fit import fit
from rjfit.pipeline.options import FitOptions
from rjfit.pipeline.resolve import resolve_options

HUES = np.array([[1.5, 0.8, 0.7], [0.75, 0.75, 1.5]])


def colour_stack(height=10, width=12, lights=6, seed=0):
    rng = np.random.default_rng(seed)
    truth = np.zeros((height, width), int)
    truth[:, width // 2:] = 1
    pixel = np.repeat(np.arange(height * width), lights)
    cos_ln, cos_hn = rng.uniform(0.2, 1, pixel.size), rng.uniform(0.5, 1, pixel.size)
    irradiance = rng.uniform(0.5, 1.5, pixel.size)
    paint = truth.ravel()[pixel]
    per_channel = []
    for c in range(3):
        y = radiance(10.0 * HUES[paint, c], 0.6, 12.0, cos_ln, cos_hn, irradiance) + rng.normal(0, 0.1, pixel.size)
        per_channel.append(Observations(image_shape=(height, width), n_lights=lights, pixel=pixel.astype(np.int64),
                                        light=np.tile(np.arange(lights), height * width).astype(np.int32), y=y,
                                        cos_ln=cos_ln, cos_hn=cos_hn, irradiance=irradiance,
                                        object_mask=np.ones((height, width), bool)))
    return stack_channels(per_channel), truth


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    obs, truth = colour_stack()
    out = tmp_path_factory.mktemp("fit") / "out"
    summary = fit(obs, out, regions="materials", channel="rgb", iterations=150, n_chains=2, processes=1,
                  truth_labels=truth, progress=False, seed=2)
    return out, summary


def test_colour_fit_writes_per_channel_parameters(fitted):
    out, summary = fitted
    assert summary["label_accuracy"] >= 0.95, summary["label_accuracy"]
    for region in summary["regions"]:
        assert set(region["channels"]) == {"R", "G", "B"} and "gamma" in region and "I0" not in region
        assert {"mean", "sd", "q2.5", "q97.5"} <= set(region["channels"]["R"]["I0"])
    import arviz as az

    idata = az.from_netcdf(str(out / "chains.nc"))
    theta = idata.posterior["theta"]
    assert theta.dims[2:] == ("material", "channel", "parameter") and list(theta["channel"].values) == ["R", "G", "B"]
    # each draw's pointwise log likelihood (a row per material and channel) sums to the chain's own, 1e-8 relative
    # (another order of float64 sums; tests/pipeline/test_fit_files.py says why that tolerance)
    iterations = idata.log_likelihood["iteration"].values
    chain_totals = idata.sample_stats["log_lik"].values[np.arange(2)[:, None], iterations - summary["burn_in"]]
    np.testing.assert_allclose(idata.log_likelihood["y"].sum("pixel_block").values, chain_totals, rtol=1e-8)
    maps = read_exr(out / "maps.exr")
    assert {"gamma", "I0_R", "kd_B", "sigma2_G", "residual_rms"} <= set(maps)
    assert (out / summary["figures"]["reflectance"]).is_file()       # the colour reflectance figure


def test_each_paint_states_its_albedo_against_its_surroundings_channel_by_channel(fitted):
    """The two paints' grey levels are equal and their hues differ: each channel's ratio (left paint over right) is
    the hues' ratio times a factor of the geometry that the channels share (one ``cos_hn`` per observation), so the
    ratios of the channels' median ratios are the hues' (R over B 4.29, G over B 2.29). Tolerance 10 %: each side's
    sum under a light holds 30 to 60 observations of noise sd 0.1 against a signal near 1.5 (about 1.5 % each), and
    four such sums and a median over 6 lights enter the figure."""
    out, summary = fitted
    labels = np.rint(read_exr(out / "labels.exr")["labels"]).astype(int)
    left = int(np.bincount(labels[:, :3].ravel()).argmax())
    reading = summary["regions"][left]["contrast_to_surroundings"]
    assert set(reading["channels"]) == {"R", "G", "B"} and reading["lights"] == 6
    median = {name: one["median"] for name, one in reading["channels"].items()}
    hue = HUES[0] / HUES[1]
    assert median["R"] / median["B"] == pytest.approx(hue[0] / hue[2], rel=0.1)
    assert median["G"] / median["B"] == pytest.approx(hue[1] / hue[2], rel=0.1)
    from rjfit.posterior.contrast import contrast_words
    assert "; per channel, under the middle half: R " in contrast_words(reading)


def test_colour_needs_the_material_model():
    with pytest.raises(ValueError, match="--channel rgb"):
        resolve_options(FitOptions(channel="rgb"))
    with pytest.raises(ValueError, match="--channel rgb"):
        resolve_options(FitOptions(channel="rgb", regions="materials", sampler="paper"))


def test_the_colour_power_divides_by_the_channels_design_effect():
    """``--likelihood-power auto`` with rgb: three copies of one channel carry one channel's
    information (r = 1: the power divided by 3), three channels of independent noise carry three
    (r ~ 0: the channels' power kept). The sphere is white noise (per-channel zeta ~ 1); with
    ~20,000 shared observations r's sampling sd is ~0.007, so |r| < 0.05 is over 7 sd."""
    import dataclasses

    from rjfit.data.synthetic import sphere_stack
    from rjfit.pipeline.fit_power import power_suggestion

    one = [sphere_stack(48, n_lights=10, seed=seed)[0] for seed in (5, 6, 7)]
    copies = power_suggestion(stack_channels([one[0]] * 3), None)
    assert copies["channel_correlation"] == pytest.approx(1.0)
    assert copies["likelihood_power"] == pytest.approx(copies["most_misfit_channel"]["likelihood_power"] / 3)
    # same geometry, independent noise per channel (sphere_stack's seed draws only the noise here)
    assert all(np.array_equal(o.pixel, one[0].pixel) and np.array_equal(o.cos_hn, one[0].cos_hn) for o in one)
    independent = stack_channels([one[0]] + [dataclasses.replace(one[0], y=o.y) for o in one[1:]])
    suggestion = power_suggestion(independent, None)
    assert abs(suggestion["channel_correlation"]) < 0.05
    assert suggestion["likelihood_power"] > 0.9 * suggestion["most_misfit_channel"]["likelihood_power"]


def test_the_measured_preset_takes_colour_and_the_area_power_is_refused_in_one_line():
    """The preset's normals noise is measured per channel (tests/data/test_normal_error.py); the area
    power's summed autocorrelation is of one channel still."""
    options = resolve_options(FitOptions(regions="materials", channel="rgb", preset="measured"))
    assert options.noise == "normals" and options.likelihood_power == "auto"
    with pytest.raises(ValueError, match="not yet with --channel rgb"):
        resolve_options(FitOptions(regions="materials", channel="rgb", likelihood_power="area"))
