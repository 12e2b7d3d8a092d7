"""Do per-pixel normals refined at full strength remove the measured stacks' residual correlation? (issue 45)

For one calibrated stack (as ``--preset measured`` sees it: ``validation/misfit_shares.py``'s cached stack), a
reflectance that gets no per-pixel freedom is fitted (``one``: one Lambert + Blinn material over the object;
``tile``: one per 5 x 5 pixel tile, :func:`rjfit.data.normal_error.patch_reference`'s tiles), and every pixel's
normal is refined by maximising its own likelihood at power 1 under that reflectance:

    minimise  sum_i (y_i - mu_i(d))^2 / (2 sigma^2) + |d|^2 / (2 tan(sigma_n)^2)

over its two gnomonic tangent coordinates ``d`` (``n' ~ n + dx t1 + dy t2``, the parametrisation and prior of
``--normals sample``), ``sigma^2`` the reflectance fit's mean squared residual (the variance a fit's material
would carry), ``sigma_n`` the stack's normal-error estimate (5 x 5 tile fits, floored at 0.25 deg). Gauss-Newton
with forward differences, a step that does not lower a pixel's objective halved (up to 5 times); the reflectance
refitted at the refined normals and the normals refined again (``--rounds``).

Measured before and after: the lag-1 correlation rho of the reflectance fit's residuals (one sigma: the
standardised ones), and of the per-pixel Lambert + Blinn fits' residuals standardised by the normal-error noise
scales (the likelihood power rule of the measured default, :func:`rjfit.data.coarsen.suggest_likelihood_power`,
re-measured at the refined normals: what a two-stage ``--normals refine`` would take), each with its implied
power ((1 - rho) / (1 + rho))^2; rho per light and by <h.n> and <l.n> band (where the correlation sits).
With ``--paint FIT`` (a fit whose MAP labels hold a paint: psm-cat's nose), the paint's log-likelihood gain as a
material of its own over the body's, per pixel, with the given normals and with each pixel's normal refined under
each material (the normals' chance to absorb the paint).

    python validation/normal_refinement.py /work/shared/data/psm-cat --cache /tmp/hpaints/cache \
        --paint /tmp/hn/meas/fixed-psm-cat --out /tmp/normref/rows.jsonl
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

from rjfit.data.coarsen import neighbour_correlations, suggest_likelihood_power
from rjfit.data.exr import read_exr
from rjfit.data.lights import tangent_frame, tangent_terms
from rjfit.data.normal_error import DEFAULT_PATCH, normal_error_noise
from rjfit.data.observations import MIN_COS, Observations
from rjfit.data.noise import weighted_observations
from rjfit.data.pixelfit import group_fit, patch_index, per_pixel_residuals
from rjfit.model.blinn import blinn_normalisation

sys.path.insert(0, str(Path(__file__).resolve().parent))
from misfit_shares import load_stack  # noqa: E402  (the calibrated stack and its cache, shared with that study)
from paint_share import paint_mask  # noqa: E402

MIN_PRIOR_DEG = 0.25          # as rjfit.pipeline.fit_power.MIN_NORMAL_SD_DEG
HN_BANDS = (0.0, 0.9, 0.98, 1.01)      # <h.n> bands: away from, near and on the highlight (within 11.5 deg)
LN_BANDS = (0.0, 0.2, 1.01)            # <l.n> bands: near the terminator and the rest


def observations_of(stack, normals) -> Observations:
    """The stack's valid mean-channel observations at ``normals`` (P, 3), with ``cos_lh`` and tangents of that frame."""
    p, light = np.nonzero(stack.valid)
    n = normals[p]
    half = stack.half[p, light]
    l_dir = stack.lights[light]
    t1, t2 = tangent_frame(n)
    width = int(stack.shape[1])
    mask = np.zeros(tuple(int(v) for v in stack.shape), bool)
    mask[stack.rows, stack.cols] = True
    return Observations(image_shape=tuple(int(v) for v in stack.shape), n_lights=stack.lights.shape[0],
                        pixel=(stack.rows[p] * width + stack.cols[p]).astype(np.int64), light=light.astype(np.int32),
                        y=stack.y[p, light].mean(axis=-1), cos_ln=np.sum(l_dir * n, axis=1),
                        cos_hn=np.sum(half * n, axis=1), irradiance=stack.irradiance[light], object_mask=mask,
                        cos_lh=np.sum(half * l_dir, axis=1), tangent=tangent_terms(l_dir, stack.view[p], t1, t2))


