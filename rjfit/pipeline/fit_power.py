"""A fit's noise scales and likelihood power, from its observations and options (``--noise``,
``--likelihood-power``): the known per-observation scales, the measured power suggestion (for
a joint colour fit per channel, with the channels' design effect) and the power the fit uses;
and the power, local gain and noise of its edge term (``--edge-power``, ``--edge-gain-sd``, ``--edge-noise``)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from rjfit.data.coarsen import area_likelihood_power, suggest_likelihood_power
from rjfit.data.noise import noise_scale, weighted_observations
from rjfit.data.normal_error import normal_error_noise
from rjfit.data.pixelfit import per_pixel_residuals
from rjfit.progress import phase
from rjfit.sampler.regions.materials.edges import edge_term
from rjfit.sampler.regions.materials.layout import labelled_pixels

__all__ = ["noise_and_power", "power_suggestion", "channel_normal_error_noise", "edge_settings", "normal_prior_sd",
           "misfit_tile_warnings", "MISFIT_TILE_SHARE_WARN",
           "MIN_NORMAL_SD_DEG"]


def edge_settings(problem, options) -> tuple:
    """``(power, gain_sd, noise, term)`` of the fit's edge term (:mod:`rjfit.sampler.regions.materials.edges`;
    power 0: none): each as given, or 'auto' ('measured' for the noise: its coefficients) measured once on
    ``problem`` (one build of the term for all), so that every chain takes those numbers and the summary records
    them; ``term`` the term that measured them (the one the chains take: built again from the three settings it is
    the same), or None where nothing was measured."""
    power, gain_sd, noise = options.edge_power, options.edge_gain_sd, options.edge_noise
    if power != "auto" and float(power) == 0:
        return 0.0, 0.0, "constant", None
    if power == "auto" or gain_sd == "auto" or noise == "measured":
        parts = [what for what, value in (("its power (--edge-power auto)", power),
                                          ("its local gain (--edge-gain-sd auto)", gain_sd),
                                          ("its noise (--edge-noise measured)", noise))
                 if value in ("auto", "measured")]
        measured = " and ".join([", ".join(parts[:-1]), parts[-1]] if len(parts) > 1 else parts)
        with phase(f"edge term: measuring {measured}", options.progress):
            term = edge_term(problem, labelled_pixels(problem), power, gain_sd=gain_sd, noise=noise)
        return term.power, term.gain_sd, term.noise or "constant", term
    return float(power), float(gain_sd), noise, None


def noise_and_power(observations, options):
    """``(scale, suggestion, power, normal_error)``: the options' known noise scales (None for
    constant noise), the measured power suggestion (None where too few adjacent pixels measure
    it and the power is given), the likelihood power the fit uses, and the normals' error
    record of ``--noise normals`` or ``footprint`` (else None).

    Raises
    ------
    ValueError
        If ``--likelihood-power auto`` cannot be measured (too few adjacent pixels).
    """
    normal_error = None
    if options.noise in ("normals", "footprint") or options.normals == "sample":
        with phase(f"noise model {options.noise}: estimating the normals' error (5 x 5 pixel tile fits)",
                   options.progress):
            scale, normal_error = channel_normal_error_noise(observations, footprint=options.noise == "footprint")
    if options.noise not in ("normals", "footprint"):
        scale = noise_scale(observations, options.noise, options.noise_floor)
    try:
        with phase("likelihood power: spatial correlation of per-pixel fits' residuals", options.progress):
            suggestion = power_suggestion(observations, scale)
    except ValueError:
        if options.likelihood_power == "auto":
            raise
        suggestion = None      # too few adjacent pixels to measure it
    if options.likelihood_power == "area":
        with phase("likelihood power area: residuals' autocorrelation summed within +-40 px", options.progress):
            area = area_likelihood_power(observations, noise_scale=scale)
        suggestion = {**(suggestion or {}), "area": area}
        power = area["likelihood_power"]
    else:
        power = suggestion["likelihood_power"] if options.likelihood_power == "auto" else options.likelihood_power
    # Sampled normals keep the inflation 1 + k g^2 of --noise normals (k as estimated, not 0): at the measured
    # powers (0.004 to 0.03) each normal's posterior is its prior, so the sampled normals carry none of the error
    # the inflation discounts, and dropping it split the DiLiGenT ball into 2 to 8 materials (with it kept: one,
    # as with fixed normals; docs/results/2026-11-28-normals.md, the ball's control).
    return scale, suggestion, power, normal_error


#: the smallest normal-error sd the prior of sampled normals takes (degrees): exact normals (an estimate of 0)
#: still leave the prior a positive width
MIN_NORMAL_SD_DEG = 0.25


def normal_prior_sd(options, normal_error) -> float | None:
    """The sd of each tangent coordinate's prior of ``--normals sample``: ``tan(sigma_n)``, sigma_n as given
    (``--normal-sd``) or the normals' error estimate (:mod:`rjfit.data.normal_error`) floored at
    :data:`MIN_NORMAL_SD_DEG`; None for fixed normals."""
    if options.normals != "sample":
        return None
    if options.normal_sd is not None:
        return math.tan(math.radians(options.normal_sd))
    return math.tan(math.radians(max(float(normal_error["sigma_n_deg"]), MIN_NORMAL_SD_DEG)))


def _one_channel(observations, c):
    """Channel ``c`` of a joint colour stack as a single-channel one, and the mask of its observations."""
    mine = observations.channel == c
    return dataclasses.replace(observations.subset(mine), channel=None, n_channels=1), mine


#: the share of the normals' noise estimate held by tiles the model does not describe above which the fit warns
MISFIT_TILE_SHARE_WARN = 0.5


def misfit_tile_warnings(noise_record) -> list:
    """The caveat of a normals' noise model set mostly by a few tiles across an outline (``noise_record``: the fit's
    ``noise``; its ``normal_error``'s ``misfit_tiles``, per channel in a colour fit): over
    :data:`MISFIT_TILE_SHARE_WARN` of its squared residual in them (:func:`~rjfit.data.normal_error.misfit_tiles`)."""
    error = (noise_record or {}).get("normal_error")
    if not isinstance(error, dict):
        return []
    records = error.get("channels") or [error]
    worst = max((r.get("misfit_tiles") or {"share": 0.0} for r in records), key=lambda m: m["share"])
    if worst["share"] <= MISFIT_TILE_SHARE_WARN:
        return []
    return [f"the normals' noise model is set by a few tiles: {worst['tiles']} of its {error['patch_px']} x "
            f"{error['patch_px']} px tiles (over {worst['factor']:g} times the median tile's misfit) hold "
            f"{100 * worst['share']:.0f} % of its squared residual, as tiles across a paint's outline do; its noise "
            f"scale and the edge term's settings are then the paints' as much as the surface's, and a body may split "
            f"along its shading (docs/measured-data.md)"]


def channel_normal_error_noise(observations, footprint: bool = False):
    """:func:`~rjfit.data.normal_error.normal_error_noise`; for a joint colour stack measured
    per channel: each channel's scales from its own tile fits and its own maximum-likelihood
    ``k`` (and ``t``), the record of each under ``channels``, and at the top the record of the
    channel with the largest normals' error (the one that bounds it from above).

    Why per channel: a tile fit pools a pixel's observations as one channel's, and the
    channels differ in albedo and signal, so one ``sigma_r^2`` and ``k`` for all would
    misweigh the darker channels.

    Raises
    ------
    ValueError
        As :func:`~rjfit.data.normal_error.normal_error_noise`, for any channel.
    """
    if observations.channel is None:
        return normal_error_noise(observations, footprint=footprint)
    scale = np.empty(observations.n_obs, np.float64)
    records = []
    for c in range(observations.n_channels):
        single, mine = _one_channel(observations, c)
        scale[mine], record = normal_error_noise(single, footprint=footprint)
        records.append(record)
    widest = max(records, key=lambda record: record["sigma_n_deg"])
    return scale, {**widest, "channels": records,
                   "channels_rule": "estimated per channel; the top-level figures are the channel with the largest "
                                    "normals' error"}


def power_suggestion(observations, scale):
    """:func:`~rjfit.data.coarsen.suggest_likelihood_power`; for a joint colour fit measured per channel, with
    each channel's under ``channels``: the smallest (the most misfit) divided by the design effect of the
    channels, ``1 + (C - 1) r``, r the mean correlation between channels of the per-pixel fits' residuals
    of one observation (clipped to [0, 1]).

    Why: the misfit of a pixel (a normal a few degrees off, a lobe the model lacks) is shared
    by its channels, so C channels then hold about as many independent discrepancies as one
    (r near 1: the power divided by C; psm-rock, docs/results/materials.md: the matrix split along
    shading at the channels' power, one material at a third of it), while independent noise
    per channel (r near 0) is C times the information and keeps the channels' power (Kish's
    design effect for clusters of C equally correlated observations)."""
    if observations.channel is None:
        return suggest_likelihood_power(observations, noise_scale=scale)
    per_channel, residuals = [], []
    for c in range(observations.n_channels):
        single, mine = _one_channel(observations, c)
        weighed = single if scale is None else weighted_observations(single, scale[mine])
        per_channel.append(suggest_likelihood_power(single, noise_scale=None if scale is None else scale[mine]))
        by_observation = np.full(int(np.prod(single.image_shape)) * single.n_lights, np.nan)
        by_observation[np.asarray(single.pixel, np.int64) * single.n_lights + np.asarray(single.light)] = \
            per_pixel_residuals(weighed)
        residuals.append(by_observation)
    correlation = _channel_correlation(residuals)
    most_misfit = min(per_channel, key=lambda s: s["likelihood_power"])
    suggestion = dict(most_misfit)
    design_effect = 1.0 + (observations.n_channels - 1) * min(max(correlation, 0.0), 1.0)
    suggestion["likelihood_power"] /= design_effect
    # the misfit warning reads the spatial part (channels that repeat each other are no misfit)
    suggestion.update(channels=per_channel, most_misfit_channel=most_misfit, channel_correlation=correlation,
                      channel_design_effect=design_effect,
                      rule="the smallest channel's power divided by the channels' design effect 1 + (C - 1) r, r the "
                           "residuals' mean correlation between channels")
    return suggestion


def _channel_correlation(residuals) -> float:
    """Mean Pearson correlation over channel pairs of the residuals of the observations every
    channel has (``residuals``: per channel, an array over (pixel, light), NaN where none or not
    fitted); 0 with fewer than 3 such observations."""
    shared = np.all(np.isfinite(residuals), axis=0)
    if shared.sum() < 3:
        return 0.0
    columns = [r[shared] for r in residuals]
    pairs = [np.corrcoef(columns[i], columns[j])[0, 1] for i in range(len(columns)) for j in range(i + 1, len(columns))]
    finite = [p for p in pairs if np.isfinite(p)]
    return float(np.mean(finite)) if finite else 0.0
