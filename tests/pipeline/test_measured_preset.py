"""``--preset measured``: what it sets, its Potts rule, and a short fit through it under each region model.

The fit is Mitsuba's paper_sphere at 48 x 48 (the session's render), 1 chain of 30 iterations:
the checks are on what the preset records (the normal-error estimate, the power, the
calibration, beta and rho), not on the chain. The area power is tested in
tests/data/test_normal_error.py. Cost: 8 s for the file once Numba's cache is warm (the two
fits 5 s and 1 s), 57 s with compilation on the loaded 2-core machine.
"""
import numpy as np
import pytest
from click.testing import CliRunner

from rjfit.cli import _likelihood_power, main
from rjfit.data.exr import read_exr
from rjfit.data.normal_error import normal_error_noise
from rjfit.data.observations import RIM_COS
from rjfit.pipeline.fit_dataset import fit_dataset
from rjfit.pipeline.options import RIM_VIEW_ANGLE, FitOptions
from rjfit.pipeline.resolve import GHOST_ODDS, GHOST_PIXELS, DataFacts, ghost_material_prior, resolve_options
from rjfit.render.datasets import load_dataset


def test_the_preset_sets_the_measured_defaults_and_survives_a_round_trip():
    options = resolve_options(FitOptions(preset="measured"))
    assert (options.noise, options.likelihood_power, options.calibrate, options.anneal,
            options.cluster_material_seed) == ("normals", "auto", True, 0.0, 0.5)      # seeds: every material fit's
    assert options.source("noise") == "preset" and options.source("preset") == "given"
    assert resolve_options(FitOptions(preset="measured", likelihood_power="area")).likelihood_power == "area"
    assert resolve_options(FitOptions.from_json(options.to_json())) == options
    plain = resolve_options(FitOptions())
    assert (plain.noise, plain.likelihood_power, plain.calibrate, plain.potts_rho) == ("constant", 1.0, False, 0.01)
    assert _likelihood_power("area") == "area"
    with pytest.raises(ValueError, match="preset"):
        FitOptions(preset="rendered")


def test_not_given_is_none_for_every_option_and_a_given_default_is_kept_under_the_preset(monkeypatch):
    """One rule: None is "not given", for every field (anneal and calibrate too); a value equal to the plain
    default is a choice. `--preset measured --noise constant --likelihood-power 1 --potts-rho 1
    --max-view-angle 90` fits what was given."""
    assert all(getattr(FitOptions(), name) is None for name in FitOptions.__dataclass_fields__ if name != "sources")
    assert resolve_options(FitOptions(preset="measured", anneal=0.5)).anneal == 0.5      # was 0: compared to 0.5
    assert resolve_options(FitOptions(preset="measured")).anneal == 0.0
    assert resolve_options(FitOptions(preset="measured", calibrate=False)).calibrate is False
    given = resolve_options(FitOptions(preset="measured", regions="materials", noise="constant",
                                       likelihood_power=1.0, potts_rho=1.0, max_view_angle=90.0),
                            DataFacts(object_mask=np.ones((8, 8), bool)))
    assert (given.noise, given.likelihood_power, given.potts_rho, given.max_view_angle) == ("constant", 1.0, 1.0, 90.0)
    assert given.potts_beta == 3.0 and given.source("potts_beta") == "default"      # a given rho keeps beta and rho
    ruled = resolve_options(FitOptions(preset="measured", regions="materials"), DataFacts(object_mask=np.ones((8, 8), bool)))
    assert ruled.source("potts_rho") == "preset" and (ruled.potts_beta, ruled.potts_rho) == ghost_material_prior(
        np.ones((8, 8), bool), 3.0)
    assert resolve_options(FitOptions.from_json(given.to_json()), DataFacts(object_mask=np.ones((8, 8), bool))) == given
    # the Python API builds options by replacing (fit_dataset(..., preset="measured")): what was not given is
    # still the preset's, and what was given stays given through a copy
    built = FitOptions.build(None, preset="measured", regions="materials")
    assert built.replace(noise="constant").given() == {"preset": "measured", "regions": "materials", "noise": "constant"}
    assert resolve_options(FitOptions(noise="constant").replace(preset="measured")).noise == "constant"
    assert resolve_options(FitOptions.from_json(ruled.to_json()).replace(preset="none")).noise == "constant"
    # the command line passes a flag it was given, and nothing for one it was not
    import rjfit.pipeline.fit_dataset as fit_dataset_module
    seen = []
    monkeypatch.setattr(fit_dataset_module, "fit_datasets", lambda datasets, out, options, **kw: seen.append(options)
                        or [])
    result = CliRunner().invoke(main, ["fit", ".", "--out", "x", "--preset", "measured", "--noise", "constant",
                                       "--likelihood-power", "1", "--chains", "4"])
    assert result.exit_code == 0, result.output
    assert seen[0].given() == {"preset": "measured", "noise": "constant", "likelihood_power": 1.0, "n_chains": 4}


