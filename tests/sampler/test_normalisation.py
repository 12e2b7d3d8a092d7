"""Giesen's normalisation is defined once (rjfit.model.blinn); the sampler's copies must agree with it.

The scalar copy (moves.region_terms.giesen_norm, Python floats for speed) and the compiled one
(passes.densities.coefficients, Numba: the model's function cannot be called there) write the
same formula, ``(g + 2)(g + 4) / (8 pi (2^(-g/2) + g))``, with ``2.0 ** x`` where the
definition has ``np.exp2(x)``. The three are different code paths: ``np.exp2`` is dispatched
to the CPU's SIMD kernel (AVX-512, AVX2 or the baseline), ``2.0 ** x`` to the C library's
``pow`` or LLVM's. So they are compared within a bound derived from the arithmetic, not bit
for bit (on an AVX-512 machine 52 of these 8,008 values differ by one unit in the last place).

The bound. Let ``eps = 2^-52`` (``u = eps / 2``, the unit roundoff). NumPy's float64 ``exp2``
is within 1 ulp of 2^x (its accuracy test, ``umath-validation-set-exp2.csv``, allows 1 ulp)
and ``pow`` within 1 ulp too, so the two values ``t1``, ``t2`` of ``2^(-g/2)`` differ by at
most 2 ulp, i.e. ``|t1 - t2| <= 2 eps t``. Everything else is the same operations on the same
operands (``-g/2``, the numerator, ``8 pi``), each result rounded once (relative error <= u):

- ``t + g`` with ``g >= 0``: the difference ``|t1 - t2| <= 2 eps t <= 2 eps (t + g)``, and each
  sum is rounded: relative difference <= 2 eps + 2u;
- the product by ``8 pi`` and the division: each rounded once in each copy, + 2u + 2u.

In all ``2 eps + 6u = 5 eps`` (about 1.1e-15) relative, to first order; the tests allow
``5 eps``. A change to a formula (another constant, order or term) moves the values by far more.
"""
import numpy as np

from rjfit.model.blinn import blinn_normalisation
from rjfit.sampler.moves.region_terms import giesen_norm
from rjfit.sampler.passes.densities import coefficients

GAMMAS = np.concatenate([np.geomspace(1e-3, 1e4, 4001), np.random.default_rng(3).uniform(0.0, 300.0, 4000),
                         [0.0, 0.5, 1.0, 2.0, 10.0, 100.0, 700.0]])
# the bound derived in the module docstring: two exp2 values 2 ulp apart, then three roundings in each copy
RTOL = 5 * np.finfo(float).eps


def test_scalar_copy_equals_the_definition_within_rounding():
    scalar = np.array([giesen_norm(float(g)) for g in GAMMAS])
    np.testing.assert_allclose(scalar, blinn_normalisation(GAMMAS), rtol=RTOL, atol=0)


def test_compiled_copy_equals_the_definition_within_rounding():
    theta = np.column_stack([np.full(GAMMAS.size, 1.0), np.zeros(GAMMAS.size), GAMMAS, np.ones(GAMMAS.size)])
    # column 1 is I0 (1 - kd) N(g): with I0 = 1, kd = 0 it is N(g) itself (products by 1 are exact)
    np.testing.assert_allclose(coefficients(theta)[:, 1], blinn_normalisation(GAMMAS), rtol=RTOL, atol=0)


def test_a_changed_formula_is_far_outside_the_bound():
    """The tolerance is tight enough to catch a real change: ``8 pi`` replaced by ``8 * 3.14159265``
    (a relative change of 1.1e-9) or the exponent's 2 by 2.0000001."""
    changed = (GAMMAS + 2.0) * (GAMMAS + 4.0) / (8.0 * 3.14159265 * (np.exp2(-GAMMAS / 2.0) + GAMMAS))
    assert not np.allclose(changed, blinn_normalisation(GAMMAS), rtol=RTOL, atol=0)
    changed = (GAMMAS + 2.0) * (GAMMAS + 4.0) / (8.0 * np.pi * (np.exp2(-GAMMAS / 2.0000001) + GAMMAS))
    assert not np.allclose(changed, blinn_normalisation(GAMMAS), rtol=RTOL, atol=0)
