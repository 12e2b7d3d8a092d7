"""Every pixel fitted on its own: the per-pixel least squares the noise models and the likelihood
power start from.

Nothing ties pixels together here, so white noise leaves the residuals uncorrelated between
pixels (:mod:`rjfit.data.coarsen` measures what correlation remains) and the prediction is a
reference signal free of any segmentation (:mod:`rjfit.data.noise`).
"""
from __future__ import annotations

import numpy as np

from rjfit.model.blinn import blinn_normalisation

__all__ = ["tile_lattice", "per_pixel_residuals", "group_fit", "fit_groups", "group_params", "patch_index", "GAMMA_GRID"]

GAMMA_GRID = np.geomspace(0.5, 500.0, 16)


GOLDEN_STEPS = 24       # golden-section steps on log(exponent): the bracket shrinks by 0.618^24 ~ 1e-5


def per_pixel_residuals(observations, gammas=GAMMA_GRID, refine_steps=GOLDEN_STEPS):
    """Residuals of a separate fit of every pixel; NaN for pixels with fewer than 4 observations.

    Per pixel and exponent g: least squares of y on A = E <l.n> / pi and B = E <l.n> <h.n>^g
    (a, b unconstrained: this is a diagnostic of the family's shape). The exponent is the best
    of ``gammas``, then refined by ``refine_steps`` golden-section steps on log g between its
    grid neighbours. Why refine: the grid's steps are a factor 1.6 apart, and on a glossy
    material with little noise the misfit of the nearest grid exponent is a smooth function of
    the geometry, the same in neighbouring pixels (lag-1 correlation 0.34 on a clean rendered
    sphere with exponents 15 to 80 and noise sd 1 % of the signal, measured), which
    :mod:`rjfit.data.coarsen` would read as a misfit of the model family.
    """
    obs = observations
    n_pix = int(np.prod(obs.image_shape))
    return group_fit(obs, np.asarray(obs.pixel, np.int64), n_pix, gammas, refine_steps)["residuals"]


