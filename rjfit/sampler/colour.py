"""A joint colour fit (``rjfit fit --channel rgb``): one segmentation, one lobe per material, per-channel amplitudes.

The problem holds every channel's observations (:attr:`~rjfit.sampler.forward.Problem.channel`);
a material owns C parameter rows ``(I0_c, kd_c, gamma, sigma2_c)``, row ``k C + c`` for
material k and channel c, all C sharing gamma. Each row has its own sufficient statistics
(the observation labels are rows: ``k C + c``), so the likelihood of a material is the sum
of its rows' (:func:`rjfit.sampler.likelihood.log_likelihood_from_stats`, unchanged): given
gamma the channels are independent linear models, each with its own (a, b) and noise.

The prior: per channel the single-channel priors of I0, kd and sigma^2, and gamma's prior
once per material (:func:`log_prior_phi`). The within-material moves
(:mod:`rjfit.sampler.moves.colour_within`) redraw each row's (a, b) and sigma^2 as the
single-channel moves do (given gamma they see one row), and move gamma jointly with every
row's (a, b). The label moves see a material through its rows: a set of pixels has C
statistics rows at a gamma (:class:`PixelSetData`), and a born or dying material's
parameters are proposed (evaluated) given one gamma from a Laplace fit of gamma's
approximate marginal summed over the channels (:func:`material_term`).

With C = 1 every function here hands over to the single-channel code with the same
arguments and draws (a fit of one channel gives the same numbers as before, bit for bit).
"""
from __future__ import annotations

import math

import numpy as np

from rjfit.sampler.likelihood import LOG_2PI, STAT_N, RegionData, b_terms, log_likelihood_from_stats, memoised
from rjfit.sampler.moves.ab_conditional import ab_conditional, draw_ab, log_q_ab
from rjfit.sampler.moves.region_proposals import (
    LAPLACE_COARSE_OBS,
    LAPLACE_GRID,
    _laplace_finite_differences,
    _laplace_newton,
    _sigma2_proposal,
    _thinned,
    laplace_log_gamma,
    region_term,
    sigma2_prior_as_invgamma,
    ssr_min,
)
from rjfit.sampler.moves.region_terms import giesen_norm
from rjfit.sampler.priors import to_phi

__all__ = ["material_rows", "log_prior_phi", "PixelSetData", "pixel_set_data", "material_log_lik", "material_term",
           "laplace_log_gamma_colour", "guide_rows", "colour_pixel_features", "starting_theta"]


def material_rows(material: int, n_channels: int) -> slice:
    """The parameter rows of ``material``: ``k C .. k C + C - 1``."""
    return slice(material * n_channels, (material + 1) * n_channels)


def log_prior_phi(prior, theta, n_channels: int) -> float:
    """Log prior density of every material's rows in phi coordinates: each row's, gamma's counted once per material."""
    if n_channels == 1:      # the single-channel sum, in its order
        return float(np.sum(prior.logpdf_phi(to_phi(theta))))
    components = prior.logpdf_phi_components(to_phi(theta))
    return float(np.sum(components[:, [0, 1, 3]]) + np.sum(components[::n_channels, 2]))


class PixelSetData:
    """The observations of a set of pixels, one :class:`RegionData` per channel (runs of the problem's arrays).

    ``stats_at(gamma)`` gives their C statistics rows (C, 7) at one gamma.
    """

    def __init__(self, channels):
        self.channels = list(channels)
        self.memo = {}      # what is derived from these observations alone (rjfit.sampler.likelihood.memoised)

    @property
    def n(self) -> int:
        return sum(data.n for data in self.channels)

    def stats_at(self, gamma: float) -> np.ndarray:
        return np.stack([data.stats_at(gamma) for data in self.channels])

    @property
    def idx(self) -> np.ndarray:
        """Every channel's observation indices, ascending."""
        return np.sort(np.concatenate([data.idx for data in self.channels]))


def pixel_set_data(problem, members):
    """The observations of the pixels ``members`` (ascending): a :class:`RegionData` for one channel, else a
    :class:`PixelSetData`."""
    n_ch = problem.n_channels
    if n_ch == 1:
        starts = problem.pixel_start[members].astype(np.int64)
        ends = problem.pixel_start[members + 1].astype(np.int64)
        keep = ends > starts
        return RegionData(y=problem.y, C=problem.C, log_cos_hn=problem.log_cos_hn, runs=(starts[keep], ends[keep]),
                          weight=problem.likelihood_power, lobe=problem.lobe)
    bounds = problem.channel_start
    channels = []
    for c in range(n_ch):
        starts, ends = bounds[members * n_ch + c], bounds[members * n_ch + c + 1]
        keep = ends > starts
        channels.append(RegionData(y=problem.y, C=problem.C, log_cos_hn=problem.log_cos_hn,
                                   runs=(starts[keep], ends[keep]), weight=problem.likelihood_power))
    return PixelSetData(channels)