def turned_normals(normals, d) -> np.ndarray:
    """(P, 3) the normals turned by tangent coordinates ``d`` (P, 2) in the frame of :func:`tangent_frame`."""
    t1, t2 = tangent_frame(normals)
    n = normals + d[:, :1] * t1 + d[:, 1:] * t2
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def reflectance(obs, group, n_groups) -> dict:
    """Per observation the Lambert + Blinn coefficients of its group's fit (``a``, ``b``, ``gamma``), its residuals
    and the fit's mean squared residual ``sigma2``."""
    fit = group_fit(obs, group, n_groups)
    residuals = fit["residuals"]
    return {"a": fit["a"][group], "b": fit["b"][group], "gamma": fit["gamma"][group], "residuals": residuals,
            "sigma2": float(np.nanmean(residuals ** 2)), "groups": fit}


def prediction(obs, coef, d_obs) -> tuple[np.ndarray, np.ndarray]:
    """``(mu, <l.n'>)`` per observation at the tangent coordinates ``d_obs`` (N, 2) of its pixel."""
    inv = 1.0 / np.sqrt(1.0 + np.sum(d_obs * d_obs, axis=1))
    t = obs.tangent.astype(float)
    ln = (obs.cos_ln + d_obs[:, 0] * t[:, 0] + d_obs[:, 1] * t[:, 1]) * inv
    hn = np.clip((obs.cos_hn + d_obs[:, 0] * t[:, 2] + d_obs[:, 1] * t[:, 3]) * inv, 1e-12, 1.0)
    g = coef["gamma"]
    mu = obs.irradiance * ln * (coef["a"] / np.pi + coef["b"] * blinn_normalisation(g) * np.exp(g * np.log(hn)))
    return mu, ln


def refine(obs, coef, sigma2, prior_sd, pixel, n_pix, start=None, steps=8) -> tuple[np.ndarray, np.ndarray]:
    """Each pixel's tangent coordinates (n_pix, 2) minimising its penalised least squares (module docstring), and the
    minimum per pixel; ``pixel`` (N,) each observation's index in 0..n_pix-1."""
    def cost(d):
        mu, ln = prediction(obs, coef, d[pixel])
        r = obs.y - mu
        value = 0.5 * np.bincount(pixel, r * r, n_pix) / sigma2 + 0.5 * np.sum(d * d, axis=1) / prior_sd ** 2
        turned_away = np.bincount(pixel, ln <= MIN_COS, n_pix) > 0
        return np.where(turned_away, np.inf, value), r

    d = np.zeros((n_pix, 2)) if start is None else start.copy()
    value, r = cost(d)
    eps = 1e-5
    for _ in range(steps):
        jac = [(prediction(obs, coef, (d + eps * e)[pixel])[0] - (obs.y - r)) / eps for e in np.eye(2)]
        jtj = [np.bincount(pixel, jac[i] * jac[j], n_pix) / sigma2 for i, j in ((0, 0), (0, 1), (1, 1))]
        jtr = [np.bincount(pixel, jac[i] * r, n_pix) / sigma2 - d[:, i] / prior_sd ** 2 for i in range(2)]
        h00, h01, h11 = jtj[0] + prior_sd ** -2, jtj[1], jtj[2] + prior_sd ** -2
        det = h00 * h11 - h01 * h01
        step = np.column_stack([(h11 * jtr[0] - h01 * jtr[1]) / det, (h00 * jtr[1] - h01 * jtr[0]) / det])
        for _ in range(5):
            trial = d + step
            trial_value, _ = cost(trial)
            better = trial_value < value
            d[better] = trial[better]
            step = np.where(better[:, None], 0.0, 0.5 * step)
            value = np.where(better, trial_value, value)
            if not step.any():
                break
        value, r = cost(d)
    return d, value


def rho_of(obs, values) -> dict:
    """Lag-1 rho of per-observation ``values`` (neighbours under one light) and its implied power."""
    rhos, pairs = neighbour_correlations(obs.dense(values))
    rho = max(0.0, float(np.nanmean(rhos)))
    return {"rho": rho, "power": ((1 - rho) / (1 + rho)) ** 2, "pairs": pairs}


