"""Priors Gaussian in an unconstrained coordinate: stated on the constrained value, with the
bijection to the unconstrained coordinate and its log-Jacobian.

This is THE place for priors of that family (log-normal for positive values, logit-normal for
values in an interval, normal for real values). The criticism refits
(:mod:`rjfit.diagnose`) state every parameter's prior with it: their Laplace evidence needs a
prior that is Gaussian in the coordinate the MAP and the Hessian are taken in. The fit's
region priors (:mod:`rjfit.sampler.priors`, ``ParamPrior`` kinds lognormal / uniform / beta /
invgamma) are another family, for the reasons listed in
:func:`rjfit.diagnose.region_priors.region_priors` and ``docs/results/criticism.md``.

Every prior here is Gaussian in its unconstrained coordinate ``z``. So the density of ``z`` is

    log p_z(z) = log p_theta(theta(z)) + log |d theta / d z|    (= a normal log-density in z),

which is what a refit's posterior and its Laplace evidence use: the MAP and the Hessian are
taken in ``z``, where the posterior is closest to Gaussian, and the Jacobian term makes the
evidence the same number it would be in the constrained coordinates (evidence does not depend
on the parametrisation). ``tests/diagnose/test_diagnose_units.py`` checks the identity above.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Prior", "LogNormal", "LogitNormal", "Normal"]

_LOG_2PI = math.log(2.0 * math.pi)


@dataclass(frozen=True)
class Prior:
    """A prior on one scalar parameter, Gaussian N(loc, scale^2) in the unconstrained coordinate."""

    loc: float
    scale: float

    # -- the bijection ---------------------------------------------------------------------
    def to_constrained(self, z):
        raise NotImplementedError

    def to_unconstrained(self, theta):
        raise NotImplementedError

    def log_abs_det_jacobian(self, z):
        """``log |d theta / d z|`` at ``z``."""
        raise NotImplementedError

    def log_prob(self, theta):
        """Log density of the constrained value ``theta`` (per unit of theta)."""
        z = self.to_unconstrained(theta)
        return self.log_prob_unconstrained(z) - self.log_abs_det_jacobian(z)

    def log_prob_unconstrained(self, z):
        """Log density of ``z``: ``log_prob(theta(z)) + log|d theta/d z|``, a normal density."""
        z = np.asarray(z, dtype=float)
        return -0.5 * ((z - self.loc) / self.scale) ** 2 - math.log(self.scale) - 0.5 * _LOG_2PI

    def describe(self) -> str:
        return f"{type(self).__name__}(loc={self.loc:.4g}, scale={self.scale:.4g}) on the unconstrained value"


@dataclass(frozen=True)
class LogNormal(Prior):
    """theta > 0, log theta ~ N(loc, scale^2)."""

    def to_constrained(self, z):
        return np.exp(z)

    def to_unconstrained(self, theta):
        return np.log(theta)

    def log_abs_det_jacobian(self, z):
        return np.asarray(z, dtype=float)


@dataclass(frozen=True)
class LogitNormal(Prior):
    """theta in (low, high) (default (0, 1)), logit((theta - low) / (high - low)) ~ N(loc, scale^2)."""

    low: float = 0.0
    high: float = 1.0

    def to_constrained(self, z):
        return self.low + (self.high - self.low) / (1.0 + np.exp(-np.asarray(z, dtype=float)))

    def to_unconstrained(self, theta):
        unit = (np.asarray(theta, dtype=float) - self.low) / (self.high - self.low)
        return np.log(unit) - np.log1p(-unit)

    def log_abs_det_jacobian(self, z):
        z = np.asarray(z, dtype=float)
        return math.log(self.high - self.low) - np.logaddexp(0.0, z) - np.logaddexp(0.0, -z)

    @classmethod
    def centred_on(cls, value: float, scale: float, low: float = 0.0, high: float = 1.0) -> "LogitNormal":
        """The prior on (low, high) whose unconstrained centre is ``value``'s: ``loc = logit((value - low) / (high -
        low))``."""
        centre = (value - low) / (high - low)
        return cls(loc=float(math.log(centre / (1.0 - centre))), scale=scale, low=low, high=high)

    def describe(self) -> str:
        bounds = "" if (self.low, self.high) == (0.0, 1.0) else f" on ({self.low:g}, {self.high:g})"
        return f"LogitNormal(loc={self.loc:.4g}, scale={self.scale:.4g}){bounds} on the unconstrained value"


@dataclass(frozen=True)
class Normal(Prior):
    """theta real, theta ~ N(loc, scale^2) (identity transform)."""

    def to_constrained(self, z):
        return np.asarray(z, dtype=float)

    def to_unconstrained(self, theta):
        return np.asarray(theta, dtype=float)

    def log_abs_det_jacobian(self, z):
        return np.zeros_like(np.asarray(z, dtype=float))