def test_the_preset_sets_the_edge_term_where_it_applies_and_a_given_one_is_checked():
    """The preset's edge power ('auto') for the material model, one channel or a joint colour fit; elsewhere the
    preset does not set it (the plain 0, from the default); a given power that cannot apply fails with the flag
    named."""
    for channel in ("mean", "rgb"):
        resolved = resolve_options(FitOptions(preset="measured", regions="materials", channel=channel))
        assert resolved.edge_power == "auto" and resolved.source("edge_power") == "preset"
    assert resolve_options(FitOptions(regions="materials")).edge_power == 0.0
    assert resolve_options(FitOptions(regions="materials", channel="rgb", edge_power=0.5)).edge_power == 0.5
    for elsewhere in ({"regions": "changepoints"}, {"regions": "materials", "sampler": "paper"},
                      {"regions": "materials", "effects": "ambient"}):
        options = resolve_options(FitOptions(preset="measured", **elsewhere))
        assert (options.edge_power, options.source("edge_power")) == (0.0, "default"), elsewhere
    assert resolve_options(FitOptions(regions="materials", edge_power="0.5")).edge_power == 0.5
    with pytest.raises(ValueError, match="--edge-power"):
        resolve_options(FitOptions(regions="changepoints", edge_power=1.0))
    with pytest.raises(ValueError, match="--edge-power"):
        FitOptions(regions="materials", edge_power="-1")
    given = resolve_options(FitOptions(preset="measured", regions="materials", edge_power=0.0))
    assert given.edge_power == 0.0 and resolve_options(FitOptions.from_json(given.to_json())) == given


def test_the_preset_measures_the_edge_terms_local_gain_with_its_term_and_a_gain_without_one_is_refused():
    """The preset's local gain is 'auto' where it sets the edge term in one channel, and 0 in a joint colour fit
    and where there is no term (change points, effects, a given --edge-power 0); a given gain ('auto' or a number)
    is kept, also in colour, and one without an edge term fails naming both flags."""
    resolved = resolve_options(FitOptions(preset="measured", regions="materials"))
    assert (resolved.edge_gain_sd, resolved.source("edge_gain_sd")) == ("auto", "preset")
    colour = resolve_options(FitOptions(preset="measured", regions="materials", channel="rgb"))
    assert (colour.edge_power, colour.edge_gain_sd, colour.source("edge_gain_sd")) == ("auto", 0.0, "default")
    assert resolve_options(FitOptions(preset="measured", regions="materials", channel="rgb",
                                      edge_gain_sd="auto")).edge_gain_sd == "auto"
    for elsewhere in ({"regions": "changepoints"}, {"regions": "materials", "effects": "ambient"},
                      {"regions": "materials", "edge_power": "0"}):
        assert resolve_options(FitOptions(preset="measured", **elsewhere)).edge_gain_sd == 0.0, elsewhere
    assert resolve_options(FitOptions(preset="measured", regions="materials", edge_power="0.3")).edge_gain_sd == "auto"
    assert resolve_options(FitOptions(preset="measured", regions="materials", edge_gain_sd="0.05")).edge_gain_sd \
        == 0.05
    given = resolve_options(FitOptions(preset="measured", regions="materials", edge_gain_sd="0"))
    assert (given.edge_gain_sd, given.source("edge_gain_sd")) == (0.0, "given")
    assert resolve_options(FitOptions(regions="materials", edge_power=0.5)).edge_gain_sd == 0.0
    with pytest.raises(ValueError, match="--edge-gain-sd.*--edge-power"):
        resolve_options(FitOptions(regions="materials", edge_gain_sd=0.1))
    with pytest.raises(ValueError, match="--edge-gain-sd.*--edge-power"):
        resolve_options(FitOptions(preset="measured", regions="materials", edge_power="0", edge_gain_sd="auto"))
    with pytest.raises(ValueError, match="--edge-gain-sd"):
        FitOptions(regions="materials", edge_gain_sd="-0.1")
    with pytest.raises(ValueError, match="--edge-gain-sd"):
        resolve_options(FitOptions(regions="changepoints", edge_gain_sd=0.1))


