"""A stated dark threshold keeps observations that measured no reflected light out of the fit.

A photometric-stereo folder has no shadow rays: a cast shadow, the background inside a loose
mask or the sensor's floor reach the loader as small values that the model would read as a
dark material. ``dark`` (raw code values, in ``rjfit.json``; in the data's units in
``dataset.json`` and ``stack.json``) flags every observation whose every channel is at or
below it (``Dataset.too_dark``), and the valid-observation mask, the observations and hence
the fit, the comparison and the diagnosis leave them out.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from rjfit.data.diligent import crop_to_mask
from rjfit.errors import DatasetError
from rjfit.render.datasets import load_dataset

from builders import (
    INTENSITIES,
    edit_description,
    make_ps_folder,
    make_rjfit_folder,
    raises,
    shading,
    sphere_geometry,
    write_png,
)


def dark_folder(folder):
    """make_ps_folder's folder with ``dark`` 350 declared and two lit object pixels of light 2
    changed: (4, 6) dark in every channel (a cast shadow), (4, 5) dark in two channels only (a
    saturated colour: still a measurement). Returns the folder and its raw images."""
    folder = make_ps_folder(folder)
    mask, normals = sphere_geometry()
    raw = shading(mask, normals)
    raw[0, 3, 4] = 65535                  # as make_ps_folder writes it
    raw[1, 4, 6] = (100, 120, 90)
    raw[1, 4, 5] = (100, 5000, 100)
    write_png(folder / "002.png", raw[1])
    (folder / "rjfit.json").write_text(json.dumps({"dark": 350}))
    return folder, raw


def test_dark_observations_of_a_photometric_folder_are_left_out(tmp_path):
    plain = load_dataset(make_ps_folder(tmp_path / "plain"))
    assert plain.too_dark is None and plain.meta["dark"]["raw_threshold"] is None
    folder, raw = dark_folder(tmp_path / "ps")
    dataset = load_dataset(folder)
    expected = (raw <= 350).all(axis=-1)
    assert expected[1, 4, 6] and not expected[1, 4, 5] and plain.valid_mask()[1, 4, 6]
    np.testing.assert_array_equal(dataset.too_dark, expected)
    assert dataset.meta["dark"] == {**dataset.meta["dark"], "raw_threshold": 350,
                                    "dark_observations_in_mask": int(expected[:, dataset.object_mask].sum())}
    np.testing.assert_array_equal(dataset.valid_mask(), plain.valid_mask() & ~expected)
    assert dataset.observations().n_obs == int((plain.valid_mask() & ~expected).sum()) < plain.observations().n_obs
    # the threshold is on raw codes, before the per-light intensities are divided out
    assert (dataset.images[dataset.too_dark] * INTENSITIES[np.nonzero(dataset.too_dark)[0]] <= 350 + 1e-3).all()
    # a crop keeps the flags with their pixels
    cropped = crop_to_mask(dataset, margin=0)
    r0, c0 = cropped.meta["crop"]["row0"], cropped.meta["crop"]["col0"]
    height, width = cropped.object_mask.shape
    np.testing.assert_array_equal(cropped.too_dark, dataset.too_dark[:, r0:r0 + height, c0:c0 + width])


@pytest.mark.parametrize("value, allowed", [(-1, "a raw value >= 0, or null"), ("low", "a raw value >= 0, or null"),
                                            (True, "a raw value >= 0, or null")])
def test_bad_dark_threshold_names_the_file(tmp_path, value, allowed):
    folder = make_ps_folder(tmp_path / "ps")
    (folder / "rjfit.json").write_text(json.dumps({"dark": value}))
    with raises(DatasetError, folder / "rjfit.json", f"dark is {value!r}; it must be {allowed}"):
        load_dataset(folder)


def test_dark_threshold_in_the_rjfit_layout(tmp_path):
    """make_rjfit_folder's images are 0.5 everywhere: a threshold of 0.5 flags them all, 0.4 none."""
    folder = make_rjfit_folder(tmp_path / "rjfit")
    edit_description(folder, lambda meta: meta.update(dark=0.4))
    assert not load_dataset(folder).too_dark.any()
    edit_description(folder, lambda meta: meta.update(dark=0.5))
    dataset = load_dataset(folder)
    assert dataset.too_dark.all() and not dataset.valid_mask().any()
    edit_description(folder, lambda meta: meta.update(dark=-0.1))
    with raises(DatasetError, folder / "dataset.json", "dark is -0.1; it must be a value >= 0"):
        load_dataset(folder)


def test_exclusion_counts_give_each_left_out_observation_one_reason(tmp_path):
    """On the object, valid + every rule's count = the number of lights, pixel by pixel; each
    count is the rule's own flags less the observations an earlier rule already took; the
    valid count is the valid-observation mask's."""
    dataset = load_dataset(dark_folder(tmp_path / "ps")[0])
    counts = dataset.exclusion_counts()
    mask = dataset.object_mask
    total = sum(counts.values())
    assert (total[mask] == dataset.n_lights).all() and not total[~mask].any()
    np.testing.assert_array_equal(counts["valid"], dataset.valid_mask().sum(axis=0))
    assert counts["saturated"][3, 4] == 1 and counts["saturated"].sum() == 1
    cos_ln = dataset.geometry()[0]
    unlit = (cos_ln <= 1e-3) & mask
    np.testing.assert_array_equal(counts["unlit"], unlit.sum(axis=0))
    np.testing.assert_array_equal(counts["too_dark"],
                                  (dataset.too_dark & ~unlit & ~dataset.saturated & mask).sum(axis=0))
    assert counts["too_dark"][4, 6] == 1 and counts["too_dark"].sum() == 1
