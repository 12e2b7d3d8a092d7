"""Posterior predictive simulation with Mitsuba: render the fitted (extended) model.

For ``n_draws`` posterior draws, the scene is rebuilt with the draw's per-region materials on the
mesh cut along the fit's regions (:func:`rjfit.effects.scenes.model_scene`; rjfit's plugin, or its
variant ``rjfit_blinn_ext`` when an effect of the model has BSDF parameters: scale = I0 /
reference_intensity, kd, gamma and those) plus the Mitsuba-side changes of the model's effects
(emitters, light scales, path depth, post-process), and every light is path-traced along the data
set's own pixel-centre rays. The spread over draws is the
simulation's own uncertainty; replicated data add the draw's noise.

Outputs (``simulate_fit``): standardised residuals z = (y - E[sim]) / sqrt(sigma^2 + Var[sim])
per image and aggregated, the gap of the Mitsuba residuals (same definition and noise
estimate as ``gap``), per-light and per-region gaps (where disagreement concentrates) and a
per-pixel posterior predictive check with the discrepancy

    T = (sum over the pixel's lights of (y - sim))^2 / sum of sigma^2

against the same discrepancy of replicated data y_rep = sim + N(0, sigma^2), p = P(T_rep >= T)
over draws and replications (small p: the data disagree with the fitted model there). A sum of
squared residuals would be a poor discrepancy here: a model that misses an effect inflates its
fitted sigma^2 until the squared residuals look like noise. The signed sum over lights keeps
what noise does not have: residuals of one sign at a pixel, in every image.
"""
from __future__ import annotations

import numpy as np

from rjfit.diagnose.figures import map_figure, per_image_figure, residual_pair_figure
from rjfit.diagnose.gap import gap, gap_breakdown
from rjfit.effects.scenes import model_scene
from rjfit.progress import phase
from rjfit.render.effect_scenes import render_model
from rjfit.render.scene_change import merge_changes

__all__ = ["simulate_fit", "simulation_record"]

SIMULATION_STREAM = 14     # purpose tag of the posterior predictive renders' streams (mitsuba_seed)


def simulate_fit(ctx, fit, sigma2_hat, *, n_draws=3, n_replicates=50, seed=0, spp_stochastic=256):  # environment: 16 x that, once per draw
    """Mitsuba posterior predictive of ``fit`` on ``ctx`` (needs the data set's mesh)."""
    if not ctx.has_mesh:
        raise ValueError("posterior predictive rendering needs the data set's mesh (a rendered data set "
                         "or a mesh stack)")
    rng = np.random.default_rng(seed)
    picks = rng.choice(fit.draws.shape[0], size=min(n_draws, fit.draws.shape[0]), replace=False)
    sims = _rendered_draws(ctx, fit, picks, seed, spp_stochastic)                  # (S, N)
    scale = 1.0 if ctx.noise_scale is None else ctx.noise_scale ** 2
    sigma2s = np.stack([fit.region_params(fit.draws[index])[ctx.region, 3] * scale for index in picks])
    mean = sims.mean(axis=0)
    var_sim = sims.var(axis=0, ddof=1) if sims.shape[0] > 1 else np.zeros_like(mean)
    residuals = ctx.y - mean
    standardised = residuals / np.sqrt(sigma2s.mean(axis=0) + var_sim)
    # Per-pixel posterior predictive check.
    n_pix = ctx.labels.size
    t_obs = np.zeros((sims.shape[0], n_pix))
    exceed = np.zeros(n_pix)
    for s in range(sims.shape[0]):
        total_var = np.bincount(ctx.pixel, weights=sigma2s[s], minlength=n_pix)
        safe = np.where(total_var > 0, total_var, 1.0)
        t_obs[s] = np.bincount(ctx.pixel, weights=ctx.y - sims[s], minlength=n_pix) ** 2 / safe
        for _ in range(n_replicates):
            noise = rng.standard_normal(ctx.n_obs) * np.sqrt(sigma2s[s])
            t_rep = np.bincount(ctx.pixel, weights=noise, minlength=n_pix) ** 2 / safe
            exceed += t_rep >= t_obs[s]
    p_values = (exceed / (sims.shape[0] * n_replicates)).reshape(ctx.image_shape)
    observed = np.bincount(ctx.pixel, minlength=n_pix).reshape(ctx.image_shape) > 0
    p_values = np.where(observed, p_values, np.nan)
    # the gap's residuals as the refit's (on the linear scale where the model has a camera response)
    in_noise_units = fit.objective.scaled_residuals(mean, fit.effect_thetas())[0]
    breakdown = gap_breakdown(ctx, in_noise_units, sigma2_hat)
    return {
        "n_draws": int(sims.shape[0]),
        "gap": gap(in_noise_units, sigma2_hat),
        "per_light_gap": breakdown["per_light"],
        "per_region_gap": breakdown["per_region"],
        "gap_map": breakdown["per_pixel"],
        "standardised": ctx.dense(standardised),                 # (L, H, W)
        "mean_abs_z_map": ctx.per_pixel_mean(np.abs(standardised)),
        "mean_z_map": ctx.per_pixel_mean(standardised),
        "ppc_p_values": p_values,
        "ppc_fraction_below_0.01": float(np.nanmean(p_values[observed] < 0.01)),
        "simulation_sd_mean": float(np.sqrt(var_sim).mean()),
    }


