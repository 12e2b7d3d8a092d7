"""The rim rule (``--max-view-angle``, set by ``--preset measured``): pixels seen at a grazing angle give no observation.

On measured data the rim carries most of what the model cannot follow: a measured normal's
error and a pixel's footprint change the radiance fastest there, and pixels partly background
darken it (docs/results/measured-data.md). The rule leaves out every observation of a pixel whose
``<v.n>`` is below the bound; the pixel stays in the object mask, so a material fit labels it
by its neighbours. The fit records the bound and ``rjfit diagnose`` leaves the same
observations out. About 1 s.
"""
import dataclasses

import numpy as np
import pytest

from rjfit.data.observations import RIM_COS
from rjfit.pipeline.options import RIM_VIEW_ANGLE, FitOptions
from rjfit.pipeline.resolve import resolve_options
from rjfit.render.datasets import load_dataset

from builders import data_diagnose_sees, make_ps_folder


def _with_a_rim(dataset):
    """The data set with its sphere's normals tilted further out, so that its edge is seen at grazing angles."""
    normals = dataset.normals.copy()
    normals[..., :2] *= 1.15
    normals[..., 2] = np.sqrt(np.clip(1.0 - normals[..., 0] ** 2 - normals[..., 1] ** 2, 0.0, None))
    normals[~dataset.object_mask] = 0.0
    return dataclasses.replace(dataset, normals=normals)


def test_the_rim_rule_leaves_out_every_observation_of_a_pixel_seen_at_a_grazing_angle(tmp_path):
    dataset = _with_a_rim(load_dataset(make_ps_folder(tmp_path / "ps")))
    cos_view = np.sum(dataset.normals * dataset.view_dirs, axis=-1)
    rim = dataset.object_mask & (cos_view < RIM_COS)
    assert 0 < rim.sum() < dataset.object_mask.sum()        # the test needs both kinds of pixel
    limited = dataclasses.replace(dataset, max_view_angle=RIM_VIEW_ANGLE)
    np.testing.assert_array_equal(limited.rim_pixels(), rim)
    assert not dataset.rim_pixels().any()                    # no bound: no rim
    plain_valid, valid = dataset.valid_mask(), limited.valid_mask()
    assert not valid[:, rim].any()
    np.testing.assert_array_equal(valid[:, ~rim], plain_valid[:, ~rim])
    counts = limited.exclusion_counts()
    # each left-out observation has one reason, the first that applies: the light's own (unlit) before the view's
    unlit = dataset.exclusion_counts()["unlit"]
    np.testing.assert_array_equal(counts["grazing_view"], np.where(rim, dataset.n_lights - unlit, 0))
    np.testing.assert_array_equal(counts["valid"], valid.sum(axis=0))
    pixels = limited.observations().pixel
    assert not np.isin(pixels, np.flatnonzero(rim.ravel())).any()
    assert abs(np.cos(np.radians(RIM_VIEW_ANGLE)) - RIM_COS) < 1e-4      # the preset's degrees are the rim's bound


def test_the_preset_sets_the_rim_rule_and_diagnose_replays_it(tmp_path, monkeypatch):
    """The preset's bound is the rim's (72.5 degrees); none (the default) or 90 keeps every view; ``diagnose_fit``
    hands the workflow the data set with the bound its fit recorded."""
    assert resolve_options(FitOptions(preset="measured")).max_view_angle == RIM_VIEW_ANGLE
    assert resolve_options(FitOptions()).max_view_angle is None                    # every view kept
    assert resolve_options(FitOptions(preset="measured", max_view_angle=80.0)).max_view_angle == 80.0   # given: kept
    # 90 keeps every view under the preset too: a value equal to a default must not be taken for "not given"
    assert resolve_options(FitOptions(preset="measured", max_view_angle=90.0)).max_view_angle == 90.0
    with pytest.raises(ValueError, match="--max-view-angle"):
        FitOptions(max_view_angle=95.0)
    dataset = _with_a_rim(load_dataset(make_ps_folder(tmp_path / "ps")))
    seen = data_diagnose_sees(dataset, {"max_view_angle": RIM_VIEW_ANGLE}, tmp_path, monkeypatch)
    assert seen.max_view_angle == RIM_VIEW_ANGLE
