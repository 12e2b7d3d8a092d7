"""Proposals of a whole region's parameters from its own data (Laplace in log gamma, then conditionals).

Births, deaths and block shifts create or change regions; their parameters are drawn afresh
from a proposal built from the region's data alone: a deterministic Laplace fit of log
gamma's approximate marginal (:func:`laplace_log_gamma`), then sigma^2 and (a, b) from their
conditionals given the drawn gamma. The reverse move evaluates the same kind of proposal
for the parameters it removes, so old and new parameters swap places and the Jacobian is 1
(:func:`regions_term` gives a move's whole parameter term). A region with too few
observations (or whose fit fails) is proposed from the prior instead.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from rjfit.sampler.likelihood import LOG_2PI, STAT_N, RegionData, memoised
from rjfit.sampler.moves.ab_conditional import ab_conditional, draw_ab, log_q_ab
from rjfit.sampler.moves.gamma import ls_point_slopes, ls_profile_nonnegative
from rjfit.sampler.moves.region_terms import giesen_norm

__all__ = ["RegionProposalSettings", "LAPLACE_COARSE_OBS", "LAPLACE_GRID", "ssr_min", "ssr_min_rows",
           "sigma2_prior_as_invgamma",
           "laplace_log_gamma", "region_proposal", "draw_region", "log_q_region", "regions_term", "region_term"]

LAPLACE_COARSE_OBS = 4096
LAPLACE_GRID = np.linspace(math.log(0.2), math.log(500.0), 9)    # log gamma: the coarse search's points


@dataclass(frozen=True)
class RegionProposalSettings:
    """How a region's parameters are proposed afresh.

    Attributes
    ----------
    min_obs : int
        Regions whose effective count (observations times the likelihood power) is below
        this are proposed from the prior (flat option ``min_obs_conditional``, shared with
        the within-region moves: the conditional proposals need a well-posed sigma^2 shape).
    gamma_inflation : float
        Widening of the Laplace sd of log gamma (``birth_gamma_inflation``).
    """

    min_obs: int = 6
    gamma_inflation: float = 1.5


def ssr_min(stats_r):
    """``(SSR, det P)`` at the centre of the (a, b) conditional at this gamma, or None (singular, or SSR <= 0).

    :func:`ssr_min_rows`' one-row case (one compiled call: cheaper than the conditional's Python floats).
    """
    ssr, det = ssr_min_rows(np.asarray(stats_r, np.float64).reshape(1, 7))
    return None if ssr[0] != ssr[0] else (float(ssr[0]), float(det[0]))


@njit(cache=True, nogil=True)
def ssr_min_rows(stats):
    """``(SSR, det P)`` of each row of ``stats`` (G, 7) at the centre of its (a, b) conditional: two (G,) arrays, NaN
    in both where the system is singular or SSR <= 0 (:func:`ssr_min` of one row).

    The centre and the refusals are :func:`~rjfit.sampler.moves.ab_conditional.ab_conditional`'s at sigma^2 = 1,
    the same operations in the same order (so the same floats); the SSR is written out in full because the centre
    may be the non-negative one. Compiled: a Laplace fit's coarse grid asks for nine rows at once.
    """
    G = stats.shape[0]
    ssr_out = np.full(G, np.nan)
    det_out = np.full(G, np.nan)
    for i in range(G):
        syy, sya, saa, syb, sab, sbb = stats[i, 1], stats[i, 2], stats[i, 3], stats[i, 4], stats[i, 5], stats[i, 6]
        det = saa * sbb - sab * sab
        if not (saa > 0 and sbb > 0 and det > 1e-10 * saa * sbb):
            continue
        ma = (sbb * sya - sab * syb) / det
        mb = (saa * syb - sab * sya) / det
        if ma < 0 or mb < 0:
            pa, pb = max(sya, 0.0), max(syb, 0.0)
            if pa * pa / saa >= pb * pb / sbb:
                ma, mb = pa / saa, 0.0
            else:
                ma, mb = 0.0, pb / sbb
        caa, cab, cbb = 1.0 * sbb / det, -1.0 * sab / det, 1.0 * saa / det
        if not (np.isfinite(caa) and np.isfinite(cbb) and np.isfinite(ma) and np.isfinite(mb)) or caa <= 0:
            continue
        lc = cab / np.sqrt(caa)
        lb2 = cbb - lc * lc
        if not (np.isfinite(lb2) and lb2 > 0):
            continue
        ssr = syy - 2.0 * (ma * sya + mb * syb) + ma * ma * saa + 2.0 * ma * mb * sab + mb * mb * sbb
        if ssr > 0:
            ssr_out[i] = ssr
            det_out[i] = det
    return ssr_out, det_out


def sigma2_prior_as_invgamma(prior):
    """(shape, scale) of an inverse gamma standing in for sigma^2's prior in proposals ((0, 0): none)."""
    p = prior.params[3]
    if p.kind == "invgamma":
        return p.a, p.b
    if p.kind == "lognormal":       # match mean and variance of 1 / sigma^2 (lognormal(-a, b))
        mean = math.exp(-p.a + 0.5 * p.b ** 2)
        shape = 1.0 / math.expm1(p.b ** 2)
        return shape, shape / mean
    return 0.0, 0.0


