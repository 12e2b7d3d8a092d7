"""``rjfit fit --regions materials`` end to end on a small in-code stack: the files and summary entries it writes.

A 12 x 14 image under 8 lights with three materials, one of them in two disconnected
patches; 2 chains of 200 iterations (about 10 s). The checks are on what the fit writes
(schema, shapes, ranges), plus that the MAP materials put both patches in one material
(the data separate the three materials by far: noise sd 0.14 against differences of 4 in I0).
"""
import dataclasses
import html
import json

import numpy as np
import pytest
from builders import smooth_shading_observations

from rjfit.data.exr import read_exr
from rjfit.data.observations import Observations
from rjfit.model.blinn import radiance
from rjfit.pipeline.fit import fit
from rjfit.pipeline.fit_folder import read_summary

TRUTH = np.array([[10.0, 0.8, 5.0, 0.02], [6.0, 0.4, 30.0, 0.02], [14.0, 0.6, 12.0, 0.02]])


def stack(height=12, width=14, lights=8, seed=0):
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:height, 0:width]
    truth = np.zeros((height, width), int)
    truth[(rows - 6) ** 2 + (cols - 4) ** 2 < 9] = 1
    truth[:, 10:] = 2
    truth[1:3, 11:13] = 1          # a second, disconnected patch of material 1
    pixel = np.repeat(np.arange(height * width), lights)
    cos_ln, cos_hn = rng.uniform(0.2, 1, pixel.size), rng.uniform(0.5, 1, pixel.size)
    irradiance = rng.uniform(0.5, 1.5, pixel.size)
    theta = TRUTH[truth.ravel()[pixel]]
    y = radiance(theta[:, 0], theta[:, 1], theta[:, 2], cos_ln, cos_hn, irradiance) + rng.normal(0, 0.14, pixel.size)
    obs = Observations(image_shape=(height, width), n_lights=lights, pixel=pixel.astype(np.int64),
                       light=np.tile(np.arange(lights), height * width).astype(np.int32), y=y, cos_ln=cos_ln,
                       cos_hn=cos_hn, irradiance=irradiance, object_mask=np.ones((height, width), bool))
    return obs, truth


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    obs, truth = stack()
    out = tmp_path_factory.mktemp("fit") / "out"
    summary = fit(obs, out, regions="materials", iterations=200, n_chains=2, processes=1, truth_labels=truth,
                  progress=False, seed=3)
    return out, summary, truth


def test_summary_has_the_material_entries(fitted):
    out, summary, truth = fitted
    assert read_summary(out)["region_model"] == "materials"
    posterior = summary["materials_posterior"]
    assert sum(posterior.values()) == pytest.approx(1.0)
    assert summary["map_materials"] == int(max(posterior, key=posterior.get)) == len(summary["regions"])
    assert all(region["pixels"] >= 0 and "I0" in region for region in summary["regions"])
    assert "no material is ever empty" in summary["empty_materials"] and summary["max_materials"] == 8
    assert 0.0 <= summary["materials_right_probability"] <= 1.0
    assert "map_model" not in summary and "changepoints.npz" not in {p.name for p in out.iterdir()}
    extra = read_summary(out)["extra_materials"]      # over the kept snapshots of both chains, in the file
    with np.load(out / "materials.npz") as files:
        kept = sum(int((files[f"chain{c}_cp_iteration"] >= summary["burn_in"]).sum()) for c in range(2))
    assert extra["snapshots"] == kept > 0 and extra["materials"] == summary["segmentation_materials"]
    # the snapshots are kept draws: one with more materials than the segmentation is mass of the K posterior above it
    above = sum(share for k, share in posterior.items() if int(k) > extra["materials"])
    assert (extra["share"] > 0) <= (above > 0) and (extra["pixels"] is None) == (extra["share"] == 0)
    # the map of where they lie: each pixel's share of the kept snapshots, its largest at the summary's place
    share = read_exr(out / "maps.exr")["extra_material_share"]
    assert share.shape == truth.shape and np.nanmin(share) >= 0.0 and np.nanmax(share) <= extra["share"] + 1e-6
    where = extra["most_often"]
    assert (where is None) == (extra["pixels"] is None)
    if where is not None:
        assert share[where["row"], where["column"]] == pytest.approx(np.nanmax(share)) == \
            pytest.approx(where["share"], abs=1e-6)


