"""Tests of rjfit.baselines: metrics on hand-made labels with known answers, each baseline on a
small rendered paper_sphere, and the ``rjfit compare`` command end to end."""
from __future__ import annotations

import json

import numpy as np
import pytest

from rjfit.baselines import metrics
from rjfit.baselines.methods import (
    gmm_position_segmentation,
    kmeans_segmentation,
    multichannel_kmeans,
    normalized_cuts,
    pick_ncut_image,
)

RESOLUTION = 48


# ---------------------------------------------------------------- metrics on hand-made labels

def two_regions(split_col, shape=(8, 12)):
    """Label 0 left of ``split_col``, 1 from it on."""
    labels = np.zeros(shape, dtype=int)
    labels[:, split_col:] = 1
    return labels


def quadrants(size=16):
    labels = np.zeros((size, size), dtype=int)
    half = size // 2
    labels[:half, half:] = 1
    labels[half:, :half] = 2
    labels[half:, half:] = 3
    return labels


def test_perfect_segmentation_scores_one():
    truth = quadrants()
    result = metrics.segmentation_metrics(truth, truth.copy())
    assert result["pixel_accuracy"] == 1.0
    assert result["ari"] == pytest.approx(1.0)
    assert result["boundary_f1"] == 1.0
    assert result["n_clusters"] == 4


def test_permuted_labels_score_one():
    truth = quadrants()
    permuted = np.array([7, 3, 0, 5])[truth]       # rename every region
    assert metrics.pixel_accuracy(truth, permuted) == 1.0
    assert metrics.adjusted_rand(truth, permuted) == pytest.approx(1.0)
    assert metrics.boundary_f1(truth, permuted)["f1"] == 1.0
    assert metrics.match_labels(truth, permuted) == {7: 0, 3: 1, 0: 2, 5: 3}


def test_extra_cluster_counts_as_error():
    truth = quadrants(16)                           # 64 pixels per region
    predicted = truth.copy()
    predicted[:2, :8] = 9                           # split 16 pixels of region 0 off into a 5th cluster
    # region 0 keeps its 48 pixels; the unmatched cluster's 16 are wrong
    assert metrics.pixel_accuracy(truth, predicted) == pytest.approx(1 - 16 / 256)
    # the larger part of a split region is the one matched
    predicted[:6, :8] = 9                           # now 48 of region 0 are in cluster 9, 16 in cluster 0
    assert metrics.match_labels(truth, predicted)[9] == 0
    assert metrics.pixel_accuracy(truth, predicted) == pytest.approx(1 - 16 / 256)


def test_unlabelled_pixels_inside_mask_are_errors_and_outside_ignored():
    truth = quadrants(16)
    mask = np.ones(truth.shape, dtype=bool)
    mask[0, :] = False                              # 16 pixels outside the comparison
    predicted = truth.copy()
    predicted[0, :] = 3                             # wrong, but outside the mask
    predicted[5, 0] = -1                            # unlabelled inside the mask
    assert metrics.pixel_accuracy(truth, predicted, mask) == pytest.approx(1 - 1 / 240)


def test_wrong_labelling_scores_low():
    truth = quadrants(16)
    stripes = np.tile(np.arange(16) % 4, (16, 1))   # vertical stripes, unrelated to the quadrants
    assert metrics.pixel_accuracy(truth, stripes) <= 0.5
    assert abs(metrics.adjusted_rand(truth, stripes)) < 0.2


def test_boundary_map_marks_both_sides_inside_mask_only():
    labels = np.array([[0, 0, 1, 1],
                       [0, 0, 1, 1],
                       [2, 2, 2, 2]])
    mask = np.ones(labels.shape, dtype=bool)
    mask[:, 3] = False                              # the right column is off the object
    expected = np.array([[0, 1, 1, 0],
                         [1, 1, 1, 0],
                         [1, 1, 1, 0]], dtype=bool)
    np.testing.assert_array_equal(metrics.boundary_map(labels, mask), expected)
    # the silhouette of the mask is no boundary
    assert not metrics.boundary_map(np.zeros((5, 5), int), np.eye(5, dtype=bool) | True).any()


