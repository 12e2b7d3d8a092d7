"""Data transforms of a measured stack before a fit (``--preset measured``): stated, estimated, recorded.

The material model's moves see the plain Lambert + Blinn lobe only, so what a change-point fit
samples as effects (``--effects light_calibration,camera_gamma``) is estimated here once, before
the fit, and applied to the images as a data transform. Each step's estimate and its
uncertainty go into the fit's summary (``calibration``); the fit does not sample them, so its
intervals are conditional on them.

1. **Isolated pixels.** Connected parts (4-neighbours) of the object mask smaller than
   ``min_component`` pixels (default 5) are left out. Why: the Potts prior ties a pixel's
   material to its neighbours'; a pixel with none can take a material of its own at no
   boundary cost, and on ``psm-horse`` one such pixel (of 29,488) held a material of its own
   in every chain of a fit (docs/results/measured-data.md).
2. **Camera response** (``Dataset.response == "unknown"`` only). The exponent kappa of
   ``raw = k linear^(1/kappa)`` by :func:`rjfit.data.response.estimate_power_response`
   (per-pixel fits, block bootstrap over 16-pixel tiles), then every image becomes
   ``(raw / raw_max)^kappa`` (all channels, one kappa).
3. **Per-light gains** (uncalibrated intensities: the response is unknown, or
   ``gains=True``). With every 5 x 5 pixel tile fitted by one Lambert + Blinn lobe
   (:func:`rjfit.data.pixelfit.group_fit`, which shares a tile's amplitudes over all lights so
   it cannot absorb a light's gain), the gain of light l is the least-squares ratio
   ``G_l = sum y m / sum m^2`` of its observations to the tiles' predictions; the images are
   divided by G_l and the step repeated (over-relaxed, until it changes a gain by under
   0.01 %); the gains are normalised to geometric mean 1 (the overall scale is I0's).
   Steps 2 and 3 read at most about ``CALIBRATION_OBSERVATIONS`` observations, whole tiles on a
   regular lattice (:func:`rjfit.data.pixelfit.tile_lattice`): their cost no longer grows with the stack.
   Uncertainty: the spread of the last step's ratio over a bootstrap of the tiles
   (``n_bootstrap``, seeded), the tile fits held fixed: it leaves out the fits' own spread.

4. **The silhouette and cast shadows** (:mod:`rjfit.data.shadows`): the mask's outline pixels
   (partly background) lose every observation; an observation under a third of its pixel's own
   Lambertian prediction (albedo: the median over its well-lit lights) is left out as occluded
   (``visibility``); the counts are recorded.

A joint colour fit (``channel`` 'rgb') estimates the response and the gains on the channel mean: both are
one per camera and per light, shared by every channel, and the mean is what a one-channel fit estimates them
on (the same transform for both fits of a stack, from a third of the observations). Estimated on R, G and B
jointly, psm-cat's kappa fell to the grid's lower bound 0.5 (the mean: 1.00) and took 2.7 min with the gains
another 2.7 (docs/results/2026-11-28-colour.md).

Saturated observations are flagged before any transform (``Dataset.saturated``), so the
transforms do not move the clipping threshold. The quantisation floor (``quantisation_variance``)
no longer applies to transformed values and is dropped (its size is recorded: on psm it is
1/36 code^2 for the channel mean against residual variances of 85 to 150 code^2).
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy import ndimage

from rjfit.data.formats import COLOUR
from rjfit.data.pixelfit import group_fit, patch_index, tile_lattice
from rjfit.data.shadows import flag_cast_shadows, flag_silhouette
from rjfit.data.response import estimate_power_response
from rjfit.progress import phase, tracked
from rjfit.progress import progress as progress_bar

__all__ = ["calibrate_measured", "drop_small_components", "small_components", "estimate_light_gains",
           "replay_calibration", "MIN_COMPONENT", "CALIBRATION_OBSERVATIONS"]

MIN_COMPONENT = 5
# Alternating tile fits and gains converges slowly where a tile's lobe can take up part of a
# light's gain (the error shrank by about 0.93 a round on paper_sphere): over-relaxed steps
# (change^1.8), until the largest step is below 1e-4 or 60 rounds.
_GAIN_ROUNDS = 60
_GAIN_TOLERANCE = 1e-4
# kappa 0.5 to 2.5 (the estimator's grid is 0.4 to 3.0): a third fewer tile-fit passes; an estimate on
# the edge is flagged (at_grid_edge)
_KAPPAS = np.round(np.arange(0.5, 2.5 + 1e-9, 0.05), 4)
_OVER_RELAXATION = 1.8
# The response and the gains are a few numbers of the whole stack; each tile-fit pass costs time in proportion to
# the observations (a 2048 x 2048 stack holds 40 million), so they are estimated on a regular lattice of tiles
# holding at most about this many (every one on psm-horse and psm-cat; a quarter on the 96-light DiLiGenT ball).
# Their bootstrap intervals are those of the lattice's observations.
CALIBRATION_OBSERVATIONS = 500_000
_TILE = 5


def small_components(object_mask, min_component: int = MIN_COMPONENT) -> np.ndarray:
    """The pixels of the mask's connected parts (4-neighbours) under ``min_component`` pixels: what
    :func:`drop_small_components` leaves out."""
    return _small_components(object_mask, min_component)[0]


def _small_components(object_mask, min_component: int):
    labels, n = ndimage.label(object_mask)
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    small = np.flatnonzero(sizes < min_component)
    small = small[small > 0]
    return np.isin(labels, small), int(small.size)


def drop_small_components(dataset, min_component: int = MIN_COMPONENT):
    """The data set with the object mask's connected parts under ``min_component`` pixels left out.

    Returns
    -------
    (Dataset, dict)
        The data set and a record: ``pixels_dropped``, ``components_dropped``, ``min_component``.
    """
    drop, n_small = _small_components(dataset.object_mask, min_component)
    record = {"min_component": min_component, "components_dropped": n_small, "pixels_dropped": int(drop.sum())}
    if not drop.any():
        return dataset, record
    return dataclasses.replace(dataset, object_mask=dataset.object_mask & ~drop), record


def estimate_light_gains(dataset, channel: str = "mean", seed: int = 0, n_bootstrap: int = 50,
                         max_observations: int | None = None, progress: bool = False) -> dict:
    """Per-light gains ``G_l`` from 5 x 5 pixel tile fits (module docstring, step 3).

    ``max_observations``: estimate from a regular lattice of whole tiles holding at most about this many
    observations (:func:`rjfit.data.pixelfit.tile_lattice`; None: every observation). ``progress``: a line per
    round of tile fits (at most every few seconds) and the bootstrap counted on stderr.

    Returns
    -------
    dict
        ``gains`` (L,), ``gains_std`` (L,; block bootstrap over tiles), ``rounds``, ``bootstrap``.
    """
    observations, lattice = tile_lattice(dataset.observations(channel), _TILE, max_observations)
    tile, n_tiles = patch_index(observations, _TILE)
    light = np.asarray(observations.light, np.int64)
    y0 = np.asarray(observations.y, float)

    def ratio(y, prediction, weights):
        keep = np.isfinite(prediction)
        m, w = prediction[keep], weights[tile[keep]]
        return (np.bincount(light[keep], weights=w * y[keep] * m, minlength=dataset.n_lights)
                / np.bincount(light[keep], weights=w * m * m, minlength=dataset.n_lights))

    total, rounds, step = np.ones(dataset.n_lights), 0, np.inf
    # the rounds stop at a tolerance, so their count is a bound: the bar counts up to it and closes early
    bar = progress_bar(_GAIN_ROUNDS, "light gains: tile fits", "round") if progress else None
    while rounds < _GAIN_ROUNDS and step > _GAIN_TOLERANCE:
        y = y0 / total[light]
        prediction = y - group_fit(dataclasses.replace(observations, y=y), tile, n_tiles)["residuals"]
        change = ratio(y, prediction, np.ones(n_tiles)) ** _OVER_RELAXATION
        total = total * change / np.exp(np.mean(np.log(total * change)))
        step, rounds = float(np.max(np.abs(np.log(change)))), rounds + 1
        if bar is not None:
            bar.update(1, detail=f"largest step {step:.2g} (stops below {_GAIN_TOLERANCE:g})")
    if bar is not None:
        bar.close()
    y = y0 / total[light]
    prediction = y - group_fit(dataclasses.replace(observations, y=y), tile, n_tiles)["residuals"]
    rng = np.random.default_rng(seed)
    draws = []
    for _ in tracked(range(n_bootstrap), "light gains: bootstrap", "replicate", enabled=progress):
        resampled = total * ratio(y, prediction, rng.multinomial(n_tiles, np.full(n_tiles, 1.0 / n_tiles)).astype(float))
        draws.append(resampled / np.exp(np.mean(np.log(resampled))))
    draws = np.asarray(draws)
    return {"gains": total.tolist(), "gains_std": draws.std(axis=0, ddof=1).tolist() if n_bootstrap > 1 else None,
            "rounds": rounds, "last_step": step, "tile_px": _TILE, "subset": lattice,
            "bootstrap": {"replicates": n_bootstrap, "over": f"{_TILE} x {_TILE} pixel tiles, the tile fits held fixed "
                                                             "(the spread of the last ratio step only)", "seed": seed}}


def _flag_saturated(dataset):
    """``Dataset.saturated`` with the threshold applied now, so that scaling the images keeps it."""
    if dataset.saturation is None:
        return dataset
    clipped = (dataset.images >= dataset.saturation).any(axis=-1)
    if dataset.saturated is not None:
        clipped |= dataset.saturated
    return dataclasses.replace(dataset, saturated=clipped, saturation=None)


def calibrate_measured(dataset, channel: str = "mean", seed: int = 0, *, gains: bool | None = None,
                       min_component: int = MIN_COMPONENT, progress: bool = False):
    """The transforms of the module docstring, in order; the transformed data set and their record.

    Parameters
    ----------
    dataset : rjfit.data.dataset.Dataset
    channel : str
        The fit's channel: the estimates are made on it, on the mean for a joint colour fit ('rgb': module
        docstring).
    seed : int
        Seeds the bootstraps.
    gains : bool or None
        Estimate per-light gains; None: only when the response is unknown (uncalibrated stacks).
    min_component : int
        Smallest connected part of the object mask kept, in pixels.
    progress : bool
        Announce each step on stderr and count its passes (:mod:`rjfit.progress`): on a large
        8-bit stack the calibration takes minutes. The result is the same either way.

    Returns
    -------
    (Dataset, dict)

    Raises
    ------
    DatasetError
        If the response must be estimated and too few pixels have a per-pixel fit.
    """
    dataset, isolated = drop_small_components(dataset, min_component)
    record = {"isolated_pixels": isolated, "response": None, "light_gains": None,
              "note": "estimated once before the fit and applied to the images; the fit's intervals are conditional "
                      "on these estimates"}
    unknown = dataset.response == "unknown"
    estimated_on = "mean" if channel == COLOUR else channel       # one response and one gain per light, every channel
    if unknown:
        dataset = _flag_saturated(dataset)
        with phase("calibration: camera response (kappa of raw = k linear^(1/kappa))", progress):
            response = estimate_power_response(dataset, estimated_on, seed, kappas=_KAPPAS,
                                               max_observations=CALIBRATION_OBSERVATIONS, progress=progress)
        dataset = _linearise(dataset, response["kappa"])
        record["response"] = {**{key: response[key] for key in ("kappa", "exponent", "kappa_std", "kappa_interval",
                                                                "at_grid_edge", "model", "errors", "caveat", "subset")},
                              "channel": estimated_on}
        record["quantisation_dropped"] = ("the raw codes' quantisation floor (1/12 code^2 per channel) does not apply "
                                          "to the linearised values and is not used")
    if gains or (gains is None and unknown):
        dataset = _flag_saturated(dataset)
        with phase("calibration: per-light gains", progress):
            estimate = estimate_light_gains(dataset, estimated_on, seed, max_observations=CALIBRATION_OBSERVATIONS,
                                            progress=progress)
        dataset = _divide_by_gains(dataset, estimate["gains"])
        record["light_gains"] = estimate
    dataset, record["silhouette"] = flag_silhouette(dataset)
    with phase("calibration: cast shadows", progress):
        dataset, shadows = flag_cast_shadows(dataset, channel)
    record["cast_shadows"] = {**shadows, "channel": channel}
    return dataset, record


def replay_calibration(dataset, record: dict, source="the fit's summary.json"):
    """Apply a recorded calibration (``summary.json["calibration"]``) to the data set it was estimated on.

    Later commands on a fit made under ``--preset measured`` (``rjfit diagnose``, ``refine``)
    must see the data the fit saw: the same pixels left out, the same response exponent and
    light gains, taken from the record rather than estimated again.

    Parameters
    ----------
    dataset : rjfit.data.dataset.Dataset
        The data set as loaded (before any transform).
    record : dict
        What :func:`calibrate_measured` returned with the transformed data set.
    source : str
        Where the record was read, for the error message.

    Returns
    -------
    Dataset

    Raises
    ------
    ValueError
        If the record does not fit the data set (another number of lights, a response
        recorded for a data set whose response is known, isolated pixels that differ).
    """
    isolated = record.get("isolated_pixels") or {}
    dataset, dropped = drop_small_components(dataset, int(isolated.get("min_component", MIN_COMPONENT)))
    if isolated and dropped["pixels_dropped"] != isolated.get("pixels_dropped"):
        raise ValueError(f"{source}: its calibration left out {isolated.get('pixels_dropped')} isolated pixels, this "
                         f"data set has {dropped['pixels_dropped']}: not the data set the fit was made from")
    if record.get("response"):
        if dataset.response != "unknown":
            raise ValueError(f"{source}: its calibration estimated a camera response, but this data set declares "
                             f"its response ({dataset.response!r}): not the data set the fit was made from")
        dataset = _linearise(_flag_saturated(dataset), record["response"]["kappa"])
    if record.get("light_gains"):
        gains = record["light_gains"]["gains"]
        if len(gains) != dataset.n_lights:
            raise ValueError(f"{source}: its calibration has gains for {len(gains)} lights, this data set has "
                             f"{dataset.n_lights}: not the data set the fit was made from")
        dataset = _divide_by_gains(_flag_saturated(dataset), gains)
    if record.get("silhouette"):
        dataset, _ = flag_silhouette(dataset)
    if record.get("cast_shadows"):
        dataset, shadows = flag_cast_shadows(dataset, record["cast_shadows"].get("channel", "mean"))
        if shadows["observations_flagged"] != record["cast_shadows"]["observations_flagged"]:
            raise ValueError(f"{source}: its calibration left out {record['cast_shadows']['observations_flagged']} "
                             f"observations as cast shadows, this data set has {shadows['observations_flagged']}: not "
                             "the data set the fit was made from")
    return dataset


def _linearise(dataset, kappa: float):
    """``(raw / raw_max)^kappa`` for every image and channel (step 2); the values are linear after it."""
    images = (np.asarray(dataset.images, float) / float(np.max(dataset.images))) ** float(kappa)
    return dataclasses.replace(dataset, images=images, response="linear", quantisation_variance=None,
                               meta={**dataset.meta, "response_estimated": float(kappa)})


def _divide_by_gains(dataset, gains):
    """Each light's image divided by its gain (step 3)."""
    scale = np.asarray(gains, float)[:, None, None, None]
    return dataclasses.replace(dataset, images=np.asarray(dataset.images, float) / scale)