def test_each_material_states_how_bright_it_is_against_its_surroundings_under_each_light(fitted, tmp_path):
    """The summary's ``contrast_to_surroundings`` of each material is the ratio of its brightness (its observations
    over their Lambertian shading) to its ring's, light by light, as :mod:`rjfit.posterior.contrast` computes it from
    the data and the written labels (the fit reads float32 copies of the observations: a relative tolerance of 1e-5);
    the report and the terminal say it, with what it means."""
    from rjfit.pipeline.regions.materials import MaterialFit
    from rjfit.pipeline.report import build_report
    from rjfit.posterior.contrast import MEANING, material_contrasts

    out, summary, _ = fitted
    obs, _ = stack()
    labels = np.rint(read_exr(out / "labels.exr")["labels"]).astype(int)
    expected = material_contrasts(obs.y, obs.light, obs.pixel, labels, obs.n_lights, obs.irradiance * obs.cos_ln)
    regions = read_summary(out)["regions"]
    assert len(regions) == len(expected) == 3
    for region, want in zip(regions, expected):
        got = region["contrast_to_surroundings"]
        assert got["pixels"] == region["pixels"] == want["pixels"] and got["lights"] == obs.n_lights
        assert got["ring_pixels"] == want["ring_pixels"] > 0
        for key in ("min", "lower_quartile", "median", "upper_quartile", "max", "spread", "middle_spread"):
            assert got[key] == pytest.approx(want[key], rel=1e-5)
    text = build_report(out, tmp_path / "report.html").read_text()
    first = regions[0]
    assert f"Material 0 ({first['pixels']:,} px): its Lambertian albedo " in text
    assert f"is {first['contrast_to_surroundings']['min']:.2f} to " in text
    assert html.escape(MEANING) in text
    printed = MaterialFit.printed_notes(summary)
    assert sum(note.startswith("material ") for note in printed) == 3 and printed[-1][0].islower()


@pytest.mark.parametrize("scaled", [False, True])
def test_the_place_of_the_extra_materials_states_its_contrast_from_the_fitted_observations(scaled):
    """On a one-material segmentation of the flat patch (:func:`builders.paint_and_shadow_observations`) whose extra
    materials' share peaks on the shadowed square, the place's contrast is the shadow's per-light factors; a
    material alone has none. With known noise scales (the problem stores ``y / s``) the same: they are undone."""
    from builders import SHADOW_FACTORS, paint_and_shadow_observations

    from rjfit.pipeline.regions.materials import add_contrasts
    from rjfit.sampler.forward import Problem

    obs, truth = paint_and_shadow_observations()
    scale = np.linspace(0.5, 2.0, obs.y.size) if scaled else None
    problem = Problem.from_observations(obs, noise_scale=scale)
    labels = np.where(truth >= 0, 0, -1)
    share = np.where(truth == 2, 0.3, 0.0)
    share[12, 16] = 0.5                                     # the peak, inside the shadowed square
    regions = [{"material": 0, "pixels": int((labels == 0).sum())}]
    extra = {"most_often": {"row": 12, "column": 16, "share": 0.5}}
    add_contrasts(problem, labels, regions, extra, share)
    assert regions[0]["contrast_to_surroundings"] is None
    place = extra["most_often"]["contrast"]
    # the place: the square's 36 px (each at least half the peak); float32 storage: a relative tolerance of 1e-6
    assert place["pixels"] == 36 and place["lights"] == SHADOW_FACTORS.size
    assert place["min"] == pytest.approx(SHADOW_FACTORS.min(), rel=1e-6)
    assert place["spread"] == pytest.approx(1 / SHADOW_FACTORS.min(), rel=1e-6)


