"""Every pixel fitted on its own: the per-pixel least squares the noise models and the likelihood
power start from.

Nothing ties pixels together here, so white noise leaves the residuals uncorrelated between
pixels (:mod:`rjfit.data.coarsen` measures what correlation remains) and the prediction is a
reference signal free of any segmentation (:mod:`rjfit.data.noise`).
"""
from __future__ import annotations

import numpy as np

from rjfit.model.blinn import blinn_normalisation

__all__ = ["per_pixel_residuals", "GAMMA_GRID"]

GAMMA_GRID = np.geomspace(0.5, 500.0, 16)


def per_pixel_residuals(observations, gammas=GAMMA_GRID):
    """Residuals of a separate fit of every pixel; NaN for pixels with fewer than 4 observations.

    Per pixel and exponent g of ``gammas``: least squares of y on A = E <l.n> / pi and
    B = E <l.n> <h.n>^g (a, b unconstrained: this is a diagnostic of the family's shape),
    keeping the exponent with the smallest residual sum of squares.
    """
    obs = observations
    pixel = np.asarray(obs.pixel, np.int64)
    n_pix = int(np.prod(obs.image_shape))
    y = np.asarray(obs.y, float)
    C = np.asarray(obs.irradiance, float) * np.asarray(obs.cos_ln, float)
    A = C / np.pi
    log_hn = np.log(np.clip(np.asarray(obs.cos_hn, float), 1e-300, None))
    count = np.bincount(pixel, minlength=n_pix)

    def sums(w):
        return np.bincount(pixel, weights=w, minlength=n_pix)

    s_yy, s_ya, s_aa = sums(y * y), sums(y * A), sums(A * A)
    best_ssr = np.full(n_pix, np.inf)
    best = (np.zeros(n_pix), np.zeros(n_pix), np.zeros(n_pix))
    for g in gammas:
        B = C * np.exp(g * log_hn) * blinn_normalisation(g)
        s_yb, s_ab, s_bb = sums(y * B), sums(A * B), sums(B * B)
        det = s_aa * s_bb - s_ab * s_ab
        ok = (count >= 4) & (det > 1e-12 * np.maximum(s_aa * s_bb, 1e-300))
        safe = np.where(ok, det, 1.0)
        a = np.where(ok, (s_bb * s_ya - s_ab * s_yb) / safe, 0.0)
        b = np.where(ok, (s_aa * s_yb - s_ab * s_ya) / safe, 0.0)
        ssr = np.where(ok, s_yy - a * s_ya - b * s_yb, np.inf)
        better = ssr < best_ssr
        best_ssr = np.where(better, ssr, best_ssr)
        best = tuple(np.where(better, new, old) for new, old in zip((a, b, np.full(n_pix, g)), best))
    a, b, g = (v[pixel] for v in best)
    residuals = y - a * A - b * C * np.exp(g * log_hn) * blinn_normalisation(g)
    return np.where(np.isfinite(best_ssr[pixel]), residuals, np.nan)