def _thinned(data, max_obs):
    """Every m-th observation of a region (sums scaled by m), or the region itself if it is small."""
    m = data.n // max_obs
    if m < 2:
        return data
    return data.thinned(m)


def laplace_log_gamma(data, prior):
    """Deterministic Laplace fit (mean, sd) of log gamma's approximate marginal, or None.

    ``h(l) = -(n/2 - 1 + a0) log(SSR_min(l)/2 + b0) - log det P(l) / 2 + log p_gamma(e^l) + l``
    with (a0, b0) the inverse gamma standing in for sigma^2's prior: (a, b) and sigma^2
    integrated out under flat priors for (a, b). The mode is located on a coarse grid
    evaluated on a thinning of the region (at most :data:`LAPLACE_COARSE_OBS`
    observations), then refined by Newton steps with the closed-form derivatives of
    :func:`~rjfit.sampler.moves.gamma.ls_profile_nonnegative` (the profile of the least
    squares over a, b >= 0, which ``SSR_min`` is), first on the thinning, then on the whole
    region from the thinning's mode: about 2 passes over the region instead of 18.
    Where that fails (a non-concave profile) it falls back to finite differences on the
    whole region, from the thinning's mode. A function of the region's data only, as a
    proposal's parameters must be: kept in ``data.memo`` for the next proposal of the same
    pixel set (:class:`~rjfit.sampler.pixel_sets.PixelSets`).
    """
    return memoised(data, "laplace", (prior,), lambda: _laplace_log_gamma(data, prior))


def _laplace_log_gamma(data, prior):
    """:func:`laplace_log_gamma` computed."""
    n = data.n * data.weight       # observations count zeta each under a coarsened likelihood
    a0, b0 = sigma2_prior_as_invgamma(prior)
    g_prior = prior.params[2]
    k = 0.5 * n - 1.0 + a0

    def h_of_stats(stats_r, ell):
        res = ssr_min(stats_r)
        if res is None:
            return -np.inf
        return -k * math.log(0.5 * res[0] + b0) - 0.5 * math.log(res[1]) + g_prior.logpdf_scalar(math.exp(ell)) + ell

    def prior_part(ell):
        return g_prior.logpdf_scalar(math.exp(ell)) + ell

    grid = LAPLACE_GRID
    coarse = _thinned(data, LAPLACE_COARSE_OBS)
    # the grid's sums in one compiled call (nine calls from Python cost more than the sums)
    ssr, det = ssr_min_rows(coarse.stats_at_many(np.exp(grid)))
    values = [-k * math.log(0.5 * res + b0) - 0.5 * math.log(d) + g_prior.logpdf_scalar(math.exp(e)) + e
              if not math.isnan(res) else -np.inf for res, d, e in zip(ssr.tolist(), det.tolist(), grid.tolist())]
    best = int(np.argmax(values))
    if not np.isfinite(values[best]):
        return None
    # Newton on the thinning first (cheap), so the passes over the whole region start within
    # a few posterior sds of its mode: about 2 of them instead of 4 to 5 from a grid point.
    start = grid[best]
    if coarse is not data:
        coarse_fit = _laplace_newton([coarse], start, [k], b0, prior_part)
        if coarse_fit is not None:
            start = coarse_fit[2]
    newton = _laplace_newton([data], start, [k], b0, prior_part)
    if newton is not None:
        return newton[:2]
    # the fallback starts where the thinning put the mode: 1 + 2 to 9 passes, not the grid's 9 more
    return _laplace_finite_differences(lambda ell: h_of_stats(data.stats_at(math.exp(ell)), ell), start,
                                       grid[1] - grid[0])