def test_the_terminal_and_the_report_say_how_large_the_extra_materials_of_other_draws_are():
    """A K posterior of 0.72 at one material, the rest specks: the printed line and the report's notes carry the
    caveat's sentence; a fit without such draws has none."""
    from rjfit.pipeline.regions.materials import MaterialFit
    from rjfit.posterior.contrast import MEANING, contrast_entry

    extra = {"materials": 1, "snapshots": 200, "share": 0.28, "chain_shares": [1.0, 0.02, 0.04, 0.06],
             "pixels": {"min": 1, "median": 24.0, "max": 34}}
    summary = {"map_materials": 1, "materials_posterior": {"1": 0.72, "2": 0.28}, "map_probability_mean": 1.0,
               "extra_materials": extra}
    sentence = "28% of the kept label snapshots hold more materials than the segmentation's 1, their extra materials "
    assert f"; {sentence}1 to 34 px (median 24) in all" in MaterialFit.printed_line(summary)
    assert f"{sentence[0].upper()}{sentence[1:]}1 to 34 px (median 24) in all." in MaterialFit.report_notes(summary)
    other_map = MaterialFit.printed_line({**summary, "map_materials": 2, "materials_posterior": {"2": 0.5, "1": 0.5},
                                          "segmentation_materials": 1})
    assert "least disagree with the others) holds 1 material; 28% of" in other_map
    # what a Lambertian albedo means goes with the place's contrast where no material states its own
    assert not any("Lambertian albedo" in note for note in MaterialFit.report_notes(summary))
    place = {"row": 3, "column": 4, "share": 0.2, "contrast": contrast_entry(np.array([0.9, 1.0, 1.2]), 3, 3, 20)}
    placed = {**summary, "extra_materials": {**extra, "most_often": place}}
    assert "a place of 3 px: its Lambertian albedo is 0.90 to 1.20 times" in MaterialFit.printed_line(placed)
    assert MEANING in MaterialFit.report_notes(placed)
    assert MaterialFit.printed_notes(placed) == [MEANING[0].lower() + MEANING[1:]]
    settled = {**summary, "extra_materials": {**extra, "share": 0.0, "pixels": None}}
    assert "kept label snapshots" not in MaterialFit.printed_line(settled)
    assert not any("kept label snapshots" in note for note in MaterialFit.report_notes(settled))


def test_the_fitted_model_leaves_white_residuals_on_data_it_generated(fitted):
    _, summary, _ = fitted
    misfit = summary["model_misfit"]
    # about 2,500 neighbour pairs (sd of rho near 0.02); the posterior mean's own error, shared by a material's pixels,
    # adds a little positive correlation (of the order of its 12 parameters over 1,300 observations)
    assert misfit["rho"] < 0.1 and misfit["implied_power"] > 0.8
    assert read_summary(fitted[0])["model_misfit"]["pairs"] == misfit["pairs"] > 2000


def test_the_three_materials_form_three_edge_groups_in_every_counted_snapshot(fitted):
    """The data separate the three materials by far (I0 6, 10, 14 against noise sd 0.14), so every boundary between
    them is an edge in every snapshot; a twin of a material, if a chain held one, would be joined to it."""
    _, summary, _ = fitted
    assert summary["edge_groups_posterior"] == {"3": 1.0}
    assert summary["edge_groups_snapshots"] == 2 * 10 and len(summary["chain_edge_groups_posterior"]) == 2


def test_the_command_line_states_the_edge_groups(fitted, capsys):
    from rjfit.cli import _echo_fit

    out, summary, _ = fitted
    _echo_fit(out, {**summary, "dataset": "in-code stack", "channel": "mean"})     # what fit_dataset adds
    assert ("edge-supported material groups (materials that meet where the data show no step joined, 20 snapshots): "
            "3: 1.00") in capsys.readouterr().out


