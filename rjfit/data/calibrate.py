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
   With ``field_degree`` d >= 1 (``--light-field``), each light's gain is instead a field over
   the image, the exponential of a degree-d polynomial (:mod:`rjfit.data.light_field`), its
   coefficients moved by unrelaxed Gauss-Newton steps on the same ratio; the fields' geometric
   mean over the lights is 1 at every pixel.

3b. **The lights' common field** (with ``field_degree`` >= 1): what the per-light fields cannot
   see, a change of every light's irradiance alike over the image (lights above the object
   light its bottom less), is read from the pixels' Lambertian albedo: a robust (biweight)
   fit of the log albedo on the same polynomial, its mean over the object 0, divided out. This
   assumes the object's most common material is one albedo; other materials are the fit's
   outliers. On the three psm stacks the albedo fell by 20 to 30 % from the top of each object
   to its bottom, and psm-cat's head and body differed by 12 % before it and 1 % after
   (docs/results/2026-11-29-light-field.md).

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
from rjfit.data.light_field import field_basis, field_image, monomials, robust_polynomial
from rjfit.data.pixelfit import group_fit, patch_index, tile_lattice
from rjfit.data.shadows import SHADOW_FRACTION, flag_cast_shadows, flag_silhouette, lambertian_albedo
from rjfit.data.response import estimate_power_response
from rjfit.progress import phase, tracked
from rjfit.progress import progress as progress_bar

__all__ = ["calibrate_measured", "drop_small_components", "small_components", "estimate_light_gains",
           "estimate_common_field", "replay_calibration", "calibration_warnings", "MIN_COMPONENT",
           "CALIBRATION_OBSERVATIONS", "LIGHT_FIELD_DEGREE"]

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
#: the light field's degree under --preset measured (rjfit.pipeline.resolve)
LIGHT_FIELD_DEGREE = 2


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
                         max_observations: int | None = None, progress: bool = False, field_degree: int = 0) -> dict:
    """Per-light gains ``G_l`` from 5 x 5 pixel tile fits (module docstring, step 3), or each light's gain field.

    ``max_observations``: estimate from a regular lattice of whole tiles holding at most about this many
    observations (:func:`rjfit.data.pixelfit.tile_lattice`; None: every observation). ``progress``: a line per
    round of tile fits (at most every few seconds) and the bootstrap counted on stderr. ``field_degree``: each
    light's gain is the exponential of a polynomial of this degree over the image (:mod:`rjfit.data.light_field`);
    0: one gain per light. Each round is a Gauss-Newton step on the log gains' (or fields') coefficients.

    Returns
    -------
    dict
        ``gains`` (L,; with a field, its geometric mean over the object's pixels), ``gains_std`` (L,; block
        bootstrap over tiles), ``rounds``, ``last_step`` (the largest change of a log gain in the last round, over
        the object), ``bootstrap``; with a field (degree >= 1) also ``field``: ``degree``, ``terms``,
        ``coefficients`` (L lists), ``coefficients_std``, and ``range`` (each light's smallest and largest gain over
        the object, relative to its geometric mean there).
    """
    observations, lattice = tile_lattice(dataset.observations(channel), _TILE, max_observations)
    tile, n_tiles = patch_index(observations, _TILE)
    light = np.asarray(observations.light, np.int64)
    y0 = np.asarray(observations.y, float)
    basis = field_basis(observations.pixel, observations.image_shape, field_degree)
    object_basis = field_basis(np.flatnonzero(dataset.object_mask), observations.image_shape, field_degree)
    n_lights, n_terms = dataset.n_lights, basis.shape[1]

    def step(y, prediction, weights):
        # a cast shadow (step 4's rule) would pull its place's field down: left out of a field's steps
        keep = np.isfinite(prediction) & ((y > SHADOW_FRACTION * prediction) if field_degree else True)
        return _gauss_newton_step(y[keep], prediction[keep], weights[tile[keep]], light[keep], basis[keep], n_lights)

    # one gain per light converges slowly without over-relaxation (module constants); a field's Gauss-Newton steps
    # converge unrelaxed (psm-horse: to 1e-4 in about 20 rounds) and over-relaxed overshoot (not in 60)
    relaxation = _OVER_RELAXATION if field_degree == 0 else 1.0
    coefficients, rounds, largest = np.zeros((n_lights, n_terms)), 0, np.inf
    # the rounds stop at a tolerance, so their count is a bound: the bar counts up to it and closes early
    bar = progress_bar(_GAIN_ROUNDS, "light gains: tile fits", "round") if progress else None
    while rounds < _GAIN_ROUNDS and largest > _GAIN_TOLERANCE:
        y = y0 / np.exp(np.sum(coefficients[light] * basis, axis=1))
        prediction = y - group_fit(dataclasses.replace(observations, y=y), tile, n_tiles)["residuals"]
        # a change common to every light is the albedo's (the shadows left out raise every light's ratio alike)
        change = _normalised(relaxation * step(y, prediction, np.ones(n_tiles)))
        coefficients = _normalised(coefficients + change)
        largest, rounds = float(np.max(np.abs(change @ object_basis.T))), rounds + 1
        if bar is not None:
            bar.update(1, detail=f"largest step {largest:.2g} (stops below {_GAIN_TOLERANCE:g})")
    if bar is not None:
        bar.close()
    y = y0 / np.exp(np.sum(coefficients[light] * basis, axis=1))
    prediction = y - group_fit(dataclasses.replace(observations, y=y), tile, n_tiles)["residuals"]
    rng = np.random.default_rng(seed)
    draws = []
    for _ in tracked(range(n_bootstrap), "light gains: bootstrap", "replicate", enabled=progress):
        weights = rng.multinomial(n_tiles, np.full(n_tiles, 1.0 / n_tiles)).astype(float)
        draws.append(_normalised(coefficients + step(y, prediction, weights)))
    draws = np.asarray(draws)
    centre = object_basis.mean(axis=0)            # a light's mean log gain over the object's pixels
    record = {"gains": np.exp(coefficients @ centre).tolist(),
              "gains_std": np.exp(draws @ centre).std(axis=0, ddof=1).tolist() if n_bootstrap > 1 else None,
              "rounds": rounds, "last_step": largest, "tile_px": _TILE, "subset": lattice,
              "bootstrap": {"replicates": n_bootstrap, "seed": seed,
                            "over": f"{_TILE} x {_TILE} pixel tiles, the tile fits held fixed (the spread of the last "
                                    "step only)"}}
    if field_degree:
        relative = coefficients @ (object_basis - centre).T
        record["field"] = {"degree": int(field_degree), "terms": [f"u^{a} v^{b}" for a, b in monomials(field_degree)],
                           "image_shape": list(observations.image_shape),
                           "coefficients": coefficients.tolist(),
                           "coefficients_std": draws.std(axis=0, ddof=1).tolist() if n_bootstrap > 1 else None,
                           "range": np.exp(np.stack([relative.min(axis=1), relative.max(axis=1)], axis=1)).tolist()}
    return record