def where_rho_sits(obs, residuals) -> dict:
    """rho per light, and of neighbour pairs whose both observations lie in one <h.n> or <l.n> band."""
    dense = obs.dense(residuals)
    per_light = [float(np.nanmean(neighbour_correlations(dense[k])[0])) for k in range(obs.n_lights)]
    out = {"per_light": per_light}
    for name, values, edges in (("hn", obs.cos_hn, HN_BANDS), ("ln", obs.cos_ln, LN_BANDS)):
        band = np.digitize(values, edges) - 1
        rows = {}
        for b in range(len(edges) - 1):
            chosen = np.where(band == b, residuals, np.nan)
            rows[f"{edges[b]:g}-{min(edges[b + 1], 1.0):g}"] = {
                "rho": float(np.nanmean(neighbour_correlations(obs.dense(chosen))[0])),
                "share_of_obs": float(np.mean(band == b)),
                "share_of_ssr": float(np.nansum(chosen ** 2) / np.nansum(residuals ** 2))}
        out[name] = rows
    return out


def smooth_part(obs, residuals, size: int = 9, seed: int = 1) -> dict:
    """How much of the residual field is smooth: the share of its sum of squares that is not in its high-pass part
    (each light's image less its local mean over a ``size`` x ``size`` window within the object), the lag-1 rho
    of the high-pass part, and the same two figures for white noise on the same pixels (``seed``), the reference
    a pixel-independent field gives (its share about 2.5 %, its rho about -1 / 80); the high-pass part across
    lights (:func:`across_lights`)."""
    def split(values):
        high = high_pass(obs.dense(values), size)
        dense = obs.dense(values)
        share = 1.0 - float(np.nansum(high ** 2) / np.nansum(dense ** 2))
        return share, float(np.nanmean(neighbour_correlations(high)[0])), high

    r = residuals - np.nanmean(residuals)
    share, rho_high, high = split(r)
    noise = np.random.default_rng(seed).standard_normal(r.size) * np.where(np.isfinite(r), 1.0, np.nan)
    noise_share, noise_rho_high, _ = split(noise)
    return {"window_px": size, "smooth_share": share, "high_pass_rho": rho_high,
            "white_noise_smooth_share": noise_share, "white_noise_high_pass_rho": noise_rho_high,
            "high_pass_across_lights": across_lights(high)}


def high_pass(dense, size: int):
    """Each image of ``dense`` (L, H, W; NaN off the data) less its local mean over a ``size`` x ``size`` window."""
    present = np.isfinite(dense)
    box = ndimage.uniform_filter(np.where(present, dense, 0.0), size=(1, size, size), mode="constant")
    count = ndimage.uniform_filter(present.astype(float), size=(1, size, size), mode="constant")
    return dense - np.where(present, box / np.maximum(count, 1e-12), np.nan)


def across_lights(high, max_lights: int = 12) -> dict:
    """Is the pixel-scale part the images' (independent per light) or the surface's (shared by every light)? The
    mean correlation of horizontal neighbours' high-pass residuals under two different lights (0 for noise that is
    independent per image), and of one pixel's under two lights, over pairs of the first ``max_lights`` lights."""
    lights = range(min(high.shape[0], max_lights))
    neighbours, same_pixel = [], []
    for k in lights:
        for j in lights:
            if j == k:
                continue
            for first, second, out in ((high[k, :, :-1], high[j, :, 1:], neighbours), (high[k], high[j], same_pixel)):
                keep = np.isfinite(first) & np.isfinite(second)
                if keep.sum() > 2:
                    out.append(float(np.corrcoef(first[keep], second[keep])[0, 1]))
    return {"neighbours_other_light_mean": float(np.mean(neighbours)),
            "neighbours_other_light_mean_abs": float(np.mean(np.abs(neighbours))),
            "same_pixel_other_light_mean": float(np.mean(same_pixel)),
            "same_pixel_other_light_mean_abs": float(np.mean(np.abs(same_pixel))), "lights": len(lights)}