def test_the_report_states_the_boundaries_and_the_edge_groups(fitted, tmp_path):
    from rjfit.pipeline.report import build_report

    out, _, _ = fitted
    text = build_report(out, tmp_path / "report.html").read_text()
    assert ("Boundaries: of the 3 boundaries between MAP materials, 3 show a step in the data and 0 show none "
            "(odds of 100:1); joined where they show none, the materials form 3 group(s).") in text
    assert ("Edge-supported groups over 20 label snapshots (materials that meet where the data show no step joined): "
            "3: 1.00.") in text


def test_the_report_says_where_a_materials_parameters_come_from(fitted, tmp_path):
    """A material summarised over the draws that hold it (``parameters_from``) and one that no draw holds (null) are
    marked under their names in the report's table; the others are not."""
    import shutil

    from rjfit.pipeline.report import build_report

    out, _, _ = fitted
    folder = tmp_path / "fit"
    shutil.copytree(out, folder)
    summary = json.loads((folder / "summary.json").read_text())
    summary["regions"][1]["parameters_from"] = {"draws": 37, "chains": [0, 2], "match_min": 0.5, "rhat_max": 1.2,
                                                "ess_bulk_min": 9.0}
    summary["regions"][2]["parameters_from"] = None
    (folder / "summary.json").write_text(json.dumps(summary))
    text = build_report(folder, tmp_path / "report.html").read_text()
    assert text.count("from the 37 draws that hold it (chain 0, 2)") == 1
    assert text.count("no draw holds it: parameters unknown") == 1


def test_map_materials_keep_the_two_patches_together(fitted):
    out, summary, truth = fitted
    labels = np.rint(read_exr(out / "labels.exr")["labels"]).astype(int)
    assert summary["label_accuracy"] > 0.98
    assert len(set(labels[truth == 1].tolist())) == 1


def test_files_maps_and_chains(fitted):
    import arviz as az

    out, summary, truth = fitted
    maps = read_exr(out / "maps.exr")
    probability = maps["map_probability"]
    assert probability.shape == truth.shape and np.all((probability > 0) & (probability <= 1))
    idata = az.from_netcdf(str(out / "chains.nc"))
    assert idata.posterior["theta"].dims == ("chain", "draw", "material", "parameter")
    assert idata.posterior["theta"].shape[2] == summary["map_materials"]
    snapshots = np.load(out / "materials.npz")
    assert snapshots["chain0_material_labels"].shape[1:] == truth.shape
    assert {"materials", "materials_histogram", "reflectance"} <= set(summary["figures"])
    assert all((out / path).is_file() for path in summary["figures"].values())
    assert json.loads((out / "summary.json").read_text())["fit_id"] == summary["fit_id"]


def test_the_chains_start_stratified_over_the_number_of_materials(tmp_path):
    """A fit's chains start at K0 = 1, 2, 3, 4, 1, ... materials (capped by --max-materials), so
    that a mode at a small K is started near by some chain whatever the seed; with the edge term every chain
    starts at 4 (capped), which it leaves by merges; a fixed segmentation or a given start is kept."""
    from rjfit.pipeline.fit import chain_specs, prepare_problem, sampler_config
    from rjfit.pipeline.options import FitOptions
    from rjfit.pipeline.resolve import resolve_options
    from rjfit.sampler.kernel import initial_state
    from rjfit.sampler.priors import make_prior

    obs, truth = stack()
    for max_materials, edge_power, expected in ((8, 0.0, [1, 2, 3, 4, 1, 2]), (3, 0.0, [1, 2, 3, 1, 2, 3]),
                                                (8, 0.5, [4] * 6), (3, 0.5, [3] * 6)):
        options = resolve_options(FitOptions(regions="materials", n_chains=6, max_materials=max_materials,
                                             iterations=20, edge_power=edge_power))
        problem = prepare_problem(obs, options)[0]
        prior, config = make_prior(options.prior, y=problem.y, diffuse_scale=problem.A), sampler_config(options)
        specs = chain_specs(problem, prior, config, options, tmp_path, None, None, None)
        starts = [initial_state(problem, prior, config, np.random.default_rng(s.chain), **s.start).layout.n_materials
                  for s in specs]
        assert starts == expected
    fixed = chain_specs(problem, prior, config, options, tmp_path, None, None, truth)
    assert all("n_materials" not in s.start and s.start["pixel_labels"] is truth for s in fixed)


