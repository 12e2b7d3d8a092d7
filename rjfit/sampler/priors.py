"""Priors of the region parameters (I0, kd, gamma, sigma^2) and their presets.

Parameter order everywhere in the sampler: ``(I0, kd, gamma, sigma2)``.

The sampler works in the unconstrained coordinates
``phi = (log I0, logit kd, log gamma, log sigma2)`` for split/merge and the fallback random
walk; the density of ``phi`` is the natural-space prior times the Jacobian of the
transform, ``|d theta / d phi| = I0 * kd (1 - kd) * gamma * sigma2`` (see
:meth:`Prior.logpdf_phi`). Leaving that Jacobian out would sample a different prior.

Presets
-------
``default``
    Respects the supports and is proper (needed: Bayes factors between numbers of
    regions depend on the prior's normalisation). ``I0 ~ LogNormal(log I0_ref, 1.5)`` with
    ``I0_ref`` the median of ``y / (E <l.n> / pi)`` (a light empirical-Bayes centring: the
    irradiance units of a data set are arbitrary), ``kd ~ Uniform(0, 1)``,
    ``gamma ~ LogNormal(log 10, 1.5)``, ``sigma2 ~ LogNormal(log s2_ref, 3)`` with
    ``s2_ref = 1e-3 var(y)``.
``paper-synthetic`` / ``paper-real``
    The structure of the paper's Tables 1 and 3 (uniform priors, starting values, normal
    random-walk proposal widths). NOTE: the numerical entries of those tables could not be
    read in the session that wrote this module; the numbers below are placeholders of the
    right kind and must be checked against the paper before a reproduction is claimed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import special

__all__ = ["PARAM_NAMES", "ParamPrior", "Prior", "make_prior", "to_phi", "from_phi", "PRESETS"]

PARAM_NAMES = ("I0", "kd", "gamma", "sigma2")
PRESETS = ("default", "paper-synthetic", "paper-real")
_SQRT_2PI = math.sqrt(2.0 * math.pi)


@dataclass(frozen=True)
class ParamPrior:
    """A one-dimensional prior: ``kind`` in {'lognormal', 'uniform', 'beta', 'invgamma'} with parameters a, b.

    lognormal: log x ~ N(a, b^2); uniform: x ~ U(a, b); beta: x ~ Beta(a, b);
    invgamma: x ~ InvGamma(shape a, scale b).
    """

    kind: str
    a: float
    b: float

    def __post_init__(self):
        if self.kind not in ("lognormal", "uniform", "beta", "invgamma"):
            raise ValueError(f"prior kind must be lognormal, uniform, beta or invgamma, got {self.kind!r}")
        if self.kind in ("beta", "invgamma") and not self.a > 0:
            raise ValueError(f"{self.kind} prior needs a positive first parameter, got {self.a}")
        if self.kind == "uniform" and not self.a < self.b:
            raise ValueError(f"uniform prior needs a < b, got ({self.a}, {self.b})")
        if self.kind in ("lognormal", "beta", "invgamma") and not self.b > 0:
            raise ValueError(f"{self.kind} prior needs a positive second parameter, got {self.b}")

    def logpdf(self, x):
        x = np.asarray(x, dtype=float)
        if self.kind == "lognormal":
            with np.errstate(divide="ignore", invalid="ignore"):
                logx = np.log(np.where(x > 0, x, 1.0))
                out = -0.5 * ((logx - self.a) / self.b) ** 2 - logx - np.log(self.b * np.sqrt(2 * np.pi))
            return np.where(x > 0, out, -np.inf)
        if self.kind == "uniform":
            return np.where((x >= self.a) & (x <= self.b), -np.log(self.b - self.a), -np.inf)
        # closed forms rather than scipy.stats: these run inside every birth/death proposal
        if self.kind == "invgamma":
            with np.errstate(divide="ignore", invalid="ignore"):
                safe = np.where(x > 0, x, 1.0)
                out = (self.a * np.log(self.b) - special.gammaln(self.a) - (self.a + 1.0) * np.log(safe) - self.b / safe)
            return np.where(x > 0, out, -np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            inside = (x > 0) & (x < 1)
            safe = np.where(inside, x, 0.5)
            out = (self.a - 1.0) * np.log(safe) + (self.b - 1.0) * np.log1p(-safe) - special.betaln(self.a, self.b)
        return np.where(inside, out, -np.inf)

    def logpdf_scalar(self, x: float) -> float:
        """Fast scalar :meth:`logpdf` (the per-region moves call it millions of times)."""
        if self.kind == "lognormal":
            if x <= 0:
                return -math.inf
            logx = math.log(x)
            return -0.5 * ((logx - self.a) / self.b) ** 2 - logx - math.log(self.b * _SQRT_2PI)
        if self.kind == "uniform":
            return -math.log(self.b - self.a) if self.a <= x <= self.b else -math.inf
        if self.kind == "invgamma":
            if x <= 0:
                return -math.inf
            return self.a * math.log(self.b) - math.lgamma(self.a) - (self.a + 1.0) * math.log(x) - self.b / x
        if not 0.0 < x < 1.0:
            return -math.inf
        return ((self.a - 1.0) * math.log(x) + (self.b - 1.0) * math.log1p(-x)
                - (math.lgamma(self.a) + math.lgamma(self.b) - math.lgamma(self.a + self.b)))

    def sample(self, rng, size=None):
        if self.kind == "lognormal":
            return np.exp(rng.normal(self.a, self.b, size))
        if self.kind == "uniform":
            return rng.uniform(self.a, self.b, size)
        if self.kind == "invgamma":
            return self.b / rng.gamma(self.a, 1.0, size)
        return rng.beta(self.a, self.b, size)

    def support(self) -> tuple[float, float]:
        """The prior's support (lower, upper): finite for 'uniform' (a, b) and 'beta' (0, 1), (0, inf) else."""
        if self.kind == "uniform":
            return float(self.a), float(self.b)
        return (0.0, 1.0) if self.kind == "beta" else (0.0, math.inf)

    def central_interval(self, mass: float) -> tuple[float, float]:
        """The interval holding the central ``mass`` of this prior (quantiles (1 - mass) / 2 and (1 + mass) / 2).

        Raises
        ------
        ValueError
            If ``mass`` is not in (0, 1).
        """
        if not 0.0 < mass < 1.0:
            raise ValueError(f"mass must lie in (0, 1), got {mass}")
        low, high = 0.5 * (1.0 - mass), 0.5 * (1.0 + mass)
        if self.kind == "lognormal":
            z = float(special.ndtri(high))
            return math.exp(self.a - z * self.b), math.exp(self.a + z * self.b)
        if self.kind == "uniform":
            return self.a + low * (self.b - self.a), self.a + high * (self.b - self.a)
        if self.kind == "invgamma":       # 1 / x ~ Gamma(a, rate b): its quantiles, reversed
            return (self.b / float(special.gammaincinv(self.a, high)),
                    self.b / float(special.gammaincinv(self.a, low)))
        return float(special.betaincinv(self.a, self.b, low)), float(special.betaincinv(self.a, self.b, high))

    def to_json(self):
        return {"kind": self.kind, "a": float(self.a), "b": float(self.b)}


