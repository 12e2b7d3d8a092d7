"""``rjfit fit --regions fixed --labels FILE`` end to end: a Mitsuba-rendered stack, its true labels in, each
label's BRDF posterior out.

The paper's sphere at 24 x 24 (10 lights, noise variance 0.1; its four quadrants are four materials) is
rendered by Mitsuba (LLVM); its true label map, renumbered to 10, 20, 30, 40 and -1 off the object, is the
label file. Each label's posterior must hold its material's truth: the rendering follows the closed form to
float precision (tests/render/test_render.py), so the truth is the parameters the data were drawn from, and a
correct posterior puts it within 4 posterior sd of the mean (a miss at 4 sd has probability 6e-5 per
parameter; the 16 checks together fail by chance with probability below 1e-3). The negative control: the
label map with two quadrants swapped gives two labels posteriors whose kd lie that far from their labels'
(swapped) truths, so the check can fail.
"""
import json

import numpy as np
import pytest
from click.testing import CliRunner

from rjfit.cli import main
from rjfit.data.exr import read_exr, write_exr
from rjfit.pipeline.fit_folder import read_summary
from rjfit.pipeline.regions.fixed import read_label_map

VALUES = np.array([10, 20, 30, 40])     # the label file's values of true materials 0 .. 3
Z_MAX = 4.0
PARAMETERS = ("I0", "kd", "gamma", "sigma2")


@pytest.fixture(scope="module")
def sphere(tmp_path_factory):
    from rjfit.render.render import render_dataset

    folder = render_dataset("paper_sphere", tmp_path_factory.mktemp("sphere") / "dataset", resolution=24)
    truth = np.rint(read_exr(folder / "truth_labels.exr")["label"]).astype(int)
    materials = json.loads((folder / "dataset.json").read_text())["materials"]
    return folder, truth, materials


def _fit(folder, labels_file, out, *extra):
    return CliRunner().invoke(main, ["fit", str(folder), "--regions", "fixed", "--labels", str(labels_file),
                                     "--chains", "2", "--iterations", "300", "--seed", "0", "--allow-unvalidated",
                                     "--out", str(out), *extra])


def _z_scores(region, material):
    return {name: abs(region[name]["mean"] - material[name]) / region[name]["sd"] for name in PARAMETERS}


@pytest.fixture(scope="module")
def fitted(sphere, tmp_path_factory):
    folder, truth, _ = sphere
    labels_file = tmp_path_factory.mktemp("labels") / "labels.npy"
    np.save(labels_file, np.where(truth >= 0, VALUES[np.maximum(truth, 0)], -1))
    out = tmp_path_factory.mktemp("fit") / "out"
    result = _fit(folder, labels_file, out)
    assert result.exit_code == 0, result.output
    return out, read_summary(out), result.output


def test_each_labels_posterior_holds_its_materials_truth(sphere, fitted):
    _, truth, materials = sphere
    _, summary, _ = fitted
    assert summary["region_model"] == "fixed"
    assert [region["label"] for region in summary["regions"]] == list(VALUES)
    for region, material in zip(summary["regions"], materials):
        assert region["pixels"] == int(np.sum(truth == region["region"]))
        z = _z_scores(region, material)
        assert max(z.values()) < Z_MAX, (region["label"], z)


def test_nothing_but_the_brdfs_moved(fitted):
    """Only the within-region moves were proposed (those a change-point or material fit adds, such as cp_u,
    birth_u, label_gibbs or cluster, never)."""
    _, summary, _ = fitted
    assert set(summary["acceptance_counts"]) <= {"ab", "gamma_ab", "gamma_newton", "gamma_rw", "phi_rw", "sigma2"}
    assert summary["acceptance_counts"]["sigma2"]["proposed"] > 0


def test_the_fit_folder_holds_the_labels_chains_and_maps(sphere, fitted):
    import xarray as xr

    _, truth, _ = sphere
    out, _, output = fitted
    labels = np.rint(np.nan_to_num(read_exr(out / "labels.exr")["labels"], nan=-1)).astype(int)
    assert np.array_equal(labels, truth)
    posterior = xr.open_dataset(out / "chains.nc", group="posterior", engine="h5netcdf")
    assert posterior["theta"].shape == (2, 150, 4, 4)
    assert "residual_rms" in read_exr(out / "maps.exr")
    assert "4 labels held fixed (--labels)" in output