def test_the_preset_measures_the_edge_terms_noise_with_its_term_and_a_noise_without_one_is_refused():
    """The preset's edge noise is 'measured' where it sets the edge term, in one channel or a joint colour fit, and
    'constant' where there is no term; a given noise is kept, also in colour; one without a term fails naming
    both flags, and an unknown one names its choices."""
    resolved = resolve_options(FitOptions(preset="measured", regions="materials"))
    assert (resolved.edge_noise, resolved.source("edge_noise")) == ("measured", "preset")
    colour = resolve_options(FitOptions(preset="measured", regions="materials", channel="rgb"))
    assert (colour.edge_noise, colour.source("edge_noise")) == ("measured", "preset")
    assert resolve_options(FitOptions(preset="measured", regions="materials", channel="rgb",
                                      edge_noise="constant")).edge_noise == "constant"
    for elsewhere in ({"regions": "changepoints"}, {"regions": "materials", "effects": "ambient"},
                      {"regions": "materials", "edge_power": "0"}):
        assert resolve_options(FitOptions(preset="measured", **elsewhere)).edge_noise == "constant", elsewhere
    given = resolve_options(FitOptions(preset="measured", regions="materials", edge_noise="constant"))
    assert (given.edge_noise, given.source("edge_noise")) == ("constant", "given")
    assert resolve_options(FitOptions(regions="materials", edge_power=0.5)).edge_noise == "constant"
    with pytest.raises(ValueError, match="--edge-noise.*--edge-power"):
        resolve_options(FitOptions(regions="materials", edge_noise="measured"))
    with pytest.raises(ValueError, match="--edge-noise"):
        FitOptions(regions="materials", edge_noise="loud")


def test_a_floored_edge_noise_is_recorded_and_warned():
    from rjfit.pipeline.regions.materials import edge_noise_record, edge_noise_warnings
    from rjfit.sampler.regions.materials.edge_noise import MIN_WHITE

    assert edge_noise_record("constant") is None and edge_noise_warnings(None) == []
    fine = edge_noise_record((0.8, 0.3, 50.0))
    assert fine == {"white": 0.8, "shading": 0.3, "turn": 50.0, "floored": False} and edge_noise_warnings(fine) == []
    floored = edge_noise_record((MIN_WHITE, 1.0, 2.0))
    assert floored["floored"]
    (warning,) = edge_noise_warnings(floored)
    assert f"floor {MIN_WHITE}" in warning and "--edge-noise" in warning