def test_relabelled_draws_carry_a_snapshots_matching_to_the_draws_after_it_up_to_a_jump():
    """Draws between label snapshots count (not one in cp_thin only), each numbered as the snapshot
    before it, and none after a step that changed the number of materials before the next snapshot
    (there the rows may be renumbered). A chain whose rows swap at a recorded jump (t = 12)."""
    from rjfit.posterior.materials import relabelled_draws
    from rjfit.sampler.runner import ChainRecord

    T, thin, k = 20, 5, 2
    labels = np.array([[0, 0, 1]], float)
    a, b = [10.0, 0.8, 5.0, 0.02], [6.0, 0.4, 30.0, 0.02]
    theta = np.array([[a, b]] * 12 + [[b, a]] * 8)                 # rows swapped from t = 12 on
    snapshots = np.array([labels, labels, labels, 1 - labels])     # t = 0, 5, 10, 15
    jumped = np.zeros(T, np.int8)
    jumped[12] = 1
    record = ChainRecord(theta=theta, log_lik=np.zeros(T), log_post=np.arange(T, dtype=float),
                         exact_truth=np.full(T, -1, np.int8), true_regions=np.full(T, -1, np.int8),
                         object_regions=np.full(T, k, np.int16), cp_iteration=np.arange(0, T, thin), accepted={},
                         proposed={}, seconds=0.0, iterations_done=T, n_materials=np.full(T, k),
                         material_labels=snapshots.astype(np.float32), jumped=jumped)
    draws = relabelled_draws([record], 0, k)
    (chain,) = draws.theta
    assert len(chain) == T - 3                      # draws 12, 13, 14: after the jump, before snapshot 15
    reference_material_of_a = 1                     # the reference: snapshot 15 (highest log posterior)
    np.testing.assert_array_equal(chain[:, reference_material_of_a], np.tile(a, (len(chain), 1)))
    assert len(draws.labels[0]) == 4                # labels: the snapshots only
    older = relabelled_draws([dataclasses.replace(record, jumped=None)], 0, k)
    assert len(older.theta[0]) == 4                 # a chain that did not record its jumps: snapshots only
    # a chain shorter than the snapshot interval: its one snapshot carries to all its draws
    short = dataclasses.replace(record, theta=theta[:4], log_lik=np.zeros(4), log_post=np.zeros(4),
                                exact_truth=record.exact_truth[:4], true_regions=record.true_regions[:4],
                                object_regions=record.object_regions[:4], cp_iteration=np.array([0]),
                                n_materials=np.full(4, k), material_labels=snapshots[:1].astype(np.float32),
                                jumped=np.zeros(4, np.int8), iterations_done=4)
    assert len(relabelled_draws([short], 0, k).theta[0]) == 4