@dataclass(frozen=True)
class Prior:
    """Independent priors of the four region parameters, plus a preset's start and widths.

    Attributes
    ----------
    params : tuple of 4 ParamPrior
        In the order ``PARAM_NAMES``.
    start : ndarray (4,) or None
        Starting values (natural space); None draws starts from the prior's bulk.
    proposal_sd : ndarray (4,)
        Normal random-walk widths (natural space) of the paper-style component-wise sampler.
    name : str
    caveat : str or None
        What a user of this prior must know before trusting a fit made with it (the paper
        presets' numbers are placeholders); a fit records it and lists it among its warnings.
    """

    params: tuple
    start: np.ndarray | None = None
    proposal_sd: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.01, 0.1, 0.01]))
    name: str = "custom"
    caveat: str | None = None

    def logpdf(self, theta):
        """Log prior density in natural space; ``theta`` has shape (..., 4)."""
        theta = np.asarray(theta, dtype=float)
        return sum(p.logpdf(theta[..., i]) for i, p in enumerate(self.params))

    def logpdf_scalar(self, I0, kd, gamma, sigma2) -> float:
        """Fast :meth:`logpdf` of one parameter vector given as four floats."""
        p = self.params
        return p[0].logpdf_scalar(I0) + p[1].logpdf_scalar(kd) + p[2].logpdf_scalar(gamma) + p[3].logpdf_scalar(sigma2)

    def logpdf_phi_components(self, phi):
        """Per-component log densities (..., 4) of ``phi``, each with its transform's Jacobian."""
        phi = np.asarray(phi, dtype=float)
        theta = from_phi(phi)
        log_jac = np.stack([phi[..., 0], -np.logaddexp(0.0, -phi[..., 1]) - np.logaddexp(0.0, phi[..., 1]),
                            phi[..., 2], phi[..., 3]], axis=-1)
        return np.stack([p.logpdf(theta[..., i]) for i, p in enumerate(self.params)], axis=-1) + log_jac

    def logpdf_phi_scalar(self, phi) -> float:
        """Fast :meth:`logpdf_phi` for one phi vector (a sequence of 4 floats)."""
        l0, l1, l2, l3 = (float(x) for x in phi)
        kd = 1.0 / (1.0 + math.exp(-l1)) if l1 > -700 else 0.0
        log_jac_kd = -_softplus(-l1) - _softplus(l1)
        return (self.logpdf_scalar(math.exp(l0), kd, math.exp(l2), math.exp(l3)) + l0 + log_jac_kd + l2 + l3)

    def logpdf_phi(self, phi):
        """Log density of ``phi = (log I0, logit kd, log g, log s2)``, Jacobian included."""
        return np.sum(self.logpdf_phi_components(phi), axis=-1)

    def sample(self, rng, size=None):
        shape = () if size is None else (size,)
        return np.stack([p.sample(rng, shape) for p in self.params], axis=-1)

    def to_json(self):
        return {"name": self.name, **{n: p.to_json() for n, p in zip(PARAM_NAMES, self.params)},
                "start": None if self.start is None else [float(s) for s in self.start],
                "proposal_sd": [float(s) for s in self.proposal_sd], "caveat": self.caveat}