def test_a_given_local_gain_and_component_moves_reach_the_fit(paper_sphere_small, tmp_path):
    """A given --edge-gain-sd under the preset is the fit's and is recorded (the preset's 'auto' is measured: the
    preset's test below); component moves given through the options land in the sampler's schedule; the preset
    leaves out the spatial splits, which a plain material fit makes and a given value sets."""
    from rjfit.pipeline.regions.materials import MaterialFit

    summary = fit_dataset(paper_sphere_small, tmp_path / "fit", FitOptions(
        preset="measured", regions="materials", edge_gain_sd="0.1", component_moves=1, n_chains=1, iterations=30,
        processes=1, progress=False, figures=False), allow_unvalidated=True)
    assert summary["fit_options"]["edge_gain_sd"] == 0.1 and summary["edge_gain_sd"] == pytest.approx(0.1)
    assert summary["fit_options"]["component_moves"] == 1 and "component" in summary["acceptance_counts"]
    config = MaterialFit().sampler_config(resolve_options(FitOptions(regions="materials", component_moves=3)),
                                          burn=0)
    assert config.regions.component_moves == 3 and config.regions.merge_split.spatial_moves == 1
    assert summary["fit_options"]["spatial_split_moves"] == 0 and "spatial_split" not in summary["acceptance_counts"]
    config = MaterialFit().sampler_config(resolve_options(FitOptions(regions="materials", spatial_split_moves=2)),
                                          burn=0)
    assert config.regions.merge_split.spatial_moves == 2
    config = MaterialFit().sampler_config(resolve_options(FitOptions(regions="materials", scatter_moves=2)), burn=0)
    assert config.regions.scatter_moves == 2 and any(entry.times == 2 and type(entry.move).__name__ == "ScatterMove"
                                                     for entry in config.regions.schedule())


def test_the_ghost_rule_bounds_a_twin_materials_prior_pixels_and_odds():
    mask = np.zeros((60, 80), bool)
    mask[5:55, 10:70] = True
    mask[30, 72:78] = True            # a thin spur: pixels with 1 or 2 neighbours
    beta, rho = ghost_material_prior(mask, 2.0)
    padded = np.pad(mask, 1)
    neighbours = (padded[:-2, 1:-1].astype(int) + padded[2:, 1:-1] + padded[1:-1, :-2] + padded[1:-1, 2:])[mask]
    ghost = np.exp(-beta * neighbours).sum()
    assert ghost <= GHOST_PIXELS < np.exp(-(beta - 0.05) * neighbours).sum()
    assert rho * ghost / 2 == pytest.approx(GHOST_ODDS)
    # a mask whose pixels all have 4 neighbours bar its edge needs less: beta never goes below the given one
    assert ghost_material_prior(np.ones((3, 3), bool), 2.0)[0] >= 2.0