def material_log_lik(stats_rows, theta_rows) -> float:
    """A material's log-likelihood: the sum of its rows' (one row: that row's, as a float)."""
    return float(np.sum(log_likelihood_from_stats(stats_rows, theta_rows)))


def laplace_log_gamma_colour(data: PixelSetData, prior):
    """Laplace fit (mean, sd) of log gamma's approximate marginal over every channel, or None.

    ``h(l) = sum_c [-(n_c/2 - 1 + a0) log(SSR_c(l)/2 + b0) - log det P_c(l) / 2] + log p_gamma(e^l) + l``:
    each channel's (a, b) and sigma^2 integrated out as in
    :func:`~rjfit.sampler.moves.region_proposals.laplace_log_gamma`, the channels
    independent given gamma. As there: the grid on a thinning of each channel (at most
    :data:`~rjfit.sampler.moves.region_proposals.LAPLACE_COARSE_OBS` observations), Newton
    steps with the closed-form derivatives (the channels' summed) on the thinning, then on
    every observation; finite differences from the thinning's mode where Newton fails. A function of
    the data only (kept in ``data.memo``).
    """
    return memoised(data, "laplace", (prior,), lambda: _laplace_colour(data, prior))


def _laplace_colour(data: PixelSetData, prior):
    """:func:`laplace_log_gamma_colour` computed."""
    a0, b0 = sigma2_prior_as_invgamma(prior)
    g_prior = prior.params[2]
    ks = [0.5 * channel.n * channel.weight - 1.0 + a0 for channel in data.channels]

    def prior_part(ell):
        return g_prior.logpdf_scalar(math.exp(ell)) + ell

    def h_of_stats(stats_rows, ell):
        total = prior_part(ell)
        for stats_c, k in zip(stats_rows, ks):
            res = ssr_min(stats_c)
            if res is None:
                return -np.inf
            total += -k * math.log(0.5 * res[0] + b0) - 0.5 * math.log(res[1])
        return total

    coarse = [_thinned(channel, LAPLACE_COARSE_OBS) for channel in data.channels]
    many = [channel.stats_at_many(np.exp(LAPLACE_GRID)) for channel in coarse]
    values = [h_of_stats([stats[i] for stats in many], ell) for i, ell in enumerate(LAPLACE_GRID)]
    best = int(np.argmax(values))
    if not np.isfinite(values[best]):
        return None
    start = LAPLACE_GRID[best]
    if any(c is not d for c, d in zip(coarse, data.channels)):
        coarse_fit = _laplace_newton(coarse, start, ks, b0, prior_part)
        if coarse_fit is not None:
            start = coarse_fit[2]
    newton = _laplace_newton(data.channels, start, ks, b0, prior_part)
    if newton is not None:
        return newton[:2]
    return _laplace_finite_differences(
        lambda ell: h_of_stats([channel.stats_at(math.exp(ell)) for channel in data.channels], ell), start,
        LAPLACE_GRID[1] - LAPLACE_GRID[0])


def _prior_in_q_coords(prior, theta_rows, conditional) -> float:
    """The material's log prior in its proposal's coordinates: ``(a_c, b_c, sigma2_c, log gamma)`` or natural."""
    g = float(theta_rows[0, 2])
    total = sum(prior.logpdf_scalar(*(float(t) for t in row)) for row in theta_rows)
    total -= (len(theta_rows) - 1) * prior.params[2].logpdf_scalar(g)        # gamma's prior once
    if conditional:
        total += -sum(math.log(float(row[0])) for row in theta_rows) - len(theta_rows) * math.log(giesen_norm(g))
        total += math.log(g)
    return total


def _draw_or_evaluate(data: PixelSetData, theta_rows, lap, prior, settings, rng):
    """``(theta rows, log q)`` of the conditional proposal given Laplace ``lap``; drawn when ``rng``; None if invalid."""
    mean, sd = lap
    sd *= settings.gamma_inflation
    ell = mean + sd * rng.normal() if rng is not None else math.log(float(theta_rows[0, 2]))
    g = math.exp(ell)
    log_q = -0.5 * ((ell - mean) / sd) ** 2 - math.log(sd) - 0.5 * LOG_2PI
    rows = []
    for c, channel in enumerate(data.channels):
        stats_c = channel.stats_at(g)
        res = ssr_min(stats_c)
        if res is None:
            return None
        shape, scale = _sigma2_proposal(stats_c, res, prior)
        s2 = scale / rng.gamma(shape) if rng is not None else float(theta_rows[c, 3])
        cond = ab_conditional(stats_c, s2)
        if cond is None:
            return None
        if rng is not None:
            a, b = draw_ab(cond, rng)
            if a <= 0 or b <= 0:
                return None
            I0 = a + b / giesen_norm(g)
            kd = a / I0
        else:
            I0, kd = float(theta_rows[c, 0]), float(theta_rows[c, 1])
            a, b = I0 * kd, I0 * (1.0 - kd) * giesen_norm(g)
        log_q += (shape * math.log(scale) - math.lgamma(shape) - (shape + 1.0) * math.log(s2) - scale / s2
                  + log_q_ab(a, b, cond))
        rows.append((I0, kd, g, s2))
    return np.array(rows, float), log_q