def test_a_material_few_draws_at_its_k_hold_is_summarised_over_the_draws_that_hold_it():
    """summarise_from_own_draws: a disc held by one chain (I0 about 3) that the other chain, at the same K, lacks (its
    second material a strip, I0 about 7). The entry's parameters become the disc's own draws', its pixels and label
    agreement stay, and ``parameters_from`` names the chain; a mask no draw holds leaves the entry and records None."""
    from rjfit.pipeline.regions.materials import summarise_from_own_draws
    from rjfit.posterior.materials import material_summaries, relabelled_draws
    from rjfit.sampler.runner import ChainRecord

    rng = np.random.default_rng(0)
    disc, strip = np.zeros((6, 6), bool), np.zeros((6, 6), bool)
    disc[1:3, 1:3], strip[5] = True, True

    def chain(part, i0):
        theta = np.tile([1.0, 0.5, 10.0, 0.01], (40, 2, 1))
        theta[:, 1, 0] = i0 + 0.1 * rng.standard_normal(40)
        labels = np.tile(part.astype(np.float32), (8, 1, 1))
        return ChainRecord(theta=theta, log_lik=np.zeros(40), log_post=np.zeros(40),
                           exact_truth=np.full(40, -1, np.int8), true_regions=np.full(40, -1, np.int8),
                           object_regions=np.full(40, 2, np.int16), cp_iteration=np.arange(0, 40, 5), accepted={},
                           proposed={}, seconds=0.0, iterations_done=40, n_materials=np.full(40, 2),
                           material_labels=labels, jumped=np.zeros(40, np.int8))

    records = [chain(disc, 3.0), chain(strip, 7.0)]
    reference = disc.astype(np.int64)
    summaries, _ = material_summaries(relabelled_draws(records, 0, 2, reference=reference), reference)
    entry = {**summaries[1], "label_agreement": 0.5}
    assert entry["I0"]["mean"] == pytest.approx(5.0, abs=0.1)            # the mixture of the disc and the strip
    summarise_from_own_draws(entry, records, 0, disc, 1)
    assert entry["I0"]["mean"] == pytest.approx(np.mean(records[0].theta[:, 1, 0]), rel=1e-12)
    assert entry["pixels"] == 4 and entry["label_agreement"] == 0.5 and entry["material"] == 1
    assert entry["parameters_from"]["draws"] == 40 and entry["parameters_from"]["chains"] == [0]
    nowhere = np.zeros((6, 6), bool)
    nowhere[0, 5] = nowhere[4, 0] = True
    unheld = dict(summaries[1])
    summarise_from_own_draws(unheld, records, 0, nowhere, 1)
    assert unheld["parameters_from"] is None and unheld["I0"] == summaries[1]["I0"]


def ramp_stack():
    """One lobe whose I0 rises smoothly from 4 to 8 across a 24 x 24 image under 8 lights (noise sd 0.05)."""
    rng = np.random.default_rng(4)
    size, lights = 24, 8
    pixel = np.repeat(np.arange(size * size), lights)
    cos_ln, cos_hn = rng.uniform(0.2, 1, pixel.size), rng.uniform(0.5, 1, pixel.size)
    irradiance = rng.uniform(0.5, 1.5, pixel.size)
    I0 = np.tile(np.linspace(4.0, 8.0, size), size)[pixel]
    y = radiance(I0, 0.8, 5.0, cos_ln, cos_hn, irradiance) + rng.normal(0, 0.05, pixel.size)
    obs = Observations(image_shape=(size, size), n_lights=lights, pixel=pixel.astype(np.int64),
                       light=np.tile(np.arange(lights), size * size).astype(np.int32), y=y, cos_ln=cos_ln,
                       cos_hn=cos_hn, irradiance=irradiance, object_mask=np.ones((size, size), bool))
    return obs