@pytest.mark.parametrize("regions,channel", [("materials", "mean"), ("changepoints", "mean"), ("materials", "rgb")])
def test_a_fit_under_the_preset_records_what_it_estimated(paper_sphere_small, tmp_path, regions, channel):
    summary = fit_dataset(paper_sphere_small, tmp_path / "fit", FitOptions(
        preset="measured", regions=regions, channel=channel, n_chains=1, iterations=30, processes=1, progress=False,
        figures=False), allow_unvalidated=True)
    assert summary["region_model"] == regions
    assert summary["noise"]["model"] == "normals"
    assert 0.0 <= summary["noise"]["normal_error"]["sigma_n_deg"] < 1.0      # the render's footprint: ~0.6
    assert summary["likelihood_power"] == pytest.approx(summary["likelihood_power_suggestion"]["likelihood_power"])
    assert summary["calibration"]["response"] is None          # a linear render: nothing to estimate
    assert summary["calibration"]["isolated_pixels"]["pixels_dropped"] >= 0
    assert summary["anneal_iterations"] == 0
    assert summary["max_view_angle"] == RIM_VIEW_ANGLE          # the rim rule, recorded for `rjfit diagnose`
    sphere = load_dataset(paper_sphere_small)
    rim = sphere.object_mask & (np.sum(sphere.normals * sphere.view_dirs, axis=-1) < RIM_COS)
    assert summary["rim_pixels"] == rim.sum() > 0
    options = summary["fit_options"]
    assert options["preset"] == "measured"
    if regions == "materials":
        assert options["potts_beta"] >= 2.0 and 0 < options["potts_rho"] < 1
        assert options["edge_power"] == "auto" and 0 < summary["edge_power"] <= 1      # as measured
        # the preset's local gain in one channel, measured: a render's shading is exact bar its footprint
        if channel == "mean":
            assert options["edge_gain_sd"] == "auto" and 0 <= summary["edge_gain_sd"] < 0.05
        else:
            assert options["edge_gain_sd"] == 0.0 and summary["edge_gain_sd"] == 0.0
        # the preset's measured noise, in one channel and in colour, recorded
        noise = summary["edge_noise"]
        assert options["edge_noise"] == "measured" and noise["white"] > 0 and noise["shading"] >= 0
        assert noise["turn"] >= 0 and isinstance(noise["floored"], bool)
        # the stated resolution counts the outline's earning, per channel in a colour fit
        assert summary["material_resolution"]["edge_evidence_per_pair"] > 0
        # each material placed by how steeply the object is seen there (the sphere's normals and view directions)
        labels = read_exr(tmp_path / "fit" / "labels.exr")["labels"]
        angles = sphere.view_angles()
        assert angles[sphere.object_mask] == pytest.approx(np.degrees(np.arccos(np.clip(np.sum(
            sphere.normals * sphere.view_dirs, axis=-1), -1, 1)))[sphere.object_mask])
        assert summary["steep_view_angle"] == pytest.approx(np.quantile(angles[labels >= 0], 0.9))
        agreement = read_exr(tmp_path / "fit" / "maps.exr")["map_probability"]
        for region in summary["regions"]:
            mine = labels == region["material"]
            assert region["steep_view_share"] == pytest.approx(np.mean(angles[mine] >= summary["steep_view_angle"]))
            # how often the draws whose parameters it reports give its pixels its label (the map's mean there)
            assert region["label_agreement"] == pytest.approx(np.nanmean(agreement[mine]), rel=1e-5)
        assert len(summary["chain_steep_materials"]) == 1       # one chain: its materials but its largest
        assert all(0.0 <= m["steep_view_share"] <= 1.0 for m in summary["chain_steep_materials"][0])
    else:       # change points have no Potts prior: the rule must not be recorded as if it applied
        assert (options["potts_beta"], options["potts_rho"]) == (FitOptions.default("potts_beta"),
                                                                FitOptions.default("potts_rho"))


def test_the_footprint_noise_is_kept_by_the_preset_and_measured_per_channel_in_colour(paper_sphere_small):
    """In a joint colour fit each channel gets its own footprint estimate (as for the normals' term,
    tests/data/test_normal_error.py): the same numbers as the channel fitted alone."""
    from rjfit.pipeline.fit_power import channel_normal_error_noise
    from rjfit.render.datasets import load_dataset

    assert resolve_options(FitOptions(preset="measured", noise="footprint")).noise == "footprint"
    assert resolve_options(FitOptions(regions="materials", channel="rgb", noise="footprint")).noise == "footprint"
    dataset = load_dataset(paper_sphere_small)
    colour = dataset.observations("rgb")
    scale, record = channel_normal_error_noise(colour, footprint=True)
    for c, name in enumerate("RGB"):
        alone_scale, alone = normal_error_noise(dataset.observations(name), footprint=True)
        np.testing.assert_array_equal(scale[colour.channel == c], alone_scale)
        assert record["channels"][c]["t"] == alone["t"]


def test_a_fit_with_the_footprint_term_records_it(paper_sphere_small, tmp_path):
    """The preset with ``--noise footprint`` (1 chain x 30 iterations, about 15 s): the estimate is recorded
    with both scale parameters, and the scales the sampler used are those the noise model gives."""
    summary = fit_dataset(paper_sphere_small, tmp_path / "fit", FitOptions(
        preset="measured", noise="footprint", regions="materials", n_chains=1, iterations=30, processes=1,
        progress=False, figures=False), allow_unvalidated=True)
    record = summary["noise"]["normal_error"]
    assert summary["noise"]["model"] == "footprint" and "f_i^2" in summary["noise"]["formula"]
    assert record["k"] >= 0 and record["t"] >= 0 and record["c"] == pytest.approx(record["t"] * record["sigma_r2"])
    assert 0.0 <= record["footprint_share"] < 1.0
    assert summary["noise"]["scale_min"] >= 1.0