def _softplus(x: float) -> float:
    return x + math.log1p(math.exp(-x)) if x > 0 else math.log1p(math.exp(x))


def to_phi(theta):
    """Natural ``(I0, kd, gamma, sigma2)`` -> unconstrained ``phi``."""
    theta = np.asarray(theta, dtype=float)
    return np.stack([np.log(theta[..., 0]), special.logit(theta[..., 1]),
                     np.log(theta[..., 2]), np.log(theta[..., 3])], axis=-1)


def from_phi(phi):
    """Unconstrained ``phi`` -> natural ``(I0, kd, gamma, sigma2)``."""
    phi = np.asarray(phi, dtype=float)
    return np.stack([np.exp(phi[..., 0]), special.expit(phi[..., 1]),
                     np.exp(phi[..., 2]), np.exp(phi[..., 3])], axis=-1)


def make_prior(name: str = "default", *, y=None, diffuse_scale=None) -> Prior:
    """Build a prior preset.

    Parameters
    ----------
    name : {'default', 'paper-synthetic', 'paper-real'}
    y, diffuse_scale : ndarray, optional
        Observed values and ``E <l.n> / pi`` per observation; the ``default`` preset
        centres ``I0`` on ``median(y / diffuse_scale)`` and ``sigma2`` on ``1e-3 var(y)``.
        Without them it centres on 1 and 1e-2. The paper presets ignore them.

    Returns
    -------
    Prior
        The preset's per-parameter priors, start point (None for ``default``) and
        proposal scales.

    Raises
    ------
    ValueError
        If ``name`` is not one of :data:`PRESETS`.
    """
    if name == "default":
        if y is not None and diffuse_scale is not None:
            ratio = np.asarray(y, float) / np.maximum(np.asarray(diffuse_scale, float), 1e-12)
            i0_ref = float(np.median(ratio[np.isfinite(ratio) & (ratio > 0)])) if np.any(ratio > 0) else 1.0
            s2_ref = float(max(1e-3 * np.var(y, dtype=np.float64), 1e-12))
        else:
            i0_ref, s2_ref = 1.0, 1e-2
        return Prior(params=(ParamPrior("lognormal", np.log(i0_ref), 1.5), ParamPrior("uniform", 0.0, 1.0),
                             ParamPrior("lognormal", np.log(10.0), 1.5), ParamPrior("lognormal", np.log(s2_ref), 3.0)),
                     start=None, proposal_sd=np.array([0.05 * i0_ref, 0.01, 0.1, 0.1 * s2_ref]), name=name)
    if name == "paper-synthetic":
        # Placeholders with the structure of the paper's Table 1 (see module docstring).
        return Prior(params=(ParamPrior("uniform", 0.0, 500.0), ParamPrior("uniform", 0.0, 1.0),
                             ParamPrior("uniform", 0.0, 100.0), ParamPrior("uniform", 0.0, 10.0)),
                     start=np.array([50.0, 0.5, 10.0, 1.0]), proposal_sd=np.array([0.5, 0.01, 0.1, 0.01]), name=name,
                     caveat=_placeholder_caveat(1))
    if name == "paper-real":
        # Placeholders with the structure of the paper's Table 3 (see module docstring).
        return Prior(params=(ParamPrior("uniform", 0.0, 5000.0), ParamPrior("uniform", 0.0, 1.0),
                             ParamPrior("uniform", 0.0, 200.0), ParamPrior("uniform", 0.0, 100.0)),
                     start=np.array([500.0, 0.5, 20.0, 10.0]), proposal_sd=np.array([5.0, 0.01, 0.2, 0.1]), name=name,
                     caveat=_placeholder_caveat(3))
    raise ValueError(f"unknown prior preset {name!r}: choose one of {', '.join(PRESETS)}")


def _placeholder_caveat(table: int) -> str:
    return (f"prior preset placeholders: the paper's Table {table} could not be read, so these priors, starting "
            f"values and proposal widths only have its structure (uniform priors, a fixed start, normal "
            f"random-walk widths); a fit with them is no reproduction of the paper's numbers")
