"""The report explains itself (issue 43, item 6): every setting in words, rows named for a reader, figures
captioned by what they show, and figures whose axes say what they measure.

Two small real fits of the session's 48 x 48 paper_sphere render (2 chains x 40 iterations each):
one under ``--preset measured`` with materials (its settings are the ones the issue lists), one
with change points and the truth (its rows include the truth's probabilities, and its chains
feed the figure functions). Cost: about 30 s on the loaded 2-core machine once Numba's cache is
warm.
"""
import re

import arviz as az
import numpy as np
import pytest

from rjfit.pipeline.fit import fit, prepare_problem
from rjfit.pipeline.fit_dataset import fit_dataset
from rjfit.pipeline.options import FitOptions
from rjfit.pipeline.report import build_report
from rjfit.pipeline.resolve import resolve_options
from rjfit.plotting import pyplot
from rjfit.posterior import figures
from rjfit.posterior import summary as post
from rjfit.posterior.chain_figures import chain_figure, chain_series, rank_counts
from rjfit.render.datasets import load_dataset
from rjfit.sampler.runner import run_chain

#: a row label that is a JSON key: snake_case, or dotted (``map_model.n_u``)
RAW_KEY = re.compile(r"[a-z0-9]+(_[a-z0-9]+)+|[a-z_0-9]+\.[a-z_0-9]+")


@pytest.fixture(scope="module")
def measured_fit(paper_sphere_small, tmp_path_factory):
    folder = tmp_path_factory.mktemp("measured") / "fit"
    fit_dataset(paper_sphere_small, folder, FitOptions(preset="measured", regions="materials", n_chains=2,
                                                       iterations=40, processes=1, progress=False, seed=4),
                allow_unvalidated=True)
    return folder


@pytest.fixture(scope="module")
def changepoint_fit(paper_sphere_small, tmp_path_factory):
    """A change-point fit with the truth, and its chains' records (run here, in this process)."""
    dataset = load_dataset(paper_sphere_small)
    observations = dataset.observations("mean")
    records = []

    def runner(specs):
        records.extend(run_chain(spec) for spec in specs)
        return records

    folder = tmp_path_factory.mktemp("changepoints") / "fit"
    summary = fit(observations, folder, n_chains=2, iterations=40, processes=1, progress=False, seed=2,
                  truth_labels=dataset.truth_labels, chain_runner=runner)
    return folder, records, summary, observations


def _section(text: str, start: str, end: str) -> str:
    return text[text.index(start):text.index(end, text.index(start))]


def test_the_settings_of_a_measured_fit_are_all_there_in_words(measured_fit):
    page = build_report(measured_fit).read_text(encoding="utf-8")
    settings = _section(page, "<h3>Fit settings</h3>", "<h2>Figures</h2>")
    for words in ("region model", "materials: a material label per pixel under a Potts prior", "preset",
                  "measured: the defaults for measured stacks", "Potts prior (beta, rho)", "per pair of neighbouring "
                  "pixels", "edge term power", "measured (auto", "rim (max. view angle)", "72.5", "calibration "
                  "(response, gains)", "camera response", "light gains", "noise model", "normals: ",
                  "the normals&#x27; error estimated", "likelihood power (zeta)", "auto: ((1 - rho) / (1 + rho))^2",
                  "channel", "the mean of R, G and B", "effects", "chains x iterations", "2 chains x 40 iterations",
                  "burn-in", "the first 20 iterations of each chain (50 %) discarded", "seed</td><td class='note'>4<"):
        assert words in settings, words


def _row_labels(page: str) -> list:
    """The first cell of every table row, and every header cell."""
    return re.findall(r"<tr><td>([^<]*)", page) + re.findall(r"<th>([^<]*)", page)


@pytest.mark.parametrize("which", ["measured", "changepoints"])
def test_no_row_is_labelled_by_a_json_key_and_every_caption_says_what_it_shows(which, measured_fit,
                                                                                 changepoint_fit):
    folder = measured_fit if which == "measured" else changepoint_fit[0]
    page = build_report(folder).read_text(encoding="utf-8")
    raw = [label for label in _row_labels(page) if RAW_KEY.fullmatch(label.strip())]
    assert raw == []
    for key in ("map_model.n_u", "rhat_reason", "exact_truth_probability", "true_regions_probability", "ess_min"):
        assert key not in page
    captions = re.findall(r"<figcaption>(.*?)</figcaption>", page)
    stems = {path.stem.replace("_", " ") for path in (folder / "figures").glob("*.png")}
    assert len(captions) == len(stems) + 1          # the fit's figures and the chains' traces and rank plots
    for caption in captions:
        assert caption not in stems and len(caption.split()) >= 8, caption
    assert any("rank histograms" in caption for caption in captions)
    # the alt text still names each figure (its file name in words), the caption says what it shows
    assert all(f'alt="{stem}"' in page for stem in stems)
    assert "what it means, when it is good" in page