def _gauss_newton_step(y, prediction, weights, light, basis, n_lights: int) -> np.ndarray:
    """Per light, the Gauss-Newton step of a log field's coefficients (L, n_terms): ``y ~ prediction exp(step . phi)``
    in weighted least squares, ``basis`` the observations' phi."""
    n_terms = basis.shape[1]
    normal = np.empty((n_lights, n_terms, n_terms))
    for i in range(n_terms):
        for j in range(i + 1):
            products = weights * prediction ** 2 * basis[:, i] * basis[:, j]
            normal[:, i, j] = normal[:, j, i] = np.bincount(light, products, n_lights)
    gradient = np.stack([np.bincount(light, weights * prediction * (y - prediction) * basis[:, i], n_lights)
                         for i in range(n_terms)], axis=1)
    return np.linalg.solve(normal, gradient[..., None])[..., 0]


def _normalised(coefficients):
    """Coefficients whose sum over the lights is 0: a field common to every light is the albedo's (or I0's)."""
    return coefficients - coefficients.mean(axis=0)


def _flag_saturated(dataset):
    """``Dataset.saturated`` with the threshold applied now, so that scaling the images keeps it."""
    if dataset.saturation is None:
        return dataset
    clipped = (dataset.images >= dataset.saturation).any(axis=-1)
    if dataset.saturated is not None:
        clipped |= dataset.saturated
    return dataclasses.replace(dataset, saturated=clipped, saturation=None)