@pytest.mark.parametrize("shift, expected_f1", [(0, 1.0), (1, 1.0), (2, 1.0), (3, 0.5), (4, 0.0)])
def test_boundary_f1_tolerance_is_two_pixels_inclusive(shift, expected_f1):
    # truth border between cols 5 | 6 -> boundary columns 5 and 6; the prediction's is shifted
    # right by `shift`: columns 5+s, 6+s. At s=3 the distances are 2 (ok) and 3 (too far) both ways.
    truth = two_regions(6)
    predicted = two_regions(6 + shift)
    result = metrics.boundary_f1(truth, predicted, tolerance=2)
    assert result["f1"] == pytest.approx(expected_f1)
    assert result["precision"] == pytest.approx(expected_f1)
    assert result["recall"] == pytest.approx(expected_f1)
    # pixel accuracy sees the shift: `shift` columns of 8 pixels out of 96 are wrong
    assert metrics.pixel_accuracy(truth, predicted) == pytest.approx(1 - 8 * shift / 96)


def test_boundary_f1_shifted_boundary_below_one_and_asymmetric_case():
    truth = two_regions(6)
    predicted = two_regions(9)                      # 3-pixel shift
    assert metrics.boundary_f1(truth, predicted)["f1"] < 1.0
    # an extra predicted border far away halves the precision, leaves the recall at 1
    predicted = two_regions(6)
    predicted[:, 11] = 2                            # new border between cols 10 | 11
    result = metrics.boundary_f1(truth, predicted)
    assert result["recall"] == 1.0
    assert result["precision"] == pytest.approx(0.5)
    assert result["f1"] == pytest.approx(2 * 0.5 / 1.5)
    # no predicted boundary at all against a truth with one: F1 = 0
    assert metrics.boundary_f1(truth, np.zeros_like(truth))["f1"] == 0.0


def test_metrics_reject_bad_input_with_a_hint():
    truth = quadrants(8)
    with pytest.raises(ValueError, match="same resolution"):
        metrics.pixel_accuracy(truth, np.zeros((4, 4), int))
    bad = truth.astype(float)
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="-1"):
        metrics.segmentation_metrics(truth, bad)
    with pytest.raises(ValueError, match="object_mask"):
        metrics.pixel_accuracy(truth, truth, mask=np.ones((8, 8)))


# ---------------------------------------------------------------- methods on a rendered sphere

@pytest.fixture(scope="module")
def sphere(paper_sphere_small):
    from rjfit.render.datasets import load_dataset

    dataset = load_dataset(paper_sphere_small)
    assert dataset.truth_labels is not None
    return dataset


def _check_object_labels(labels, mask, k):
    assert labels.shape == mask.shape
    assert np.issubdtype(labels.dtype, np.integer)
    assert (labels[~mask] == -1).all()
    np.testing.assert_array_equal(np.unique(labels[mask]), np.arange(k))


@pytest.mark.parametrize("k", [4, 8])
def test_kmeans_labels_object_with_k_clusters(sphere, k):
    labels = kmeans_segmentation(sphere.channel_values("mean"), sphere.object_mask, k, rng=0)
    _check_object_labels(labels, sphere.object_mask, k)


def test_kmeans_same_seed_same_labels(sphere):
    grey = sphere.channel_values("mean")
    first = kmeans_segmentation(grey, sphere.object_mask, 5, rng=np.random.default_rng(3))
    second = kmeans_segmentation(grey, sphere.object_mask, 5, rng=np.random.default_rng(3))
    np.testing.assert_array_equal(first, second)


@pytest.mark.parametrize("k", [4, 8])
def test_multichannel_kmeans_labels_object_with_k_clusters(sphere, k):
    labels = multichannel_kmeans(sphere.images, sphere.object_mask, k, rng=0)
    _check_object_labels(labels, sphere.object_mask, k)


@pytest.mark.parametrize("k", [4, 8])
def test_gmm_labels_object_with_k_components(sphere, k):
    labels = gmm_position_segmentation(sphere.channel_values("mean"), sphere.object_mask, k, rng=0)
    _check_object_labels(labels, sphere.object_mask, k)


@pytest.mark.parametrize("k", [5, 6])
def test_normalized_cuts_gives_k_segments_over_whole_image(sphere, k):
    index = pick_ncut_image(sphere.valid_mask("mean"))
    assert 0 <= index < sphere.n_lights
    labels = normalized_cuts(sphere.channel_values("mean")[index], k, rng=0)
    assert labels.shape == sphere.object_mask.shape
    np.testing.assert_array_equal(np.unique(labels), np.arange(k))
    # the background is (mostly) one segment of its own
    background = labels[~sphere.object_mask]
    dominant = np.bincount(background).argmax()
    assert np.mean(background == dominant) > 0.9