def test_the_truth_probabilities_are_told_apart(changepoint_fit):
    page = build_report(changepoint_fit[0]).read_text(encoding="utf-8")
    assert "probability of the true regions" in page and "probability of the exact true partition" in page
    assert "asks for every pixel" in page
    assert re.search(r"MAP model \(n_u, n_v\)</td><td>\(\d, \d\)</td>", page)


def _image_axes(figure):
    return [axis for axis in figure.axes if axis.images and axis.get_label() != "<colorbar>"]


def test_the_figures_label_their_axes_and_tell_the_chains_apart(changepoint_fit):
    folder, records, summary, observations = changepoint_fit
    burn, model = summary["burn_in"], (summary["map_model"]["n_u"], summary["map_model"]["n_v"])
    plt = pyplot()

    histogram = figures.model_histogram_figure(records, burn)
    axis = histogram.axes[0]
    assert "(n_u, n_v)" in axis.get_xlabel() and axis.get_ylabel() == "posterior probability"
    assert all(re.fullmatch(r"\(\d, \d\)", tick.get_text()) for tick in axis.get_xticklabels())

    traces = figures.trace_figure(records, burn, model)
    legend = [axis.get_legend() for axis in traces.axes if axis.get_legend() is not None]
    assert len(legend) == 1 and [t.get_text() for t in legend[0].get_texts()] == ["chain 0", "chain 1"]
    assert all(axis.get_xlabel() for axis in traces.axes[-4:])
    assert {line.get_linestyle() for line in traces.axes[0].get_lines()[:2]} == {"-", "--"}

    problem = prepare_problem(observations, resolve_options(FitOptions()))[0]
    labels = post.map_labels(records, burn, model, problem.image_shape, problem.object_mask)
    reflectance = figures.reflectance_figure(labels, post.posterior_mean_prediction(records, burn, problem))
    panels = _image_axes(reflectance)
    assert len(panels) == 4
    assert all((a.get_xlabel(), a.get_ylabel()) == ("column (px)", "row (px)") for a in panels)
    colour_bars = [axis for axis in reflectance.axes if axis not in panels]
    assert len(colour_bars) == 4 and all(axis.get_ylabel() for axis in colour_bars)
    assert [axis.get_ylabel() for axis in colour_bars][:3] == ["radiance (image units)"] * 3

    materials = figures.material_map_figure(labels)
    assert (materials.axes[0].get_xlabel(), materials.axes[0].get_ylabel()) == ("column (px)", "row (px)")
    counts = figures.materials_histogram_figure({"1": 0.25, "2": 0.7, "3": 0.05})
    assert [tick.get_text() for tick in counts.axes[0].get_xticklabels()] == ["1", "2", "3"]
    assert counts.axes[0].get_xlabel() == "number of materials K"

    chains = chain_figure(az.from_netcdf(str(folder / "chains.nc")), burn_in=burn)
    trace_axes, rank_axes = chains.axes[0::2], chains.axes[1::2]
    assert [t.get_text() for t in trace_axes[0].get_legend().get_texts()] == ["chain 0", "chain 1"]
    assert trace_axes[0].get_title(loc="left").startswith("log posterior")
    assert all(axis.get_ylabel() for axis in trace_axes) and trace_axes[-1].get_xlabel()
    assert all([t.get_text() for t in axis.get_yticklabels()] == ["chain 0", "chain 1"] for axis in rank_axes)
    for figure in (histogram, traces, reflectance, materials, counts, chains):
        plt.close(figure)


def test_rank_counts_pool_the_chains_and_skip_missing_draws():
    """Ranks among all chains' finite draws: two chains that alternate fill every bin equally; NaN is left out."""
    values = np.array([[0.0, 2.0, 4.0, 6.0], [1.0, 3.0, 5.0, np.nan]])
    counts = rank_counts(values, bins=7)
    np.testing.assert_array_equal(counts, [[1, 0, 1, 0, 1, 0, 1], [0, 1, 0, 1, 0, 1, 0]])


