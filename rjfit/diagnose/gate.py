"""The cross-check gate for an extended model: Mitsuba with the effects' changes against the
extended closed form (:func:`rjfit.diagnose.model.predict`), on the data set's own pixel-centre
rays. The rendering is the render layer's (:mod:`rjfit.render.effect_scenes`); the closed form,
its context and the effects are the criticism's, so the gate lives here. The same path-traced
stack is also compared with the closed form the FIT samples with the effects inside its
likelihood (:func:`rjfit.diagnose.model.fit_prediction`, issue 26): ``result["fit"]``.
"""
from __future__ import annotations

import time

import numpy as np

from rjfit.diagnose.context import build_context
from rjfit.diagnose.model import fit_prediction, order_effects, predict
from rjfit.render.datasets import load_dataset
from rjfit.render.effect_scenes import render_model
from rjfit.render.gate import MEDIAN_TOLERANCE, P99_TOLERANCE
from rjfit.render.scene_change import merge_changes

__all__ = ["gate", "STOCHASTIC_RATIO"]

# the stochastic criterion: sum (path - closed)^2 / sum se^2, whose expectation is 1 when they agree
STOCHASTIC_RATIO = 1.5


def _verdict(path, closed, se, stochastic):
    """Compare path-traced and closed-form values of the same observations."""
    scale = np.maximum(np.abs(path), np.abs(closed))
    compared = scale > 1e-6 * max(float(scale.max()), 1e-30)
    rel = np.abs(path - closed)[compared] / scale[compared]
    out = {"observations_compared": int(compared.sum()), "median_rel_err": float(np.median(rel)),
           "p99_rel_err": float(np.quantile(rel, 0.99)), "max_rel_err": float(rel.max()),
           "unexplained_fraction": float(np.sum((path - closed)[compared]) / np.sum(path[compared]))}
    if stochastic:
        se = se[compared]
        z = (path - closed)[compared] / np.maximum(se, 1e-9 * scale[compared] + 1e-30)
        total_se = float(np.sqrt(np.sum(se ** 2)))
        bias = float(np.sum((path - closed)[compared]))
        ratio = float(np.sum((path - closed)[compared] ** 2) / max(float(np.sum(se ** 2)), 1e-300))
        out.update(median_abs_z=float(np.median(np.abs(z))), total_bias_in_se=bias / max(total_se, 1e-30),
                   mse_over_mc_variance=ratio,
                   passed=bool(ratio <= STOCHASTIC_RATIO and (abs(bias) <= 3 * total_se
                                                              or abs(bias) <= 1e-3 * np.sum(path[compared]))),
                   criterion=f"sum (path - closed)^2 / sum se^2 <= {STOCHASTIC_RATIO} (1 expected) and total bias "
                             f"within 3 SE (or 1e-3 relative)")
    else:
        out.update(passed=bool(out["median_rel_err"] <= MEDIAN_TOLERANCE and out["p99_rel_err"] <= P99_TOLERANCE),
                   criterion=f"median rel err <= {MEDIAN_TOLERANCE}, p99 <= {P99_TOLERANCE}")
    return out


def gate(dataset_dir, effects=(), thetas=(), *, materials=None, spp=64, batches=8, seed=0, reference_effects=()):
    """The cross-check gate for an extended model: Mitsuba with the effects' changes vs the
    extended closed form, on the data set's own pixel-centre rays.

    Compared: every observation on the object that faces the light (shadowed ones included:
    occlusion is part of what is checked) where the path-traced or the closed-form radiance
    exceeds 1e-6 of the largest; relative error = |path - closed| / max(path, closed).
    Deterministic changes (no Monte Carlo in the path tracer's answer): the thresholds of
    ``rjfit.render.gate`` (median relative error <= 1e-4, p99 <= 1e-3). Stochastic changes
    (ambient, interreflection): the Monte Carlo error is estimated from ``batches``
    independent batches (and, for interreflection, the feature's own batches); the gate passes
    when sum (path - closed)^2 / sum se^2 <= 1.5 (its expectation is 1 when they agree) and the
    relative bias of the totals is within 3 standard errors or 1e-3.
    (Per-observation |z| is reported too, but with standard errors from a few batches it is
    t-distributed and heavy-tailed; the ratio of sums uses unbiased variance estimates only.)

    The same path-traced stack is also compared with a REFERENCE closed form that includes only
    ``reference_effects`` (default none: the plain eq. 2), which must fail where the effect
    matters, and with the fit's forward model with the effects (``"fit"``: the mean the fit's
    likelihood has, :func:`rjfit.diagnose.model.fit_prediction`). Returns ``{"extended":
    verdict, "reference": verdict, "fit": verdict, ...}``.
    """
    started = time.perf_counter()
    dataset = load_dataset(dataset_dir)
    materials = materials if materials is not None else dataset.meta["materials"]
    cos_ln, _, _ = dataset.geometry()
    valid = dataset.object_mask[None] & (cos_ln > 1e-3)
    ctx = build_context(dataset, dataset.truth_labels, valid=valid)
    labels_used = np.unique(dataset.truth_labels[dataset.truth_labels >= 0])
    region_params = np.array([[materials[m]["I0"], materials[m]["kd"], materials[m]["gamma"], 1.0]
                              for m in labels_used])
    ctx.features["fit_region_params"] = region_params
    pairs = list(zip(effects, thetas))
    ordered = order_effects([e for e, _ in pairs])
    theta_of = {e.name: np.asarray(t, dtype=float) for e, t in pairs}
    features = [e.prepare(ctx) for e in ordered]

    def closed_form(names):
        keep = [i for i, e in enumerate(ordered) if names is None or e.name in names]
        return predict(ctx, [ordered[i] for i in keep], region_params, [theta_of[ordered[i].name] for i in keep],
                       [features[i] for i in keep])

    change = merge_changes([e.mitsuba_change(theta_of[e.name], ctx) for e in ordered])
    stochastic = change.stochastic
    if stochastic and change.post_process is not None:
        raise NotImplementedError("a stochastic change with a post-process has no gate here")
    traced = render_model(dataset, materials, change, spp=max(spp // batches, 1) if stochastic else 1, seed=seed,
                          batches=batches if stochastic else 1)
    path_stack, se_stack = traced if stochastic else (traced, None)
    width = ctx.image_shape[1]
    at = (ctx.light, ctx.pixel // width, ctx.pixel % width)
    path = path_stack[at]
    se = None
    if stochastic:
        se2 = se_stack[at] ** 2
        if "interreflection" in theta_of and "indirect_se" in ctx.features:
            se2 = se2 + (theta_of["interreflection"][0] * ctx.features["indirect_se"][at]) ** 2
        se = np.sqrt(se2)
    result = {"dataset": str(dataset_dir), "effects": [e.name for e in ordered],
              "thetas": {e.name: theta_of[e.name].tolist() for e in ordered}, "stochastic": bool(stochastic),
              "spp": int(max(spp // batches, 1) * batches) if stochastic else 1,
              "extended": _verdict(path, closed_form(None), se, stochastic),
              "reference_effects": list(reference_effects),
              "reference": _verdict(path, closed_form(tuple(reference_effects)), se, stochastic)}
    if ordered:
        fitted = fit_prediction(ctx, ordered, region_params, [theta_of[e.name] for e in ordered])
        result["fit"] = _verdict(path, fitted, se, stochastic)
    result["passed"] = result["extended"]["passed"]
    result["seconds"] = round(time.perf_counter() - started, 3)
    return result
