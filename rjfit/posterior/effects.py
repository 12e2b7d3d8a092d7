"""The posterior of the effects a fit sampled with the regions (issue 26): summaries and the mean prediction.

A chain's record holds each draw's effect parameters, constrained (``ChainRecord.effects``,
columns named by :attr:`rjfit.sampler.forward.EffectData.names`). :func:`effect_summaries`
gives, per effect, each parameter's posterior mean, sd, 95 % interval, R-hat and ESS (and,
for per-light gains, each light's gain); :func:`effects_prediction` is the posterior mean
prediction of a fit with effects, draw by draw on the problem transformed at that draw's
parameters.
"""
from __future__ import annotations

import numpy as np

from rjfit.posterior.misfit import residual_correlation
from rjfit.sampler.forward import transformed
from rjfit.sampler.likelihood import ab_from_theta, lobe_column

__all__ = ["effect_draws", "effect_summaries", "effects_prediction"]


def effect_draws(records, burn_in: int) -> np.ndarray:
    """Kept draws of the effect parameters, (chains, draws, K) (constrained)."""
    T = min(len(r.effects) for r in records)
    return np.stack([r.effects[burn_in:T] for r in records])


def _stats(draws) -> dict:
    """Mean, sd, 2.5 % and 97.5 % quantiles over all draws, R-hat and bulk ESS over chains (draws: chains x draws)."""
    import arviz as az

    flat = draws.ravel()
    out = {"mean": float(np.mean(flat)), "sd": float(np.std(flat, ddof=1)) if flat.size > 1 else 0.0,
           "q2.5": float(np.quantile(flat, 0.025)), "q97.5": float(np.quantile(flat, 0.975))}
    rhat = float(az.rhat(draws)) if draws.shape[0] > 1 and draws.shape[1] > 3 else None
    out["rhat"] = rhat if rhat is not None and np.isfinite(rhat) else None
    ess = float(az.ess(draws, method="bulk")) if draws.shape[1] > 3 else None
    out["ess_bulk"] = ess if ess is not None and np.isfinite(ess) else None
    return out


def effect_summaries(records, burn_in: int, effect_data, source: dict | None = None) -> list:
    """Per effect: its name, stage and each parameter's prior and posterior (mean, sd, 95 % interval, R-hat, ESS).

    Per-light gains (``light_calibration``) also get ``light_gains``: each light's gain
    ``exp(H h)`` summarised the same way. ``source`` (effect name -> dict) adds where an
    effect's features came from.
    """
    draws = effect_draws(records, burn_in)
    out = []
    for effect, block in zip(effect_data.effects, effect_data.blocks()):
        entry = {"name": effect.name, "stage": effect.stage, "parameters": []}
        for k, param in enumerate(effect.params):
            entry["parameters"].append({"name": param.name, "prior": param.prior.describe(), "init": param.init,
                                        **_stats(draws[:, :, block.start + k])})
        if hasattr(effect, "gains"):
            gains = np.apply_along_axis(effect.gains, -1, draws[:, :, block])
            entry["light_gains"] = [_stats(gains[:, :, light]) for light in range(gains.shape[-1])]
        if source and effect.name in source:
            entry["source"] = source[effect.name]
        out.append(entry)
    return out


def effects_prediction(records, burn_in: int, problem, picks_of) -> dict:
    """The posterior mean prediction of a fit with effects (what
    :func:`rjfit.posterior.summary.posterior_mean_prediction` returns; see there).

    Each picked draw's problem is the base problem transformed at that draw's effect
    parameters. ``radiance`` and ``abs_error`` are on the data's scale (the draw's mean
    through its camera response, plus its known offsets); ``residual_rms`` on the fit's
    linearised scale (``(y' - mu') / sigma`` of the transformed problem, averaged over draws
    before squaring). ``picks_of(records)`` gives the ``(record, snapshot)`` pairs to average
    and their labels per observation.
    """
    data = problem.effects
    picks = picks_of(records)
    n = problem.n_obs
    resid_sum, mean_sum, sigma2_sum = np.zeros(n), np.zeros(n), np.zeros(n)
    for rec, t, labels in picks:
        z = np.array([float(prior.to_unconstrained(v)) for prior, v in zip(data.priors(), rec.effects[t])])
        draw_problem, _ = transformed(problem, z)
        R = int(labels.max()) + 1
        theta = rec.theta[t, :R]
        a, b = ab_from_theta(theta)
        mu = (a[labels] * draw_problem.C.astype(np.float64) / np.pi
              + b[labels] * lobe_column(draw_problem, slice(None), theta[labels, 2]))
        resid_sum += draw_problem.y.astype(np.float64) - mu
        scale = 1.0 if data.scale is None else data.scale
        mean_sum += data.columns(z).data_scale(mu * scale)
        sigma2_sum += theta[labels, 3]
    resid, mean, sigma2 = resid_sum / len(picks), mean_sum / len(picks), sigma2_sum / len(picks)
    n_pix = problem.height * problem.width
    count = np.bincount(problem.pixel, minlength=n_pix).astype(float)

    def per_pixel(values):
        with np.errstate(invalid="ignore", divide="ignore"):
            return (np.bincount(problem.pixel, weights=values, minlength=n_pix) / count).reshape(problem.image_shape)

    return {"radiance": per_pixel(mean), "observed": per_pixel(data.y), "abs_error": per_pixel(np.abs(data.y - mean)),
            "residual_rms": np.sqrt(per_pixel(resid ** 2 / sigma2)), "draws": int(len(picks)),
            "residual_correlation": residual_correlation(problem, resid / np.sqrt(sigma2))}
