"""A power-law camera response estimated from an image stack: ``raw = k * linear^(1 / kappa)``.

A folder declared ``{"response": "unknown"}`` is loaded as raw codes
(``Dataset.response == "unknown"``); :func:`estimate_power_response` estimates the exponent
kappa with which ``raw^kappa`` is linear in radiance (up to scale), for a later stage (the
fit) to apply or to sample around. The loader never applies it.

Method (a profile likelihood over kappa, Box and Cox, "An analysis of transformations",
JRSS B 26, 1964). For each kappa on a grid, the stack's values are raised to kappa and every
pixel is fitted on its own by least squares with Lambert plus one energy-normalised Blinn
lobe, the exponent on a grid (:func:`rjfit.data.pixelfit.per_pixel_residuals`). The residuals give
the negative log-likelihood of the raw values with kappa's other parameters profiled out:

``errors="linear"`` (default)
    Gaussian errors of one variance in the linearised values ``u^kappa`` (the fit's
    ``constant`` noise model once linearised), with the Jacobian of the transformation:
    ``N/2 log(SSR/N) - N log kappa - (kappa - 1) sum log u``.
``errors="codes"``
    Gaussian errors of one variance in the raw codes (quantisation, read noise after the
    response): ``N/2 log(SSR_codes/N)``, ``SSR_codes`` over ``u - max(u^kappa - r, 0)^(1/kappa)``
    (the per-pixel fit stays least squares in linearised values, so this is an approximation).

``u`` is the value divided by the stack's largest (kappa is scale-free); observations of value
0 are left out (no logarithm; a code 0 is censored, not measured). The minimum on the grid is
refined by a parabola through it and its neighbours.

Uncertainty: a block bootstrap over square tiles of pixels (``tile`` pixels a side), seeded:
the per-pixel misfit of measured data is shared by neighbouring pixels (see
:mod:`rjfit.data.coarsen`), so single pixels are not independent draws. It measures the sampling
spread over the object's surface only; on measured data the choice of error model and of
which dark observations to leave out (cast shadows) moves the estimate further than that
spread (docs/dataset-format.md states what was measured on the psm folders).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from rjfit.data.pixelfit import per_pixel_residuals, tile_lattice
from rjfit.errors import DatasetError
from rjfit.progress import tracked

__all__ = ["estimate_power_response", "KAPPA_GRID", "ERROR_MODELS"]

KAPPA_GRID = np.round(np.arange(0.4, 3.0 + 1e-9, 0.05), 4)
ERROR_MODELS = ("linear", "codes")
# what every estimate's record says of its model, method and caveat (estimate_power_response)
_ESTIMATE_TEXT = {
    "model": "raw = k * linear^(1/kappa); linear = raw^kappa up to scale",
    "method": "profile likelihood over kappa of per-pixel least-squares fits (Lambert + one Blinn lobe, "
              "rjfit.data.pixelfit.per_pixel_residuals)",
    "caveat": "the interval is the sampling spread over the surface (block bootstrap); a misfit of the "
              "Lambert + Blinn-Phong family, the normals' error and cast shadows bias kappa by more on "
              "measured data, and the error model and dark threshold move it",
}
# Fewer pixels with a per-pixel fit than this leave too few bootstrap tiles to say anything.
_MIN_PIXELS = 20


def _per_pixel_sums(observations, kappas, errors, progress=False):
    """Per kappa and pixel: the squared residuals' sum (K, P); per pixel: observations and sum of log u.

    ``progress``: count the kappas on stderr (one per-pixel fit of the stack each: minutes on a large stack).
    """
    n_pix = int(np.prod(observations.image_shape))
    u = np.asarray(observations.y, float) / float(np.max(observations.y))
    pixel = np.asarray(observations.pixel, np.int64)
    ssr = np.empty((len(kappas), n_pix))
    fitted = None
    for index in tracked(range(len(kappas)), "camera response: per-pixel fits", "kappa", enabled=progress):
        kappa = kappas[index]
        linear = u ** kappa
        residuals = per_pixel_residuals(dataclasses.replace(observations, y=linear))
        # Whether a pixel has a fit depends on its geometry only (count, determinant), not on kappa.
        fitted = np.isfinite(residuals) if fitted is None else fitted
        if errors == "linear":
            squared = residuals ** 2
        else:
            squared = (u - np.clip(linear - residuals, 0.0, None) ** (1.0 / kappa)) ** 2
        ssr[index] = np.bincount(pixel[fitted], weights=squared[fitted], minlength=n_pix)
    count = np.bincount(pixel[fitted], minlength=n_pix).astype(float)
    log_u = np.bincount(pixel[fitted], weights=np.log(u[fitted]), minlength=n_pix)
    return ssr, count, log_u


def _negative_log_likelihood(ssr, count, log_u, kappas, errors):
    """The profile's negative log-likelihood per kappa (up to a constant), from summed statistics."""
    n = float(count)
    value = 0.5 * n * np.log(ssr / n)
    if errors == "linear":
        value = value - n * np.log(kappas) - (kappas - 1.0) * log_u
    return value


