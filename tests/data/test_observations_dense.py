"""Observations.dense: per-observation values back into images (what the noise and power estimates read)."""
import numpy as np

from rjfit.data.observations import observations_from_stack


def test_dense_puts_every_value_back_where_it_was_observed():
    rng = np.random.default_rng(0)
    images = rng.normal(size=(3, 4, 5))
    valid = rng.random((3, 4, 5)) > 0.3
    ones = np.ones_like(images)
    obs = observations_from_stack(images, ones, ones, ones, valid, np.ones((4, 5), bool))
    np.testing.assert_array_equal(obs.dense(), np.where(valid, images, np.nan))
    np.testing.assert_array_equal(obs.dense(2.0 * obs.y), np.where(valid, 2.0 * images, np.nan))
