"""The scatter moves' sequential allocations (:mod:`rjfit.sampler.regions.materials.passes.scatter`): proper
distributions over every allocation, and a drawn allocation's probability evaluated again when given.

On a 2 x 3 image (one pixel unlabelled) every allocation is enumerated: the birth's 2^5 (each labelled pixel joins
or keeps), the dissolve's 3^n over the other materials of the dying one's n pixels. Their probabilities must sum to
1 (1e-12: a sum of 32 or 81 float64 exponentials) whatever the powers, the Potts coupling and the log-likelihoods,
drawn with a fixed seed. The chain-level exactness of the move is tested against enumerated posteriors in
``test_exact_materials.py`` and ``test_edge_term.py``.
"""
import itertools

import numpy as np
import pytest

from rjfit.sampler.regions.materials.passes.scatter import allocate_birth, allocate_dissolve
from rjfit.sampler.regions.materials.scatter_move import birth_probability, dissolve_probability, dissolve_weights

HEIGHT, WIDTH = 2, 3
#: the state before a birth, numbered for the new material at slot 1 (no pixel of it); pixel 4 unlabelled
BEFORE_BIRTH = np.array([0, 0, 2, 3, -1, 2], np.int64)
#: the state before a dissolve of material 1 (pixels 1, 3, 5) among 4 materials
BEFORE_DISSOLVE = np.array([0, 1, 2, 1, 3, 1], np.int64)
NONE = np.empty(0)


@pytest.mark.parametrize("power,beta,seed", [(1.0, 1.0, 1), (0.05, 3.0, 2), (2.0, 0.0, 3)])
def test_birth_allocations_sum_to_one_and_draws_evaluate_again(power, beta, seed):
    rng = np.random.default_rng(seed)
    own, new = rng.normal(0, 3, HEIGHT * WIDTH), rng.normal(0, 3, HEIGHT * WIDTH)
    labelled = np.flatnonzero(BEFORE_BIRTH >= 0)
    total = 0.0
    for joins in itertools.product((0, 1), repeat=labelled.size):
        forced = np.zeros(HEIGHT * WIDTH, np.int64)
        forced[labelled] = joins
        labels = BEFORE_BIRTH.copy()
        total += np.exp(allocate_birth(labels, own, new, power, beta, HEIGHT, WIDTH, 1, NONE, forced))
        np.testing.assert_array_equal(labels == 1, forced == 1)
    assert total == pytest.approx(1.0, abs=1e-12)
    for _ in range(20):
        drawn = BEFORE_BIRTH.copy()
        log_p = allocate_birth(drawn, own, new, power, beta, HEIGHT, WIDTH, 1, rng.random(HEIGHT * WIDTH),
                               np.empty(0, np.int64))
        again = BEFORE_BIRTH.copy()
        assert allocate_birth(again, own, new, power, beta, HEIGHT, WIDTH, 1, NONE,
                              (drawn == 1).astype(np.int64)) == pytest.approx(log_p, abs=1e-12)
        np.testing.assert_array_equal(again, drawn)


@pytest.mark.parametrize("power,beta,seed", [(1.0, 1.0, 4), (0.05, 3.0, 5), (2.0, 0.0, 6)])
def test_dissolve_allocations_sum_to_one_and_draws_evaluate_again(power, beta, seed):
    rng = np.random.default_rng(seed)
    log_lik = rng.normal(0, 3, (4, HEIGHT * WIDTH))
    members = np.flatnonzero(BEFORE_DISSOLVE == 1)
    total = 0.0
    for targets in itertools.product((0, 2, 3), repeat=members.size):
        labels = BEFORE_DISSOLVE.copy()
        total += np.exp(allocate_dissolve(labels, members, 1, log_lik, power, beta, HEIGHT, WIDTH, NONE,
                                          np.array(targets, np.int64)))
        np.testing.assert_array_equal(labels[members], targets)
    assert total == pytest.approx(1.0, abs=1e-12)
    for _ in range(20):
        drawn = BEFORE_DISSOLVE.copy()
        log_p = allocate_dissolve(drawn, members, 1, log_lik, power, beta, HEIGHT, WIDTH, rng.random(members.size),
                                  np.empty(0, np.int64))
        assert not np.any(drawn == 1)
        again = BEFORE_DISSOLVE.copy()
        assert allocate_dissolve(again, members, 1, log_lik, power, beta, HEIGHT, WIDTH, NONE,
                                 drawn[members]) == pytest.approx(log_p, abs=1e-12)


def test_the_kinds_probabilities_and_dissolve_weights():
    assert [birth_probability(k, 8) for k in (1, 3, 8)] == [0.5, 0.5, 0.0]
    assert [dissolve_probability(k, 8) for k in (1, 3, 8)] == [0.0, 0.5, 1.0]
    assert birth_probability(1, 1) == dissolve_probability(1, 1) == 0.0
    np.testing.assert_allclose(dissolve_weights([100, 25, 1]), np.array([0.01, 0.04, 1.0]) / 1.05)