def calibrate_measured(dataset, channel: str = "mean", seed: int = 0, *, gains: bool | None = None,
                       min_component: int = MIN_COMPONENT, progress: bool = False, field_degree: int = 0):
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
    field_degree : int
        With the gains, each light's gain a field over the image, the exponential of a polynomial of this
        degree (:mod:`rjfit.data.light_field`); 0: one gain per light.
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
                                            progress=progress, field_degree=field_degree)
        dataset = _divide_by_gains(dataset, estimate)
        record["light_gains"] = estimate
        if field_degree:
            with phase("calibration: the lights' common field", progress):
                record["common_field"] = estimate_common_field(dataset, estimated_on, field_degree)
            dataset = _divide_by_common_field(dataset, record["common_field"])
    dataset, record["silhouette"] = flag_silhouette(dataset)
    with phase("calibration: cast shadows", progress):
        dataset, shadows = flag_cast_shadows(dataset, channel)
    record["cast_shadows"] = {**shadows, "channel": channel}
    return dataset, record


def estimate_common_field(dataset, channel: str = "mean", degree: int = LIGHT_FIELD_DEGREE) -> dict:
    """The lights' common field (module docstring, step 3b): the exponential of a polynomial of ``degree`` over the
    image, fitted robustly to the pixels' Lambertian albedo (:func:`rjfit.data.shadows.lambertian_albedo`), its
    mean log over the object's pixels 0.

    Returns
    -------
    dict
        ``degree``, ``terms``, ``coefficients`` (n_terms), ``image_shape``, ``range`` (smallest and largest over the
        object), ``inlier_share`` (the pixels with a non-zero weight), ``scale`` (the log albedo's robust sd about
        the field), ``rule``, ``caveat``.
    """
    pixels, albedo = lambertian_albedo(dataset, channel)
    judged = np.isfinite(albedo) & (albedo > 0)
    coefficients, weights, scale = robust_polynomial(np.log(albedo[judged]),
                                                     field_basis(pixels[judged], dataset.image_shape, degree))
    inside = field_basis(np.flatnonzero(dataset.object_mask), dataset.image_shape, degree)
    coefficients[0] -= float(np.mean(inside @ coefficients))
    log_field = inside @ coefficients
    return {"degree": int(degree), "terms": [f"u^{a} v^{b}" for a, b in monomials(degree)],
            "coefficients": coefficients.tolist(), "image_shape": list(dataset.image_shape),
            "range": [float(np.exp(log_field.min())), float(np.exp(log_field.max()))],
            "inlier_share": float(np.mean(weights > 0)), "scale": scale,
            "rule": "Tukey's biweight fit, started from Huber's, of the pixels' log Lambertian albedo (the median of y / (E <l.n>) over "
                    "lights with <l.n> > 0.3) on the polynomial",
            "caveat": "reads a smooth change of the object's most common albedo over the image as illumination"}


def calibration_warnings(record: dict | None) -> tuple[str, ...]:
    """What a calibration record (:func:`calibrate_measured`) must say beside the fit's figures: gains or a light
    field whose alternating rounds stopped at their limit before their steps fell below the tolerance."""
    gains = (record or {}).get("light_gains")
    if not gains or gains.get("last_step", 0.0) <= _GAIN_TOLERANCE:
        return ()
    what = "light field" if gains.get("field") else "per-light gains"
    return (f"the {what} estimate had not settled after {gains['rounds']} rounds of tile fits: the last changed a "
            f"light's gain by up to {100 * gains['last_step']:.2g} % (the tile fits' lobes trade with the gains); "
            f"the fit is conditional on these values",)


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
        field = record["light_gains"].get("field")
        if field and tuple(field["image_shape"]) != tuple(dataset.images.shape[1:3]):
            raise ValueError(f"{source}: its light field was estimated on {field['image_shape'][1]} x "
                             f"{field['image_shape'][0]} images, this data set's are {dataset.images.shape[2]} x "
                             f"{dataset.images.shape[1]}: not the data set the fit was made from")
        dataset = _divide_by_gains(_flag_saturated(dataset), record["light_gains"])
    if record.get("common_field"):
        dataset = _divide_by_common_field(dataset, record["common_field"])
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


def _divide_by_gains(dataset, estimate: dict):
    """Each light's image divided by its gain, or by its gain field where ``estimate`` holds one (step 3)."""
    field = estimate.get("field")
    if field:
        scale = field_image(field["coefficients"], dataset.images.shape[1:3], field["degree"])[..., None]
    else:
        scale = np.asarray(estimate["gains"], float)[:, None, None, None]
    return dataclasses.replace(dataset, images=np.asarray(dataset.images, float) / scale)


def _divide_by_common_field(dataset, field: dict):
    """Every image divided by the lights' common field (step 3b)."""
    scale = field_image([field["coefficients"]], dataset.images.shape[1:3], field["degree"])[0][None, :, :, None]
    return dataclasses.replace(dataset, images=np.asarray(dataset.images, float) / scale)