def power_rule(obs) -> dict:
    """The measured default's power rule at these normals: normal-error scales (5 x 5 tiles) and per-pixel fits."""
    scale, record = normal_error_noise(obs)
    rule = suggest_likelihood_power(obs, noise_scale=scale)
    weighted = weighted_observations(obs, scale)
    return {"rho": rule["rho"], "power": rule["likelihood_power"], "sigma_n_deg": record["sigma_n_deg"],
            "k": record["k"], "smooth": smooth_part(obs, per_pixel_residuals(weighted))}


def run_reference(stack, obs0, pixel, n_pix, mode, prior_sd, rounds) -> tuple[dict, np.ndarray]:
    """Refine under the ``mode`` reflectance (``one`` or ``tile``); the row of figures and the final d (n_pix, 2)."""
    group, n_groups = (np.zeros(obs0.n_obs, np.int64), 1) if mode == "one" else patch_index(obs0, DEFAULT_PATCH)
    start = time.time()
    fit0 = reflectance(obs0, group, n_groups)
    d, obs = None, obs0
    fit = fit0
    for _ in range(rounds):
        d, _ = refine(obs0, fit, fit["sigma2"], prior_sd, pixel, n_pix, start=d)
        obs = observations_of(stack, turned_normals(stack.normals, d))
        fit = reflectance(obs, group, n_groups)
    shift = np.degrees(np.arctan(np.hypot(d[:, 0], d[:, 1])))[np.bincount(pixel, minlength=n_pix) > 0]
    row = {"reference": mode, "seconds": round(time.time() - start, 1),
           "before": {**rho_of(obs0, fit0["residuals"]), "rms": math.sqrt(fit0["sigma2"])},
           "after": {**rho_of(obs, fit["residuals"]), "rms": math.sqrt(fit["sigma2"])},
           "shift_deg": {"median": float(np.median(shift)), "p95": float(np.percentile(shift, 95)),
                         "p99": float(np.percentile(shift, 99))},
           "rule_after": power_rule(obs)}
    if mode == "one":
        row["where_before"] = where_rho_sits(obs0, fit0["residuals"])
        row["smooth_before"] = smooth_part(obs0, fit0["residuals"])
        row["where_after"] = where_rho_sits(obs, fit["residuals"])
    return row, d


