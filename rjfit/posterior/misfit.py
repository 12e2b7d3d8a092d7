"""What the fit's own model leaves unexplained: the spatial correlation of its residuals.

The likelihood power of ``--likelihood-power auto`` is measured before the fit, on per-pixel
Lambert + Blinn-Phong fits (:func:`rjfit.data.coarsen.suggest_likelihood_power`). After the
fit, the same lag-1 correlation measured on the residuals of the fit's own posterior mean
prediction says how much misfit the fitted model (its materials, effects and noise model)
still shares between neighbouring pixels, and the power that correlation would imply,
``((1 - rho) / (1 + rho))^2`` (Miller and Dunson's coarsening as in :mod:`rjfit.data.coarsen`).
It rises towards 1 as the model carries more of the physics.
"""
from __future__ import annotations

import numpy as np

from rjfit.data.coarsen import neighbour_correlations

__all__ = ["residual_correlation"]


def residual_correlation(problem, standardised) -> dict | None:
    """Lag-1 correlation of the standardised residuals of neighbouring pixels under one light (and channel).

    Parameters
    ----------
    problem : rjfit.sampler.forward.Problem
        The fit's problem (its ``pixel``, ``light`` and, for a joint colour fit, ``channel``).
    standardised : ndarray (N,)
        ``(y_i - E[mu_i]) / sqrt(E[sigma_i^2])`` per observation, in the problem's order.

    Returns
    -------
    dict or None
        ``rho_rows``, ``rho_cols`` (horizontal and vertical neighbours; None where not
        finite), ``rho`` (their mean, floored at 0), ``pairs`` and ``implied_power``
        (``((1 - rho) / (1 + rho))^2``); None where no two adjacent pixels share a light or
        the problem does not record its lights.
    """
    if problem.light is None or problem.n_obs == 0:
        return None
    n_lights = int(np.max(problem.light)) + 1
    n_pix = problem.height * problem.width
    channel = 0 if problem.channel is None else problem.channel.astype(np.int64)
    index = (channel * n_lights + problem.light.astype(np.int64)) * n_pix + problem.pixel.astype(np.int64)
    dense = np.full(problem.n_channels * n_lights * n_pix, np.nan)
    dense[index] = standardised
    rhos, pairs = neighbour_correlations(dense.reshape((problem.n_channels * n_lights,) + tuple(problem.image_shape)))
    if pairs == 0 or not np.any(np.isfinite(rhos)):
        return None
    rho = max(0.0, float(np.nanmean(rhos)))
    return {"rho_rows": _finite(rhos[0]), "rho_cols": _finite(rhos[1]), "rho": rho, "pairs": int(pairs),
            "implied_power": ((1.0 - rho) / (1.0 + rho)) ** 2,
            "measured_on": "standardised residuals of the posterior mean prediction, neighbours under one light"}


def _finite(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None
