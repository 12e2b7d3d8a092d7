"""A recorded calibration replays to the data the fit saw (about 10 s: one calibration of a 48 x 48 render)."""
import dataclasses
import json

import numpy as np
import pytest

from rjfit.data.calibrate import calibrate_measured, replay_calibration
from rjfit.render.datasets import load_dataset

from builders import data_diagnose_sees


def test_a_recorded_calibration_replays_to_the_data_the_fit_saw(paper_sphere_small):
    """``rjfit diagnose`` on a ``--preset measured`` fit replays the fit's calibration record:
    the same pixels, response exponent and gains give the same images, bit for bit, as the
    estimation did; a record that does not fit the data set is refused with one line."""
    dataset = load_dataset(paper_sphere_small)
    gains = np.geomspace(0.85, 1.15, dataset.n_lights)[np.random.default_rng(1).permutation(dataset.n_lights)]
    linear = dataset.images * gains[:, None, None, None]
    mask = dataset.object_mask.copy()
    mask[0, 0] = True                          # a lone pixel the calibration leaves out
    raw = dataclasses.replace(dataset, images=np.clip(linear / linear.max(), 0.0, None) ** (1 / 1.3), response="unknown",
                              object_mask=mask, quantisation_variance=None)
    calibrated, record = calibrate_measured(raw)
    record = json.loads(json.dumps(record))          # as read back from summary.json
    replayed = replay_calibration(raw, record)
    np.testing.assert_array_equal(replayed.images, calibrated.images)
    np.testing.assert_array_equal(replayed.object_mask, calibrated.object_mask)
    np.testing.assert_array_equal(replayed.visibility, calibrated.visibility)      # the cast shadows left out
    assert replayed.response == "linear" and record["isolated_pixels"]["pixels_dropped"] == 1
    assert record["response"] is not None and record["light_gains"] is not None
    wrong = json.loads(json.dumps(record))
    wrong["light_gains"]["gains"] = wrong["light_gains"]["gains"][:-1]
    with pytest.raises(ValueError, match=r"fit/summary.json: .*gains for \d+ lights"):
        replay_calibration(raw, wrong, source="fit/summary.json")
    with pytest.raises(ValueError, match="declares its response"):
        replay_calibration(dataclasses.replace(raw, response="linear"), record)


def test_diagnose_of_a_calibrated_fit_sees_the_calibrated_data(paper_sphere_small, tmp_path, monkeypatch):
    """The wiring: ``diagnose_fit`` hands the workflow the replayed data set, not the raw one
    (before, a ``--preset measured`` fit of a psm stack was criticised on its raw codes)."""
    dataset = load_dataset(paper_sphere_small)
    gains = np.linspace(0.9, 1.1, dataset.n_lights)
    raw = dataclasses.replace(dataset, images=dataset.images * gains[:, None, None, None])
    record = {"isolated_pixels": {"min_component": 5, "components_dropped": 0, "pixels_dropped": 0},
              "response": None, "light_gains": {"gains": gains.tolist()}}
    seen = data_diagnose_sees(raw, {"calibration": record}, tmp_path, monkeypatch)
    np.testing.assert_allclose(seen.images, dataset.images, rtol=1e-12, atol=1e-12)


def test_a_colour_fits_response_and_gains_are_the_channel_means(paper_sphere_small):
    """A joint colour fit (channel 'rgb') estimates the camera response and the light gains on the channel mean,
    one per camera and per light for every channel: the same kappa and gains as a mean-channel calibration, bit
    for bit (the same computation), and the record says so; the cast shadows stay flagged on the fit's channel."""
    dataset = load_dataset(paper_sphere_small)
    gains = np.geomspace(0.9, 1.1, dataset.n_lights)
    linear = dataset.images * gains[:, None, None, None]
    raw = dataclasses.replace(dataset, images=np.clip(linear / linear.max(), 0.0, None) ** (1 / 1.3), response="unknown",
                              quantisation_variance=None)
    _, mean_record = calibrate_measured(raw, "mean")
    _, colour_record = calibrate_measured(raw, "rgb")
    assert colour_record["response"]["kappa"] == mean_record["response"]["kappa"]
    assert colour_record["response"]["channel"] == "mean"
    np.testing.assert_array_equal(colour_record["light_gains"]["gains"], mean_record["light_gains"]["gains"])
    assert colour_record["cast_shadows"]["channel"] == "rgb"