def paint_evidence(stack, obs0, pixel, n_pix, paint_pixels, prior_sd, powers) -> dict:
    """The paint's log-likelihood gain as its own material over the body's, given normals and refined normals.

    ``paint_pixels`` (n_pix,) bool (in ``pixel``'s numbering). Both materials are fitted at the given normals
    (body: every other pixel); one sigma^2 (the two-material fit's) for both, so the gain moves with the normals
    only. Refined: each paint pixel's normal refined under each material's reflectance on its own (the penalised
    optimum of each, the prior's term included).
    """
    label = paint_pixels[pixel].astype(np.int64)
    fit = reflectance(obs0, label, 2)
    sigma2 = fit["sigma2"]
    inside = paint_pixels[pixel]
    sub = obs0.subset(inside)
    sub_pixel = np.unique(pixel[inside], return_inverse=True)[1].reshape(-1)
    n_sub = int(sub_pixel.max()) + 1
    out = {"pixels": int(paint_pixels.sum()), "sigma2": sigma2}
    values = {}
    for m, name in ((0, "body"), (1, "paint")):
        coef = {key: np.full(sub.n_obs, fit["groups"][key][m]) for key in ("a", "b", "gamma")}
        mu, _ = prediction(sub, coef, np.zeros((sub.n_obs, 2)))
        values[name, "given"] = 0.5 * np.bincount(sub_pixel, (sub.y - mu) ** 2, n_sub) / sigma2
        values[name, "refined"] = refine(sub, coef, sigma2, prior_sd, sub_pixel, n_sub)[1]
    for normals in ("given", "refined"):
        gain = values["body", normals] - values["paint", normals]
        out[normals] = {"gain": float(np.sum(gain)), "pixels_favouring_paint": float(np.mean(gain > 0)),
                        **{f"gain_x_{name}": float(np.sum(gain) * power) for name, power in powers.items()}}
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("stack", type=Path)
    parser.add_argument("--cache", type=Path, default=None, help="the calibrated stacks' cache (misfit_shares.py)")
    parser.add_argument("--paint", type=Path, default=None, help="a fit whose smallest MAP material is a paint")
    parser.add_argument("--prior-deg", type=float, default=None,
                        help="the normals' prior sd (degrees); default the stack's normal-error estimate")
    parser.add_argument("--perturb-deg", type=float, default=None,
                        help="a check of the refinement: turn the given normals by iid N(0, tan(X)^2) tangent "
                             "coordinates first (--seed) and report the refined normals' error from the originals")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--references", nargs="+", default=["one", "tile"], choices=["one", "tile"])
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    stack, rule_before = load_stack(args.stack, 72.5, 1, args.cache)
    truth = stack.normals
    if args.perturb_deg is not None:
        turn = np.random.default_rng(args.seed).normal(0.0, math.tan(math.radians(args.perturb_deg)), truth[:, :2].shape)
        stack = dataclasses.replace(stack, normals=turned_normals(truth, turn))
    obs0 = observations_of(stack, stack.normals)
    pixel = np.nonzero(stack.valid)[0]          # each observation's stack pixel (observations_of's order)
    n_pix = stack.valid.shape[0]
    observed = np.bincount(pixel, minlength=n_pix) > 0
    rule0 = power_rule(obs0)
    prior_deg = max(rule0["sigma_n_deg"], MIN_PRIOR_DEG) if args.prior_deg is None else args.prior_deg
    prior_sd = math.tan(math.radians(prior_deg))
    rows = {"stack": args.stack.name, "pixels": int(observed.sum()), "observations": obs0.n_obs,
            "prior_sd_deg": prior_deg, "rule_before": rule0, "rule_cached": rule_before}
    print(f"{args.stack.name}: {int(observed.sum())} px, prior {prior_deg:.2f} deg, rule rho {rule0['rho']:.3f} "
          f"power {rule0['power']:.4f}", flush=True)
    for mode in args.references:
        row, d = run_reference(stack, obs0, pixel, n_pix, mode, prior_sd, args.rounds)
        rows[mode] = row
        if args.perturb_deg is not None:
            error = np.degrees(np.arccos(np.clip(np.sum(turned_normals(stack.normals, d) * truth, axis=1), -1, 1)))
            given = np.degrees(np.arccos(np.clip(np.sum(stack.normals * truth, axis=1), -1, 1)))
            row["perturbed_error_deg"] = {"given_median": float(np.median(given[observed])),
                                          "refined_median": float(np.median(error[observed]))}
            print(f"  {mode}: error from the unperturbed normals, median {row['perturbed_error_deg']}", flush=True)
        print(f"  {mode}: rho {row['before']['rho']:.3f} -> {row['after']['rho']:.3f}, rms {row['before']['rms']:.4g}"
              f" -> {row['after']['rms']:.4g}, shift median {row['shift_deg']['median']:.2f} deg; rule at refined "
              f"normals rho {row['rule_after']['rho']:.3f} power {row['rule_after']['power']:.4f} "
              f"sigma_n {row['rule_after']['sigma_n_deg']:.2f} ({row['seconds']} s)", flush=True)
    if args.paint is not None:
        image = paint_mask(args.paint)
        offset = _frame_offset(image.shape, stack, args.paint)
        paint_pixels = image[stack.rows + offset[0], stack.cols + offset[1]]
        powers = {"rule_before": rule0["power"], "rule_after_one": rows.get("one", {}).get("rule_after", {}).get("power", np.nan)}
        rows["paint"] = paint_evidence(stack, obs0, pixel, n_pix, paint_pixels, prior_sd, powers)
        print(f"  paint {rows['paint']['pixels']} px: gain given {rows['paint']['given']['gain']:.0f}, refined "
              f"{rows['paint']['refined']['gain']:.0f}", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "a") as handle:
        handle.write(json.dumps(rows) + "\n")
    return 0


def _frame_offset(shape, stack, fit) -> tuple[int, int]:
    """(row, col) of the cropped stack's origin in the fit's maps (written in the original frame): the object's
    bounding boxes aligned."""
    labels = np.asarray(read_exr(Path(fit) / "labels.exr")["labels"]).squeeze()
    rows, cols = np.nonzero(np.isfinite(labels) & (labels >= 0))
    return int(rows.min() - stack.rows.min()), int(cols.min() - stack.cols.min())


if __name__ == "__main__":
    sys.exit(main())