def _rendered_draws(ctx, fit, picks, seed, spp_stochastic):
    """Mitsuba's radiance of ``fit``'s draws ``picks`` at the observations of ``ctx``: (S, N).

    Rendered once per fit, context, draws and seed, and kept on the fit
    (:meth:`rjfit.diagnose.refit.FitResult.cached`): a diagnosis renders the same fits more than
    once (the naming rule the current model of each step and each candidate that passed rules 1
    to 3, the simulation record the plain and final models), and the render of one seed is the
    same every time.
    """
    def render(_fit):
        width = ctx.image_shape[1]
        at = (ctx.light, ctx.pixel // width, ctx.pixel % width)
        sims = []
        for k, index in enumerate(picks):
            z = fit.draws[index]
            thetas = fit.effect_thetas(z)
            change = merge_changes([e.mitsuba_change(t, ctx) for e, t in zip(fit.effects, thetas)])
            stack = render_model(*model_scene(ctx, fit.region_params(z)), change,
                                 spp=spp_stochastic if change.stochastic else 1, seed=(seed, SIMULATION_STREAM, k))
            sims.append(stack[at])
        return ctx, np.stack(sims)

    # the context is kept with its renders, so no other context can take its id while they are kept
    key = ("mitsuba_renders", id(ctx), tuple(int(i) for i in picks), seed, spp_stochastic)
    return fit.cached(key, render)[1]


def simulation_record(ctx, plain, current, sigma2_hat, *, n_draws, seed, figure_dir=None, progress=False) -> dict:
    """The Mitsuba posterior predictive of the plain and final models (``diagnosis.json``
    "simulation"), with its figures in ``figure_dir`` where given; ``progress``: each model's
    renders announced on stderr (:func:`rjfit.progress.phase`)."""
    models = {"plain": plain} if current is plain else {"plain": plain, "final": current}
    sim = {}
    for label, fit in models.items():
        with phase(f"diagnosis: Mitsuba posterior predictive of the {label} model ({n_draws} draws rendered)",
                   progress):
            sim[label] = simulate_fit(ctx, fit, sigma2_hat, n_draws=n_draws, seed=seed)
    sim_figs = {}
    if figure_dir is not None:
        final = sim.get("final", sim["plain"])
        sim_figs["mitsuba_residuals"] = residual_pair_figure(
            figure_dir / "mitsuba_residuals.png", sim["plain"]["mean_z_map"], final["mean_z_map"],
            f"Mitsuba, plain (gap {sim['plain']['gap']:.3g})", f"Mitsuba, final (gap {final['gap']:.3g})",
            label="mean standardised residual over lights")
        sim_figs["ppc"] = map_figure(figure_dir / "ppc_p_values.png", final["ppc_p_values"],
                                     "posterior predictive p-value per pixel (final model)", vmin=0, vmax=1,
                                     unit="p-value (small: the data lie outside the simulations)")
        for label, s in sim.items():
            sim_figs[f"per_image_{label}"] = per_image_figure(
                figure_dir / f"mitsuba_per_image_{label}.png", s["standardised"],
                f"{label}: standardised residual per image")
    simulation = {label: {k: v for k, v in s.items() if not isinstance(v, np.ndarray)} for label, s in sim.items()}
    simulation["figures"] = sim_figs
    return simulation