def test_methods_reject_bad_input_with_a_hint(sphere):
    grey = sphere.channel_values("mean")
    with pytest.raises(ValueError, match="object_mask"):
        kmeans_segmentation(grey, sphere.object_mask[:-1], 4)
    with pytest.raises(ValueError, match=r"\(L, H, W\)"):
        gmm_position_segmentation(grey[0], sphere.object_mask, 4)
    with pytest.raises(ValueError, match="k must be"):
        multichannel_kmeans(sphere.images, sphere.object_mask, 0)
    with pytest.raises(ValueError, match="one grey image"):
        normalized_cuts(grey, 5)


def test_pick_ncut_image_takes_most_valid():
    valid = np.zeros((3, 4, 4), dtype=bool)
    valid[1, :3] = True
    valid[2, :2] = True
    assert pick_ncut_image(valid) == 1


# ---------------------------------------------------------------- rjfit's MAP labels and the command

def _write_fit(folder, labels, off_value, summary, name="map_labels.exr"):
    from rjfit.data.exr import write_exr

    folder.mkdir(parents=True, exist_ok=True)
    raw = labels.astype(np.float32)
    raw[labels < 0] = off_value
    write_exr(folder / name, {"labels": raw})
    (folder / "summary.json").write_text(json.dumps(summary))
    return folder


@pytest.mark.parametrize("off_value, name", [(np.nan, "map_labels.exr"), (-1.0, "map_labels.exr"),
                                             (-1.0, "labels.exr")])
def test_read_map_labels_tolerates_nan_and_minus_one(sphere, tmp_path, off_value, name):
    from rjfit.pipeline.compare import read_map_labels

    fit = _write_fit(tmp_path / "fit", sphere.truth_labels, off_value, {"seconds": 3.0}, name)
    labels, summary = read_map_labels(fit, sphere.object_mask)
    np.testing.assert_array_equal(labels, np.where(sphere.object_mask, sphere.truth_labels, -1))
    assert summary == {"seconds": 3.0}