@pytest.mark.parametrize("power", [0.05, 0.1])
def test_a_smooth_ramp_split_into_materials_is_reported_as_one_group(tmp_path, power):
    """One lobe whose I0 rises smoothly from 4 to 8 across a 24 x 24 image (noise sd 0.05): at likelihood powers
    0.05 and 0.1 the fit buys two or three bands along the ramp, 8 to 14 px wide (the precondition, checked), and
    the boundary check finds no step in the data where they meet (log ratios -230 to -1,150 with this seed), so it
    warns and joins them into one group, which maps.exr's edge_group holds. (At power 0.25 the fit cuts five
    bands about 5 px wide, and pairs 3 px apart then straddle a staircase step that matches the ramp's rise: the
    check's limit, docs/results/materials.md, "Boundaries". The spatial splits are left out: with them the chains
    reach that limit at power 0.1, four bands about 6 px wide, docs/results/2026-12-01-spatial-splits.md.)"""
    obs = ramp_stack()
    summary = fit(obs, tmp_path / "out", regions="materials", iterations=200, n_chains=2, processes=1, progress=False,
                  seed=1, figures=False, likelihood_power=power, spatial_split_moves=0)
    assert summary["map_materials"] >= 2
    assert summary["edge_supported_materials"] == 1 and summary["material_groups"] == [
        list(range(summary["map_materials"]))]
    assert all(row["log_likelihood_ratio"] < 0 for row in summary["boundaries"])
    assert any("meet where the data show no edge" in w for w in summary["warnings"])
    edge_group = read_exr(tmp_path / "out" / "maps.exr")["edge_group"]
    assert np.all(edge_group == 0)
    # every counted snapshot's bands, not only the MAP's, form one group
    assert summary["edge_groups_posterior"] == {"1": 1.0} and summary["edge_groups_snapshots"] == 2 * 10


def smooth_ramp_stack():
    """:func:`ramp_stack`'s ramp (I0 from 4 to 8 across 24 x 24 px, 8 lights, noise sd 0.05) on a surface whose shading
    is smooth across neighbouring pixels, as a real surface's is (``ramp_stack`` draws each observation's angles on
    their own)."""
    rng = np.random.default_rng(4)
    size = 24

    def reflected(col, cos_ln, cos_hn):
        I0 = np.linspace(4.0, 8.0, size)[col]
        return radiance(I0, 0.8, 5.0, cos_ln, cos_hn, np.ones(col.size)) + rng.normal(0, 0.05, col.size)

    return smooth_shading_observations((size, size), 8, reflected, cos_ln_mean=0.6)


def test_with_the_edge_term_the_ramp_stays_one_material_and_three_paints_stay_three(tmp_path, capsys):
    """The smooth ramp at likelihood power 0.1: without the term the fit buys bands along it (K > 1 takes at least
    0.9, the precondition); with the edge term at its 'auto' power the bands' boundaries explain the neighbours'
    differences no better than the data's own trend, so they cost and K = 1 takes at least 0.9 (every chain starts
    at 4 materials). The three-material stack keeps its three materials, every boundary an edge, labels at least
    98 % right. The command line states the term's power.

    On ``ramp_stack`` (each observation's shading drawn on its own) the term cannot do this: no trend follows
    shading that jumps from pixel to pixel, so a staircase of bands explains the differences better than one
    material and better than no step, and earns (docs/results/2026-11-28-trend-cost.md)."""
    from rjfit.cli import _echo_fit

    bands = fit(smooth_ramp_stack(), tmp_path / "bands", regions="materials", iterations=200, n_chains=2, processes=1,
                progress=False, seed=1, figures=False, likelihood_power=0.1)
    assert bands["materials_posterior"].get("1", 0.0) <= 0.1, bands["materials_posterior"]
    ramp = fit(smooth_ramp_stack(), tmp_path / "ramp", regions="materials", iterations=200, n_chains=2, processes=1,
               progress=False, seed=1, figures=False, likelihood_power=0.1, edge_power="auto")
    assert 0 < ramp["edge_power"] <= 1
    assert ramp["materials_posterior"].get("1", 0.0) >= 0.9, ramp["materials_posterior"]
    obs, truth = stack()
    paints = fit(obs, tmp_path / "paints", regions="materials", iterations=200, n_chains=2, processes=1,
                 truth_labels=truth, progress=False, seed=3, figures=False, edge_power="auto")
    assert paints["map_materials"] == 3 and paints["label_accuracy"] >= 0.98
    _echo_fit(tmp_path / "ramp", {**ramp, "dataset": "in-code ramp", "channel": "mean"})
    assert f"edge term in the target (power {ramp['edge_power']:.3g})" in capsys.readouterr().out
