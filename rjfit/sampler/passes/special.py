"""Special functions for the compiled passes: a vectorising ``exp``, the normal CDF and quantile, log-sum-exp.

:func:`fast_exp` is why the passes vectorise (libm's scalar ``exp`` costs about 5 ns in a
compiled loop; this is plain arithmetic, about 0.5 ns); :func:`ndtr` and :func:`ndtri` are
:func:`scipy.special.ndtr` and :func:`~scipy.special.ndtri` callable from Numba (the
truncated-normal steps of the vector redraw). ``tests/sampler/test_passes.py`` checks each
against NumPy or SciPy.
"""
from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

__all__ = ["LOG_2PI", "INV_PI", "fast_exp", "log_normal", "logaddexp", "log_sum_exp", "ndtr", "ndtri",
           "truncated_mass"]

# Acklam's rational approximation of the normal quantile (relative error < 1.2e-9), refined
# in :func:`ndtri` by one Halley step on ndtr to full double precision.
_Q_A = (-3.969683028665376e+01, 2.209460984245205e+02, -2.759285104469687e+02, 1.383577518672690e+02,
        -3.066479806614716e+01, 2.506628277459239e+00)
_Q_B = (-5.447609879822406e+01, 1.615858368580409e+02, -1.556989798598866e+02, 6.680131188771972e+01,
        -1.328068155288572e+01)
_Q_C = (-7.784894002430293e-03, -3.223964580411365e-01, -2.400758277161838e+00, -2.549732539343734e+00,
        4.374664141464968e+00, 2.938163982698783e+00)
_Q_D = (7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e+00, 3.754408661907416e+00)
_SQRT_HALF = math.sqrt(0.5)
_SQRT_2PI = math.sqrt(2.0 * math.pi)


LOG_2PI = math.log(2.0 * math.pi)


INV_PI = 1.0 / math.pi


@intrinsic
def _float64_from_bits(typingctx, bits):
    """The float64 whose IEEE bits are the int64 ``bits`` (an LLVM bitcast, no memory round trip)."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())
    return types.float64(types.int64), codegen


_LOG2_E = 1.4426950408889634


_LN2_HI = 6.93147180369123816490e-01     # ln 2 split so that k * _LN2_HI is exact (Cody-Waite)


_LN2_LO = 1.90821492927058770002e-10


@njit(inline="always", fastmath={"contract"})
def fast_exp(x):
    """``e^x`` within 1 ulp of NumPy's (0 below ``e^-708``, where NumPy's is subnormal or 0).

    Why not ``math.exp``: a compiled loop calls libm's scalar ``exp`` (about 5 ns), while this
    is plain arithmetic that the compiler vectorises with the loop around it (about 0.5 ns):
    ``x = k ln 2 + r`` with |r| <= ln 2 / 2, ``e^r`` by its Taylor polynomial of degree 13
    (truncation error below 1e-17), ``2^k`` written into the exponent bits. Measured against
    ``np.exp`` on 300,000 arguments in [-750, 0]: at most 1 ulp apart, 92 % equal.
    """
    clamped = min(max(x, -708.0), 709.0)
    k = np.floor(clamped * _LOG2_E + 0.5)
    r = (clamped - k * _LN2_HI) - k * _LN2_LO
    p = 1.0 / 6227020800.0
    p = p * r + 1.0 / 479001600.0
    p = p * r + 1.0 / 39916800.0
    p = p * r + 1.0 / 3628800.0
    p = p * r + 1.0 / 362880.0
    p = p * r + 1.0 / 40320.0
    p = p * r + 1.0 / 5040.0
    p = p * r + 1.0 / 720.0
    p = p * r + 1.0 / 120.0
    p = p * r + 1.0 / 24.0
    p = p * r + 1.0 / 6.0
    p = p * r + 0.5
    p = p * r + 1.0
    p = p * r + 1.0
    value = p * _float64_from_bits((np.int64(k) + 1023) << 52)
    return value if x >= -708.0 else 0.0


@njit(cache=True, nogil=True)
def log_normal(x, mean, sd):
    d = (x - mean) / sd
    return -0.5 * d * d - math.log(sd) - 0.5 * LOG_2PI


@njit(cache=True, nogil=True)
def logaddexp(a, b):
    if a == -np.inf:
        return b
    if b == -np.inf:
        return a
    top = max(a, b)
    return top + math.log(math.exp(a - top) + math.exp(b - top))


@njit(cache=True, nogil=True)
def log_sum_exp(values):
    top = -np.inf
    for v in values:
        if v > top:
            top = v
    if not np.isfinite(top):
        return top
    total = 0.0
    for v in values:
        total += math.exp(v - top)
    return top + math.log(total)


@njit(cache=True, nogil=True)
def ndtr(x):
    """Standard normal CDF (as :func:`scipy.special.ndtr`)."""
    return 0.5 * math.erfc(-x * _SQRT_HALF)


@njit(cache=True, nogil=True)
def _ndtri_lower(p):
    q = math.sqrt(-2.0 * math.log(p))
    c, d = _Q_C, _Q_D
    return ((((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5])
            / ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0))


@njit(cache=True, nogil=True)
def ndtri(p):
    """Standard normal quantile (as :func:`scipy.special.ndtri`): -inf at 0, inf at 1."""
    if p <= 0.0:
        return -np.inf
    if p >= 1.0:
        return np.inf
    if p < 0.02425:
        x = _ndtri_lower(p)
    elif p > 1.0 - 0.02425:
        x = -_ndtri_lower(1.0 - p)
    else:
        q = p - 0.5
        r = q * q
        a, b = _Q_A, _Q_B
        x = ((((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q
             / (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1.0))
    # one Halley step on ndtr(x) = p; in the upper half through the complement, so that
    # the step sees 1 - p's own rounding and not that of ndtr near 1
    if x > 0.0:
        e = 0.5 * math.erfc(x * _SQRT_HALF) - (1.0 - p)
        u = -e * _SQRT_2PI * math.exp(0.5 * x * x)
    else:
        e = ndtr(x) - p
        u = e * _SQRT_2PI * math.exp(0.5 * x * x)
    if math.isfinite(u):
        x = x - u / (1.0 + 0.5 * x * u)
    return x


@njit(cache=True, nogil=True)
def truncated_mass(a, b):
    # P(a < Z < b); both ends in the upper tail: the mirrored lower tail keeps its digits
    if a > 0.0:
        return ndtr(-a) - ndtr(-b)
    return ndtr(b) - ndtr(a)