def test_compare_command_writes_its_three_outputs(sphere, tmp_path):
    from click.testing import CliRunner

    from rjfit.cli import main

    # a "fit" that recovered the truth exactly, with the regions renamed
    renamed = np.where(sphere.truth_labels >= 0, 3 - sphere.truth_labels, -1)
    fit = _write_fit(tmp_path / "fit", renamed, np.nan, {"seconds": 42.0, "dataset": str(sphere.path.resolve())})
    out = tmp_path / "cmp"
    result = CliRunner().invoke(main, ["compare", str(sphere.path), "--out", str(out), "--fit", str(fit),
                                       "--seed", "1"])
    assert result.exit_code == 0, result.output
    assert "rjfit_map" in result.output and "best k per method" in result.output
    payload = json.loads((out / "comparison.json").read_text())
    rows = payload["rows"]
    expected = ([("kmeans", k) for k in range(4, 9)] + [("kmeans_multichannel", k) for k in range(4, 9)]
                + [("gmm_position", k) for k in range(4, 9)] + [("normalized_cuts", k) for k in (5, 6)]
                + [("rjfit_map", 4)])
    assert [(row["method"], row["k"]) for row in rows] == expected
    for row in rows:
        for key in ("pixel_accuracy", "ari", "boundary_f1"):
            assert -1.0 <= row[key] <= 1.0
        assert row["seconds"] is not None and row["seconds"] >= 0
    rjfit_row = rows[-1]
    assert rjfit_row["pixel_accuracy"] == 1.0 and rjfit_row["boundary_f1"] == 1.0
    assert rjfit_row["seconds"] == 42.0
    # the baselines are not perfect on this sphere (shading, not material, drives their clusters)
    assert max(row["pixel_accuracy"] for row in rows[:-1]) < 1.0
    table = (out / "comparison.md").read_text()
    assert "| method | k | pixel accuracy |" in table and table.count("\n| ") >= len(rows) + 1
    assert (out / "segmentations.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(out.glob(".*tmp*")), "temporary files left behind"


def test_read_map_labels_missing_or_wrong_size(sphere, tmp_path):
    from rjfit.pipeline.compare import read_map_labels

    with pytest.raises(FileNotFoundError, match="no MAP segmentation"):
        read_map_labels(tmp_path, sphere.object_mask)
    fit = _write_fit(tmp_path / "fit", sphere.truth_labels[:-2], -1.0, {})
    with pytest.raises(ValueError, match="data set it was run on"):
        read_map_labels(fit, sphere.object_mask)


def test_compare_refuses_a_fit_of_another_data_set_before_any_baseline_runs(sphere, tmp_path, monkeypatch):
    from rjfit.pipeline import compare

    def fail(*args, **kwargs):
        raise AssertionError("a baseline ran before the fit was checked")

    monkeypatch.setattr(compare.methods, "kmeans_segmentation", fail)
    for summary, expected in (({"dataset": str(tmp_path / "other_dataset")}, "is a fit of .*other_dataset, not of"),
                              ({}, "unknown data set .no summary.json.")):
        fit = _write_fit(tmp_path / f"fit{len(summary)}", sphere.truth_labels, -1.0, summary)
        if not summary:
            (fit / "summary.json").unlink()
        with pytest.raises(ValueError, match=expected):
            compare.compare_dataset(sphere.path, tmp_path / "cmp", fit_dir=fit, seed=0)


def test_compare_without_fit_notes_missing_rjfit(sphere, tmp_path, monkeypatch):
    from rjfit.pipeline import compare

    monkeypatch.setattr(compare, "METHODS", {name: (label, list(ks)[:1])
                                             for name, (label, ks) in compare.METHODS.items()})
    rows = compare.compare_dataset(sphere.path, tmp_path / "cmp", seed=0)
    assert [(row["method"], row["k"]) for row in rows] == [("kmeans", 4), ("kmeans_multichannel", 4),
                                                           ("gmm_position", 4), ("normalized_cuts", 5)]
    assert "rjfit_map" not in {row["method"] for row in rows}
    notes = json.loads((tmp_path / "cmp" / "comparison.json").read_text())["notes"]
    assert any("no fit folder" in note for note in notes)


def test_baselines_separate_two_flat_materials_exactly():
    """Known answer: two halves of different albedo (grey 1.0 and 2.0 under every light) with
    noise sd 0.05 are 10 sd apart; k-means, multichannel k-means and the GMM with positions
    must recover the halves exactly (accuracy 1 after matching, boundary F1 1)."""
    from rjfit.baselines import methods
    from rjfit.baselines.metrics import segmentation_metrics

    rng = np.random.default_rng(7)
    truth = np.zeros((20, 24), int)
    truth[:, 12:] = 1
    mask = np.ones(truth.shape, bool)
    albedo = np.where(truth == 1, 2.0, 1.0)
    stack = albedo[None] * np.linspace(0.8, 1.2, 6)[:, None, None] + rng.normal(0.0, 0.05, (6, *truth.shape))
    images = np.repeat(stack[..., None], 3, axis=-1)
    for name, labels in (("kmeans", methods.kmeans_segmentation(stack, mask, 2, rng=1)),
                         ("kmeans_multichannel", methods.multichannel_kmeans(images, mask, 2, rng=1)),
                         ("gmm_position", methods.gmm_position_segmentation(stack, mask, 2, rng=1))):
        metrics = segmentation_metrics(truth, labels, mask)
        assert metrics["pixel_accuracy"] == 1.0 and metrics["boundary_f1"] == 1.0, (name, metrics)


def _few_methods(monkeypatch):
    from rjfit.pipeline import compare

    monkeypatch.setattr(compare, "METHODS", {name: (label, list(ks)[:1])
                                             for name, (label, ks) in compare.METHODS.items()})
    return compare


def test_an_interrupted_comparison_leaves_the_previous_one_whole(sphere, tmp_path, monkeypatch):
    """The three files are published together, comparison.json last: Ctrl-C while the figure is
    drawn (it used to come after the new json and Markdown) leaves the previous comparison."""
    compare = _few_methods(monkeypatch)
    out = tmp_path / "cmp"
    compare.compare_dataset(sphere.path, out, seed=0)
    before = {path.name: path.read_bytes() for path in out.iterdir()}
    assert sorted(before) == ["comparison.json", "comparison.md", "segmentations.png"]
    assert json.loads(before["comparison.json"])["figures"] == ["segmentations.png"]

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(compare, "_write_figure", interrupt)
    with pytest.raises(KeyboardInterrupt):
        compare.compare_dataset(sphere.path, out, seed=1)
    assert {path.name: path.read_bytes() for path in out.iterdir()} == before, "a staging or temporary file stayed"


def test_the_report_embeds_only_the_figures_a_comparison_names(sphere, tmp_path, monkeypatch):
    from rjfit.pipeline.report import build_report

    compare = _few_methods(monkeypatch)
    fit_dir = tmp_path / "fit"
    fit_dir.mkdir()
    (fit_dir / "summary.json").write_text("{}")
    compare.compare_dataset(sphere.path, fit_dir / "comparison", seed=0)
    (fit_dir / "comparison" / "old_run.png").write_bytes((fit_dir / "comparison" / "segmentations.png").read_bytes())
    html = build_report(fit_dir).read_text()
    assert "comparison: segmentations" in html and "old run" not in html
    assert html.count("data:image/png") == 1