def test_the_chain_figure_reads_either_layout_of_chains_nc():
    """Today's layout (``theta`` with a parameter dimension, NaN-padded regions, ``log_post``) and the
    standard one (a variable per parameter, ``sample_stats.lp``) give the same series."""
    rng = np.random.default_rng(0)
    theta = rng.normal(size=(2, 30, 3, 4))
    theta[:, :, 2] = np.nan                                  # a padded region slot no draw uses
    lp = rng.normal(size=(2, 30))
    names = ["I0", "kd", "gamma", "sigma2"]
    padded = az.from_dict(posterior={"theta": theta, "log_post": lp},
                          coords={"region": np.arange(3), "parameter": names}, dims={"theta": ["region", "parameter"]})
    standard = az.from_dict(posterior={name: theta[:, :, :2, k] for k, name in enumerate(names)},
                            sample_stats={"lp": lp}, coords={"region": np.arange(2)},
                            dims={name: ["region"] for name in names})
    first, second = chain_series(padded, max_regions=3), chain_series(standard, max_regions=3)
    assert [title for title, _, _ in first] == [title for title, _, _ in second]
    assert len(first) == 1 + 2 * 4 and first[0][0].startswith("log posterior")
    for (_, _, a), (_, _, b) in zip(first, second):
        np.testing.assert_array_equal(a, b)


def test_the_resolution_is_a_single_pixel_where_any_pixel_pays():
    """A synthetic resolution (the DiLiGenT ball's case: evidence so high that the disc is smaller than a pixel)
    reads as a single pixel, not 'about 0 pixels'; a larger one keeps its size; with an edge term the sentence
    says the figure counts its earning along the outline (rjfit.posterior.resolution)."""
    from rjfit.pipeline.regions.materials import MaterialFit, resolution_sentence

    tiny = {"contrast": 0.5, "material": 0, "pixels": 0.03, "radius_px": 0.1}
    sentence = resolution_sentence(tiny)
    assert "from a single pixel (the smallest possible)" in sentence and "about 0 pixels" not in sentence
    assert "edge term" not in sentence and "smaller ones" not in sentence      # nothing is smaller than a pixel
    larger = resolution_sentence({**tiny, "pixels": 151.2, "radius_px": 6.94})
    assert "about 151 pixels (a disc of radius 6.9 px)" in larger and "smaller ones are merged" in larger
    assert "counting the edge term's earning along its outline" in resolution_sentence(tiny, 0.8)
    summary = {"map_materials": 1, "materials_posterior": {"1": 1.0}, "map_probability_mean": 1.0,
               "material_resolution": tiny, "edge_power": 0.8}
    (printed,) = MaterialFit.printed_notes(summary)     # a line of its own, not at the end of the model's
    assert printed.startswith("resolution: a region of 0.5 times material 0's albedo gets a material of its own from "
                              "a single pixel") and "resolution" not in MaterialFit.printed_line(summary)
    assert MaterialFit.printed_notes({**summary, "material_resolution": None}) == []
    notes = MaterialFit.report_notes(summary)
    assert notes[0].startswith("Resolution: ") and "single pixel" in notes[0] and "edge term's earning" in notes[0]


def test_the_extra_materials_figure_shows_each_pixels_share_over_the_segmentations_outlines():
    """A 6 x 8 object of two materials (outline drawn) with a pixel held by extra materials in 30 % of the draws and
    one off the object: the image holds the shares as given (the pixel off the object masked), its colour scale
    runs from 0 to the largest share, and its axes and colour bar are labelled."""
    import matplotlib.pyplot as plt

    labels = np.zeros((6, 8), int)
    labels[:, 4:] = 1
    labels[0, 0] = -1
    share = np.zeros((6, 8))
    share[3, 2] = 0.3
    share[0, 0] = np.nan
    figure = figures.extra_materials_figure(share, labels)
    image_axis = figure.axes[0]
    (image,) = image_axis.get_images()
    shown = image.get_array()
    assert shown.mask[0, 0] and not shown.mask[3, 2] and shown[3, 2] == pytest.approx(0.3)
    assert image.get_clim() == pytest.approx((0.0, 0.3))
    assert (image_axis.get_xlabel(), image_axis.get_ylabel()) == ("column (px)", "row (px)")
    assert figure.axes[1].get_ylabel() == "share of the kept snapshots"
    assert image_axis.collections        # the segmentation's outline between its two materials
    plt.close(figure)