def test_the_report_names_the_labels_and_tests_no_segmentation(fitted):
    """The report of a fixed fit: the model in words, a row per label named by its value in the file, and no
    row of another model (change points' MAP model, materials' K)."""
    from rjfit.pipeline.report import build_report

    out, _, _ = fitted
    page = build_report(out).read_text(encoding="utf-8")
    assert "fixed: the label map" in page and "4 labels, one BRDF per label" in page
    assert "<th>label</th>" in page
    assert all(f"<tr><td>label {value}<br>" in page for value in VALUES)
    assert "labels (regions held fixed)</td><td>4</td>" in page
    for other in ("MAP model (n_u, n_v)", "MAP number of materials", "split map", "Potts prior"):
        assert other not in page, other


def test_swapped_labels_give_posteriors_far_from_the_swapped_truth(sphere, tmp_path):
    """Negative control: quadrants 1 (kd 0.9) and 3 (kd 0.4) swapped in the map; each label's kd is then its
    pixels' (the other material's), far outside Z_MAX sd of the truth the check compares it with."""
    folder, truth, materials = sphere
    swapped = np.array([0, 3, 2, 1])[np.maximum(truth, 0)]
    labels_file = tmp_path / "swapped.npy"
    np.save(labels_file, np.where(truth >= 0, swapped, -1))
    result = _fit(folder, labels_file, tmp_path / "out", "--iterations", "100")
    assert result.exit_code == 0, result.output
    regions = read_summary(tmp_path / "out")["regions"]
    assert _z_scores(regions[1], materials[1])["kd"] > Z_MAX and _z_scores(regions[3], materials[3])["kd"] > Z_MAX


def test_a_map_that_leaves_an_observed_pixel_unlabelled_is_refused_in_one_line(sphere, tmp_path):
    folder, truth, _ = sphere
    labels_file = tmp_path / "holes.npy"
    holed = truth.copy()
    row, col = np.argwhere(truth >= 0)[0]
    holed[row, col] = -1
    np.save(labels_file, holed)
    result = _fit(folder, labels_file, tmp_path / "out")
    assert result.exit_code == 1
    assert f"{labels_file}: 1 pixels with observations have no label" in result.output
    assert "Traceback" not in result.output


def test_labels_without_the_fixed_model_are_refused(sphere, tmp_path):
    folder, truth, _ = sphere
    np.save(tmp_path / "labels.npy", truth)
    result = CliRunner().invoke(main, ["fit", str(folder), "--labels", str(tmp_path / "labels.npy"),
                                       "--allow-unvalidated", "--out", str(tmp_path / "out")])
    # one line naming the flag and the model that reads it (rjfit.pipeline.resolve refuses an unread option)
    assert result.exit_code != 0 and "--labels is an option of --regions fixed, not of --regions changepoints" \
        in result.output and "Traceback" not in result.output


def test_label_maps_read_from_png_exr_and_npy_alike(tmp_path):
    import cv2

    labels = np.array([[0, 1, 1], [2, 2, 0]])
    cv2.imwrite(str(tmp_path / "labels.png"), labels.astype(np.uint16))
    write_exr(tmp_path / "labels.exr", {"labels": np.where(labels == 2, np.nan, labels).astype(np.float32)})
    np.save(tmp_path / "labels.npy", labels)
    assert np.array_equal(read_label_map(tmp_path / "labels.png"), labels)
    assert np.array_equal(read_label_map(tmp_path / "labels.exr"), np.where(labels == 2, -1, labels))
    assert np.array_equal(read_label_map(tmp_path / "labels.npy"), labels)
    np.save(tmp_path / "half.npy", labels + 0.5)
    with pytest.raises(ValueError, match="half.npy: the label map holds float64 values, not integers|not integers"):
        read_label_map(tmp_path / "half.npy")
    cv2.imwrite(str(tmp_path / "rgb.png"), np.zeros((2, 3, 3), np.uint8))
    with pytest.raises(ValueError, match=r"rgb.png: a label map is one channel of one image"):
        read_label_map(tmp_path / "rgb.png")