def _minimum(kappas, profile):
    """The grid minimum refined by a parabola through it and its neighbours; and whether it lies on the grid's edge."""
    best = int(np.argmin(profile))
    if best == 0 or best == len(kappas) - 1:
        return float(kappas[best]), True
    x, y = kappas[best - 1:best + 2], profile[best - 1:best + 2]
    curvature = y[0] - 2.0 * y[1] + y[2]
    if curvature <= 0:
        return float(x[1]), False
    step = x[1] - x[0]
    return float(x[1] + 0.5 * step * (y[0] - y[2]) / curvature), False


def estimate_power_response(dataset, channel: str = "mean", seed: int = 0, *, errors: str = "linear",
                            dark: float | None = None, kappas=KAPPA_GRID, n_bootstrap: int = 200,
                            tile: int = 16, max_observations: int | None = None, progress: bool = False) -> dict:
    """Estimate kappa of a power-law response ``raw = k * linear^(1/kappa)`` (linear = raw^kappa up to scale).

    Parameters
    ----------
    dataset : rjfit.data.dataset.Dataset
        Usually loaded with ``response="unknown"`` (raw codes); any stack works (a linear one
        should give kappa near 1).
    channel : str
        The channel fitted (see :meth:`rjfit.data.dataset.Dataset.channel_values`).
    seed : int
        Seeds the bootstrap.
    errors : {"linear", "codes"}
        The error model of the profile likelihood (module docstring).
    dark : float or None
        Values (in the Dataset's units) at or below it are left out besides those the data
        set itself excludes (``Dataset.observations``); values of 0 are always left out.
    kappas : array_like
        The grid of kappa, increasing and evenly spaced.
    n_bootstrap : int
        Block-bootstrap replicates (0: none).
    tile : int
        Side of the bootstrap's square tiles, in pixels (1: a bootstrap over single pixels).
    max_observations : int, optional
        Estimate from a regular lattice of whole bootstrap tiles holding at most about this
        many observations (:func:`rjfit.data.pixelfit.tile_lattice`; None: every observation).
    progress : bool
        Count the per-kappa fits and the bootstrap on stderr (:func:`rjfit.progress.tracked`); same estimate.

    Returns
    -------
    dict
        ``kappa`` (the estimate), ``exponent`` (1 / kappa: the log-log slope of raw against
        linear), ``kappa_std`` and ``kappa_interval`` (standard deviation and central 95 %
        interval of the bootstrap estimates; None without a bootstrap), ``at_grid_edge``
        (the minimum lies on the grid's edge: the estimate is a bound, not a value),
        ``profile`` (``kappas`` and ``negative_log_likelihood`` relative to its minimum),
        the settings, counts and ``caveat`` (what the interval does not cover).

    Raises
    ------
    ValueError
        For an unknown ``errors``, a grid of fewer than three evenly spaced increasing values,
        ``n_bootstrap < 0`` or ``tile < 1``.
    DatasetError
        If fewer than 20 pixels have the four positive observations a per-pixel fit needs.
    """
    kappas = _checked_settings(errors, kappas, n_bootstrap, tile)
    observations = dataset.observations(channel, dark)
    observations, lattice = tile_lattice(observations.subset(np.asarray(observations.y) > 0), tile, max_observations)
    ssr, count, log_u = _per_pixel_sums(observations, kappas, errors, progress)
    used = _used_pixels(count, dataset.path)

    def estimate(weights):
        profile = _negative_log_likelihood(ssr @ weights, count @ weights, log_u @ weights, kappas, errors)
        return profile, _minimum(kappas, profile)

    profile, (kappa, at_edge) = estimate(np.ones(ssr.shape[1]))
    draws, n_tiles = _tile_bootstrap(lambda weights: estimate(weights)[1][0], used, observations.image_shape[1],
                                     tile, n_bootstrap, seed, progress)
    return {
        "kappa": kappa,
        "exponent": 1.0 / kappa,
        "kappa_std": float(draws.std(ddof=1)) if draws.size > 1 else None,
        "kappa_interval": [float(v) for v in np.percentile(draws, [2.5, 97.5])] if draws.size > 1 else None,
        "at_grid_edge": at_edge,
        **_ESTIMATE_TEXT,
        "errors": errors, "channel": channel, "dark": dark, "dataset_response": getattr(dataset, "response", None),
        "n_observations": int(count.sum()),
        "n_pixels": int(used.sum()),
        "bootstrap": {"replicates": n_bootstrap, "tile_px": tile, "tiles": n_tiles, "seed": seed},
        "subset": lattice,
        "profile": {"kappas": kappas.tolist(), "negative_log_likelihood": (profile - profile.min()).tolist()},
    }