def _laplace_derivatives(channels, ell, ks, b0, prior_part, pieces=None, eps=1e-3):
    """``(h', h'', pieces)`` of the Laplace objective at ``ell`` summed over ``channels``, or None where undefined.

    Each channel's terms from :func:`~rjfit.sampler.moves.gamma.ls_profile_nonnegative` (on
    the piece given in ``pieces``, else the one that applies), the prior's by central
    differences (step ``eps``), once; ``pieces`` returned is the tuple of the channels' pieces.
    """
    g = math.exp(ell)
    h1 = h2 = 0.0
    used = []
    for c, (channel, k) in enumerate(zip(channels, ks)):
        syy, sya, saa = channel.fixed[1], channel.fixed[2], channel.fixed[3]
        profile = ls_profile_nonnegative(sya, saa, channel.b_sums_newton(g), g, None if pieces is None else pieces[c])
        if profile is None:
            return None
        f, f1, f2, det, det1, det2, piece = profile
        q = 0.5 * (syy - f) + b0
        if not q > 0:
            return None
        h1 += k * f1 / (2.0 * q) - 0.5 * det1 / det
        h2 += k * f2 / (2.0 * q) + k * f1 * f1 / (4.0 * q * q) - 0.5 * (det2 / det - (det1 / det) ** 2)
        used.append(piece)
    p0, pp, pm = prior_part(ell), prior_part(ell + eps), prior_part(ell - eps)
    h1 += (pp - pm) / (2.0 * eps)
    h2 += (pp - 2.0 * p0 + pm) / eps ** 2
    return h1, h2, tuple(used)


def _laplace_newton(channels, ell, ks, b0, prior_part, max_steps=8):
    """Newton steps to the mode of the Laplace objective summed over ``channels``: (mean, sd, mode), or None.

    None where the objective is undefined or not concave at an iterate, or after
    ``max_steps`` without convergence (a step below 0.2 sd: what is left is O(step^2)).
    The constrained profile's curvature jumps where a face starts to bind (often a
    hundredfold), and a mode at that kink would make plain Newton steps cycle between its
    two sides: each step is kept inside the bracket of the iterates seen on either side of
    the mode; where Newton's leaves it and the bracket's ends lie on two pieces, the kink
    between them is found (:func:`_kink`), and a mode within an sd of it gets the mean and
    sd of the quadratic expansions on either side (:func:`_kinked_moments`); otherwise a
    secant step. ``mode`` is where h peaks (the next fit's start).
    """
    below = above = None            # (ell, h', h'', pieces) of the nearest iterates with h' > 0 and h' <= 0
    for _ in range(max_steps):
        derivs = _laplace_derivatives(channels, ell, ks, b0, prior_part)
        if derivs is None:
            return None
        h1, h2, pieces = derivs
        if not (math.isfinite(h1) and math.isfinite(h2) and h2 < 0):
            return None
        if h1 > 0:
            below = (ell, h1, h2, pieces)
        else:
            above = (ell, h1, h2, pieces)
        sd = 1.0 / math.sqrt(-h2)
        step = min(max(-h1 / h2, -0.5), 0.5)
        if below is not None and above is not None and below[0] < above[0] and not below[0] < ell + step < above[0]:
            kink = _kink(channels, below, above, ks, b0, prior_part) if below[3] != above[3] else None
            if kink is not None:
                at, h1, h2_below, h2_above = kink
                mode = at - h1 / (h2_above if h1 > 0 else h2_below)
                moments = _kinked_moments(at, h1, h2_below, h2_above)
                if moments is not None and abs(mode - at) < 1.0 / math.sqrt(-(h2_above if h1 > 0 else h2_below)):
                    return moments[0], min(max(moments[1], 1e-4), 2.0), mode
                if h1 > 0:
                    below = (at, h1, h2_above, above[3])
                else:
                    above = (at, h1, h2_below, below[3])
                ell = mode
                continue
            step = below[0] - below[1] * (above[0] - below[0]) / (above[1] - below[1]) - ell
        ell += step
        if abs(step) < 0.2 * sd:
            return ell, min(max(sd, 1e-4), 2.0), ell
    return None