def patch_index(observations, patch: int) -> tuple[np.ndarray, int]:
    """Per observation, the index of its ``patch`` x ``patch`` pixel tile; and the number of tiles."""
    height, width = observations.image_shape
    tiles_across = -(-width // patch)
    pixel = np.asarray(observations.pixel, np.int64)
    tile = (pixel // width // patch) * tiles_across + (pixel % width) // patch
    return tile, int(-(-height // patch) * tiles_across)


def tile_lattice(observations, patch: int, max_observations: int | None):
    """The observations of a regular lattice of ``patch`` x ``patch`` pixel tiles, at most about ``max_observations``.

    A stack-wide estimate of a few numbers (a camera response, one gain per light) needs far
    fewer observations than a large stack holds, and its cost grows with them. Every
    ``s``-th tile in both directions is kept, ``s = ceil(sqrt(N / max_observations))``: whole
    tiles (the estimators' bootstrap resamples tiles), every light of a kept pixel (the
    lights stay balanced), spread evenly over the object with no RNG. ``s`` = 1 keeps all.

    Returns
    -------
    (Observations, dict)
        The kept observations and the record: ``lattice`` (s), ``observations_used``,
        ``observations``, ``tile_px``.
    """
    n_obs = int(observations.n_obs)
    stride = 1 if not max_observations or n_obs <= max_observations else int(np.ceil(np.sqrt(n_obs / max_observations)))
    record = {"lattice": stride, "observations": n_obs, "tile_px": int(patch)}
    if stride > 1:
        width = observations.image_shape[1]
        pixel = np.asarray(observations.pixel, np.int64)
        keep = ((pixel // width // patch) % stride == 0) & (((pixel % width) // patch) % stride == 0)
        observations = observations.subset(keep)
    record["observations_used"] = int(observations.n_obs)
    return observations, record


def group_fit(observations, group, n_groups, gammas=GAMMA_GRID, refine_steps=GOLDEN_STEPS) -> dict:
    """One Lambert + Blinn fit per group of observations (a pixel, a patch of pixels).

    Per group and exponent g: least squares of y on A = E <l.n> / pi and B = E <l.n> <h.n>^g N(g)
    (a, b unconstrained), g the best of ``gammas`` refined by golden section on log g (see
    :func:`per_pixel_residuals`). A group with fewer than 4 observations (or a singular
    system) has no fit.

    Returns
    -------
    dict
        ``a``, ``b``, ``gamma`` (per group; a, b 0 where there is no fit), ``fitted`` (per
        group, bool) and ``residuals`` (per observation, NaN where its group has no fit).
    """
    obs = observations
    C = np.asarray(obs.irradiance, float) * np.asarray(obs.cos_ln, float)
    log_hn = np.log(np.clip(np.asarray(obs.cos_hn, float), 1e-300, None))
    return fit_groups(obs.y, C, log_hn, group, n_groups, gammas, refine_steps)


def fit_groups(y, C, log_hn, group, n_groups, gammas=GAMMA_GRID, refine_steps=GOLDEN_STEPS) -> dict:
    """:func:`group_fit` on the columns themselves: ``C = E <l.n>`` and ``log <h.n>`` per observation (a
    fit's problem holds them, divided by the noise scales). A group without observations has no fit (gamma NaN).

    The fit runs over the groups present only: a per-pixel fit's groups are the image's pixels, and its
    per-group sums, dozens per fit, would otherwise cost the image's size however few observations it reads.
    """
    present, dense = np.unique(np.asarray(group, np.int64), return_inverse=True)
    fitted = _fit_present(y, C, log_hn, dense.reshape(-1), present.size, gammas, refine_steps)
    out = {"residuals": fitted["residuals"]}
    for key, empty in (("a", 0.0), ("b", 0.0), ("gamma", np.nan), ("fitted", False)):
        out[key] = np.full(n_groups, empty, dtype=fitted[key].dtype)
        out[key][present] = fitted[key]
    return out


def _fit_present(y, C, log_hn, group, n_groups, gammas, refine_steps) -> dict:
    """:func:`fit_groups` where every group 0 .. n_groups - 1 has observations."""
    y = np.asarray(y, float)
    C = np.asarray(C, float)
    log_hn = np.asarray(log_hn, float)
    A = C / np.pi
    count = np.bincount(group, minlength=n_groups)

    def sums(w):
        return np.bincount(group, weights=w, minlength=n_groups)

    s_yy, s_ya, s_aa = sums(y * y), sums(y * A), sums(A * A)

    def lobe(g_group):
        # the normalisation per group, then indexed: one exp2 per group instead of per observation
        return C * np.exp(g_group[group] * log_hn) * blinn_normalisation(g_group)[group]

    def fit(g_group):
        """(a, b, residual sum of squares) per group at the exponents ``g_group``."""
        B = lobe(g_group)
        s_yb, s_ab, s_bb = sums(y * B), sums(A * B), sums(B * B)
        det = s_aa * s_bb - s_ab * s_ab
        ok = (count >= 4) & (det > 1e-12 * np.maximum(s_aa * s_bb, 1e-300))
        safe = np.where(ok, det, 1.0)
        a = np.where(ok, (s_bb * s_ya - s_ab * s_yb) / safe, 0.0)
        b = np.where(ok, (s_aa * s_yb - s_ab * s_ya) / safe, 0.0)
        return a, b, np.where(ok, s_yy - a * s_ya - b * s_yb, np.inf)

    gammas = np.asarray(gammas, float)
    ssr_grid = np.stack([fit(np.full(n_groups, g))[2] for g in gammas])
    best_index = np.argmin(ssr_grid, axis=0)
    g = _golden_section(lambda log_g: fit(np.exp(log_g))[2],
                        np.log(gammas[np.maximum(best_index - 1, 0)]),
                        np.log(gammas[np.minimum(best_index + 1, gammas.size - 1)]), refine_steps)
    g = np.exp(g)
    a, b, ssr = fit(g)
    worse = ssr > ssr_grid[best_index, np.arange(n_groups)]      # the bracket held no better point
    g = np.where(worse, gammas[best_index], g)
    a, b, ssr = fit(g)
    residuals = y - a[group] * A - b[group] * lobe(g)
    fitted = np.isfinite(ssr)
    return {"a": a, "b": b, "gamma": g, "fitted": fitted, "residuals": np.where(fitted[group], residuals, np.nan)}


def group_params(y, C, log_hn, group, n_groups) -> np.ndarray:
    """(n_groups, 4): each group's Lambert + Blinn ``(I0, kd, gamma)`` from :func:`fit_groups` (its two amplitudes
    are ``I0 kd`` and ``I0 (1 - kd)``, unconstrained, so the prediction is the fit's even where one is negative) and
    its mean squared residual; a row of NaN for a group without a fit."""
    group = np.asarray(group, np.int64)
    fitted = fit_groups(y, C, log_hn, group, n_groups)
    I0 = fitted["a"] + fitted["b"]
    ssr = np.bincount(group, weights=np.nan_to_num(fitted["residuals"]) ** 2, minlength=n_groups)
    with np.errstate(invalid="ignore", divide="ignore"):
        rows = np.column_stack([I0, fitted["a"] / I0, fitted["gamma"], ssr / np.bincount(group, minlength=n_groups)])
    return np.where(fitted["fitted"][:, None], rows, np.nan)

def _golden_section(cost, low, high, steps):
    """Per element, the minimiser of ``cost`` (vectorised: an array of costs per array of points)
    on [low, high] by golden-section search (the middle of the last bracket)."""
    ratio = (np.sqrt(5.0) - 1.0) / 2.0
    low, high = np.array(low, float), np.array(high, float)
    left, right = high - ratio * (high - low), low + ratio * (high - low)
    cost_left, cost_right = cost(left), cost(right)
    for _ in range(steps):
        go_left = cost_left <= cost_right          # the minimum lies in [low, right]
        high = np.where(go_left, right, high)
        low = np.where(go_left, low, left)
        new_left, new_right = high - ratio * (high - low), low + ratio * (high - low)
        probe = np.where(go_left, new_left, new_right)
        cost_probe = cost(probe)
        left, right = np.where(go_left, probe, right), np.where(go_left, left, probe)
        cost_left, cost_right = (np.where(go_left, cost_probe, cost_right), np.where(go_left, cost_left, cost_probe))
    return 0.5 * (low + high)