def _used_pixels(count, path):
    """The pixels with observations (``count`` > 0). Raises DatasetError, naming ``path``, for too few of them."""
    used = count > 0
    if int(used.sum()) < _MIN_PIXELS:
        raise DatasetError(f"{path}: only {int(used.sum())} pixels have the 4 positive observations a "
                           f"per-pixel fit needs (at least {_MIN_PIXELS}): cannot estimate the camera response")
    return used


def _checked_settings(errors, kappas, n_bootstrap: int, tile: int) -> np.ndarray:
    """``kappas`` as a float array once the settings of :func:`estimate_power_response` are checked (its Raises)."""
    if errors not in ERROR_MODELS:
        raise ValueError(f"errors must be one of {ERROR_MODELS}, got {errors!r}")
    kappas = np.asarray(kappas, dtype=float)
    steps = np.diff(kappas)
    if kappas.ndim != 1 or kappas.size < 3 or kappas[0] <= 0 or not np.allclose(steps, steps[0]) or steps[0] <= 0:
        raise ValueError("kappas must be at least three positive, evenly spaced, increasing values")
    if n_bootstrap < 0 or tile < 1:
        raise ValueError(f"n_bootstrap must be >= 0 and tile >= 1, got {n_bootstrap} and {tile}")
    return kappas


def _tile_bootstrap(estimate, used, width: int, tile: int, n_bootstrap: int, seed: int, progress: bool):
    """``(estimates, tiles)``: ``estimate(weights)`` (a weight per pixel, by the image's flat index) over
    ``n_bootstrap`` block-bootstrap replicates that draw the ``tile`` x ``tile`` tiles holding the ``used``
    pixels with replacement, each pixel weighted by its tile's count; and the number of those tiles."""
    pixels = np.nonzero(used)[0]
    tiles = (pixels // width // tile) * (width // tile + 1) + (pixels % width) // tile
    _, tile_of = np.unique(tiles, return_inverse=True)
    n_tiles = int(tile_of.max()) + 1
    rng = np.random.default_rng(seed)
    draws = []
    for _ in tracked(range(n_bootstrap), "camera response: bootstrap", "replicate", enabled=progress):
        tile_weights = rng.multinomial(n_tiles, np.full(n_tiles, 1.0 / n_tiles))
        weights = np.zeros(used.shape[0])
        weights[pixels] = tile_weights[tile_of]
        draws.append(estimate(weights))
    return np.asarray(draws), n_tiles