def _kink(channels, below, above, ks, b0, prior_part, max_steps=6):
    """Where the constrained profile changes piece between bracket ends ``below`` and ``above``.

    Returns ``(ell, h', h'' below, h'' above)`` there (each side's curvature from its own
    piece's formula), or None where the ends differ in more than one channel, neither is
    inside (piece 0), or the search fails. The kink is where the unconstrained
    least-squares a (piece 1) or b (piece 2) of that channel crosses 0: Newton steps on
    that smooth function (:func:`~rjfit.sampler.moves.gamma.ls_point_slopes`), kept inside
    the bracket, to within a hundredth of the narrower side's sd.
    """
    differ = [c for c, (p, q) in enumerate(zip(below[3], above[3])) if p != q]
    if len(differ) != 1 or 0 not in (below[3][differ[0]], above[3][differ[0]]):
        return None
    c = differ[0]
    which = 0 if max(below[3][c], above[3][c]) == 1 else 1          # a (piece 1) or b (piece 2) crosses 0
    channel = channels[c]
    lo, hi = below[0], above[0]
    tol = 0.01 / math.sqrt(max(-below[2], -above[2]))
    ell = lo if below[3][c] == 0 else hi
    for _ in range(max_steps):
        g = math.exp(ell)
        slopes = ls_point_slopes(channel.fixed[2], channel.fixed[3], channel.b_sums_newton(g), g)
        if slopes is None or slopes[2 + which] == 0:
            return None
        step = -slopes[which] / slopes[2 + which]
        new = ell + step if lo < ell + step < hi else 0.5 * (lo + hi)
        done = abs(new - ell) < tol
        ell = new
        if done:
            break
    else:
        return None
    sides = [_laplace_derivatives(channels, ell, ks, b0, prior_part, pieces) for pieces in (below[3], above[3])]
    if any(side is None or not (math.isfinite(side[0]) and side[1] < 0) for side in sides):
        return None
    return ell, sides[0][0], sides[0][1], sides[1][1]


def _kinked_moments(at, slope, curv_below, curv_above):
    """Mean and sd of ``exp(h)`` for ``h(x) = slope t + curv t^2 / 2`` (``t = x - at``), ``curv`` one value below
    ``at`` and another above: the quadratic expansion on each side of a kink, each side a truncated normal.

    None where neither side has any mass in double precision.
    """
    pieces = []
    for curv, upper in ((curv_below, False), (curv_above, True)):
        s = 1.0 / math.sqrt(-curv)
        mu = at - slope / curv                         # the side's own quadratic, completed
        alpha = (at - mu) / s
        z = 0.5 * math.erfc(alpha / math.sqrt(2.0)) if upper else 0.5 * math.erfc(-alpha / math.sqrt(2.0))
        if z <= 0.0:
            continue
        ratio = math.exp(-0.5 * alpha * alpha) / math.sqrt(2.0 * math.pi) / z
        sign = 1.0 if upper else -1.0
        mean = mu + sign * s * ratio
        var = s * s * (1.0 + sign * alpha * ratio - ratio * ratio)
        pieces.append((math.log(s) + 0.5 * (slope * s) ** 2 + math.log(z), mean, max(var, 0.0)))
    if not pieces:
        return None
    top = max(p[0] for p in pieces)
    weights = [math.exp(p[0] - top) for p in pieces]
    total = sum(weights)
    mean = sum(w * p[1] for w, p in zip(weights, pieces)) / total
    var = sum(w * (p[2] + (p[1] - mean) ** 2) for w, p in zip(weights, pieces)) / total
    return mean, math.sqrt(var)


def _laplace_finite_differences(h, centre, delta):
    """(mean, sd) from parabolas through ``h`` at ``centre`` and ``centre +- delta``, three times, delta / 3 each.

    The Laplace fit's fallback where Newton fails; ``centre`` is the thinning's mode (or
    the coarse grid's best point) and ``delta`` the grid's step. None where ``h(centre)`` is
    not finite; sd 2 where the curvature is not negative (a flat or rising profile).
    """
    h0 = h(centre)
    if not np.isfinite(h0):
        return None
    curvature = -1.0
    for _ in range(3):
        hm, hp = h(centre - delta), h(centre + delta)
        curvature = (hp - 2 * h0 + hm) / (delta * delta)
        if not (np.isfinite(hm) and np.isfinite(hp)) or curvature >= 0:
            break
        shift = min(max(-0.5 * (hp - hm) / delta / curvature, -delta), delta)
        centre += shift
        h0 = h(centre)
        delta /= 3.0
    sd = 1.0 / math.sqrt(-curvature) if np.isfinite(curvature) and curvature < 0 else 2.0
    return centre, min(max(sd, 1e-4), 2.0)


def _prior_in_q_coords(prior, theta, conditional):
    """Log prior density of a region's parameters in the coordinates its proposal uses.

    The likelihood is not included: the moves take it from the full recompute.
    """
    I0, kd, g, s2 = theta
    if conditional:      # coordinates (a, b, log gamma, sigma^2)
        return prior.logpdf_scalar(I0, kd, g, s2) - math.log(I0) - math.log(giesen_norm(g)) + math.log(g)
    return prior.logpdf_scalar(I0, kd, g, s2)   # natural coordinates