def _prior_draw(prior, n_channels, rng):
    """Rows drawn from the prior: one gamma, each channel's I0, kd and sigma^2."""
    g = float(prior.params[2].sample(rng))
    rows = [(float(prior.params[0].sample(rng)), float(prior.params[1].sample(rng)), g,
             float(prior.params[3].sample(rng))) for _ in range(n_channels)]
    return np.array(rows, float)


def material_term(data, theta_rows, prior, settings, draw_rng=None):
    """A material's ``(rows (C, 4), log prior in q-coordinates - log q)`` for its pixels' data.

    One channel (``data`` a :class:`RegionData`):
    :func:`~rjfit.sampler.moves.region_proposals.region_term` itself, its parameters as one
    row. Several: gamma from the Laplace fit over the channels
    (:func:`laplace_log_gamma_colour`), then per channel sigma^2 and (a, b) from their
    conditionals given it; from the prior where a channel has fewer effective observations
    than ``settings.min_obs`` or the fit fails. With ``draw_rng`` the rows are drawn first.
    ``(None, -inf)`` for an invalid draw.
    """
    if not isinstance(data, PixelSetData):
        theta_r, term = region_term(data, None if theta_rows is None else np.asarray(theta_rows)[0], prior, settings,
                                    draw_rng=draw_rng)
        return (None if theta_r is None else theta_r.reshape(1, 4)), term
    few = min(channel.n * channel.weight for channel in data.channels) < settings.min_obs
    lap = None if few else laplace_log_gamma_colour(data, prior)
    if lap is None:
        rows = _prior_draw(prior, len(data.channels), draw_rng) if draw_rng is not None else np.asarray(theta_rows)
        log_q = _prior_in_q_coords(prior, rows, False)
        return rows, 0.0 if np.isfinite(log_q) else -np.inf
    drawn = _draw_or_evaluate(data, None if draw_rng is not None else np.asarray(theta_rows, float), lap, prior,
                              settings, draw_rng)
    if drawn is None:
        return None, -np.inf
    rows, log_q = drawn
    return rows, _prior_in_q_coords(prior, rows, True) - log_q


def guide_rows(data, prior, fallback_gamma: float):
    """A deterministic fit of a pixel set's rows (the split guide's): gamma at the Laplace mode (else
    ``fallback_gamma``), per row (a, b) at their least-squares point there and sigma^2 the mean squared
    residual; None where a channel has no fit."""
    channels = data.channels if isinstance(data, PixelSetData) else [data]
    lap = laplace_log_gamma_colour(data, prior) if isinstance(data, PixelSetData) else laplace_log_gamma(data, prior)
    g = math.exp(lap[0]) if lap is not None else fallback_gamma
    rows = []
    for channel in channels:
        stats_r = channel.stats_at(g)
        cond, res = ab_conditional(stats_r, 1.0), ssr_min(stats_r)
        if cond is None or res is None or not (cond.ma + cond.mb > 0):
            return None
        I0 = cond.ma + cond.mb / giesen_norm(g)
        rows.append((I0, cond.ma / I0, g, max(res[0] / stats_r[STAT_N], 1e-12)))
    return np.array(rows, float)


def colour_pixel_features(problem, gamma: float) -> np.ndarray:
    """(H W, 2 C): each channel's per-pixel least-squares (a, b) at ``gamma`` (clipped at 0); NaN with < 3
    observations in a channel (the bonds' and split guides' features of a joint colour fit)."""
    n_pix = problem.height * problem.width
    pixel = np.asarray(problem.pixel, np.int64)
    y = problem.y.astype(np.float64)
    A = problem.A
    B = b_terms(problem.C, problem.log_cos_hn, gamma)
    columns = []
    for c in range(problem.n_channels):
        mine = problem.channel == c

        def sums(w, mine=mine):
            return np.bincount(pixel[mine], weights=w[mine], minlength=n_pix)

        s_ya, s_yb, s_aa, s_ab, s_bb = sums(y * A), sums(y * B), sums(A * A), sums(A * B), sums(B * B)
        count = np.bincount(pixel[mine], minlength=n_pix)
        det = s_aa * s_bb - s_ab * s_ab
        ok = (count >= 3) & (det > 1e-12 * np.maximum(s_aa * s_bb, 1e-300))
        safe = np.where(ok, det, 1.0)
        a = np.where(ok, np.clip((s_bb * s_ya - s_ab * s_yb) / safe, 0, None), np.nan)
        b = np.where(ok, np.clip((s_aa * s_yb - s_ab * s_ya) / safe, 0, None), np.nan)
        columns += [a, b]
    return np.stack(columns, axis=1)


def starting_theta(theta_materials, n_channels: int) -> np.ndarray:
    """Rows (K C, 4) from one row per material (K, 4): each channel starts at the material's row."""
    return np.repeat(np.asarray(theta_materials, float).reshape(-1, 4), n_channels, axis=0)
