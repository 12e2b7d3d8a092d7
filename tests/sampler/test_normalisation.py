"""Giesen's normalisation is defined once (rjfit.model.blinn); the sampler's copies must agree with it.

The scalar copy (moves.region_terms.giesen_norm, Python floats for speed) and the compiled one
(passes.densities.coefficients, Numba: the model's function cannot be called there) write the
same formula with ``2.0 ** x`` where the definition has ``np.exp2(x)``. Both are checked bit
for bit against the definition over the exponents a fit meets and beyond; a change to either
formula that changes a result fails here.
"""
import numpy as np

from rjfit.model.blinn import blinn_normalisation
from rjfit.sampler.moves.region_terms import giesen_norm
from rjfit.sampler.passes.densities import coefficients

GAMMAS = np.concatenate([np.geomspace(1e-3, 1e4, 4001), np.random.default_rng(3).uniform(0.0, 300.0, 4000),
                         [0.0, 0.5, 1.0, 2.0, 10.0, 100.0, 700.0]])


def test_scalar_copy_equals_the_definition_bit_for_bit():
    scalar = np.array([giesen_norm(float(g)) for g in GAMMAS])
    np.testing.assert_array_equal(scalar, blinn_normalisation(GAMMAS))


def test_compiled_copy_equals_the_definition_bit_for_bit():
    theta = np.column_stack([np.full(GAMMAS.size, 1.0), np.zeros(GAMMAS.size), GAMMAS, np.ones(GAMMAS.size)])
    # column 1 is I0 (1 - kd) N(g): with I0 = 1, kd = 0 it is N(g) itself (products by 1 are exact)
    np.testing.assert_array_equal(coefficients(theta)[:, 1], blinn_normalisation(GAMMAS))