def region_proposal(data, settings: RegionProposalSettings, prior):
    """What proposes a region's parameters: ('conditional', laplace) or ('prior', None).

    The count is the effective one (observations times the likelihood power), as in the
    within-region moves: the conditional proposals need a well-posed sigma^2 shape.
    """
    if data.n * data.weight < settings.min_obs:
        return ("prior", None)
    lap = laplace_log_gamma(data, prior)
    return ("prior", None) if lap is None else ("conditional", lap)


def draw_region(rng, data, proposal, prior, settings: RegionProposalSettings):
    """Draw a region's parameters; returns (theta, log q) or None if invalid."""
    kind, lap = proposal
    if kind == "prior":
        theta = prior.sample(rng)
        I0, kd, g, s2 = (float(t) for t in theta)
        return (I0, kd, g, s2), prior.logpdf_scalar(I0, kd, g, s2)
    mean, sd = lap
    sd *= settings.gamma_inflation
    ell = mean + sd * rng.normal()
    g = math.exp(ell)
    stats_r = data.stats_at(g)
    res = ssr_min(stats_r)
    if res is None:
        return None
    shape, scale = _sigma2_proposal(stats_r, res, prior)
    s2 = scale / rng.gamma(shape)
    cond = ab_conditional(stats_r, s2)
    if cond is None:
        return None
    a, b = draw_ab(cond, rng)
    if a <= 0 or b <= 0:
        return None
    I0 = a + b / giesen_norm(g)
    theta = (I0, a / I0, g, s2)
    return theta, log_q_region(theta, stats_r, proposal, prior, settings)


def _sigma2_proposal(stats_r, res, prior):
    """Inverse gamma of sigma^2 given gamma ((a, b) integrated out), prior folded in approximately."""
    a0, b0 = sigma2_prior_as_invgamma(prior)
    return 0.5 * stats_r[STAT_N] - 1.0 + a0, 0.5 * res[0] + b0


def log_q_region(theta, stats_r, proposal, prior, settings: RegionProposalSettings):
    """Log density of proposing ``theta`` for a region with statistics ``stats_r`` (at ``theta``'s gamma)."""
    kind, lap = proposal
    I0, kd, g, s2 = theta
    if kind == "prior":
        return prior.logpdf_scalar(I0, kd, g, s2)
    mean, sd = lap
    sd *= settings.gamma_inflation
    res = ssr_min(stats_r)
    cond = ab_conditional(stats_r, s2)
    if res is None or cond is None:
        return -np.inf
    shape, scale = _sigma2_proposal(stats_r, res, prior)
    log_ig = shape * math.log(scale) - math.lgamma(shape) - (shape + 1.0) * math.log(s2) - scale / s2
    a, b = I0 * kd, I0 * (1.0 - kd) * giesen_norm(g)
    return (-0.5 * ((math.log(g) - mean) / sd) ** 2 - math.log(sd) - 0.5 * LOG_2PI + log_ig + log_q_ab(a, b, cond))


def regions_term(problem, prior, settings: RegionProposalSettings, labels, theta, regions, draw_rng=None):
    """Sum over ``regions`` of (log prior in q-coordinates - log q); draws new parameters if ``draw_rng``.

    Returns (theta, total) where theta has the drawn parameters filled in (or ``(None,
    -inf)`` if a draw was invalid).
    """
    total = 0.0
    theta = theta.copy()
    split = RegionData.split(problem, labels, theta.shape[0])
    for r in regions:
        theta_r, term = region_term(split[r], theta[r], prior, settings, draw_rng)
        if theta_r is None:
            return None, -np.inf
        theta[r] = theta_r
        total += term
    return theta, total


def region_term(data, theta_r, prior, settings: RegionProposalSettings, draw_rng=None):
    """One region's (log prior in q-coordinates - log q) for its data ``data`` (a :class:`RegionData`).

    With ``draw_rng`` the parameters are drawn from the proposal first (``theta_r`` is then
    ignored). Returns ``(theta_r, term)``, or ``(None, -inf)`` if a draw was invalid. What
    a move that creates (removes) a region whose parameters are drawn afresh from its data
    adds to (subtracts from) its log ratio, Jacobian 1.
    """
    proposal = region_proposal(data, settings, prior)
    if draw_rng is not None:
        drawn = draw_region(draw_rng, data, proposal, prior, settings)
        if drawn is None:
            return None, -np.inf
        theta_r, log_q = drawn
    else:
        theta_r = tuple(float(t) for t in theta_r)
        log_q = log_q_region(theta_r, data.stats_at(theta_r[2]), proposal, prior, settings)
    return np.asarray(theta_r, float), _prior_in_q_coords(prior, tuple(theta_r), proposal[0] == "conditional") - log_q
