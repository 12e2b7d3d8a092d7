"""Why the measured DiLiGenT ball splits: the evidence for a split around its highlight, per noise model.

For one material the posterior should keep one region; it keeps several
(docs/results/measured-ball.md). This script measures the reason without a sampler: one Lambert + Blinn lobe
fitted to the whole ball (exponent on a grid, amplitudes by non-negative least squares)
against two, one inside a box around the highlight and one outside, each with its own
sigma^2. The log-likelihood gain of that split, times the likelihood power zeta that
``--likelihood-power auto`` would choose (:func:`rjfit.data.coarsen.suggest_likelihood_power`),
is the evidence the sampler weighs against the penalty of the split's 4 extra parameters,
about ``4 / 2 log(zeta n)``.

Noise models:

``constant``
    One sigma^2 per region: the default, the paper's model.
``geometric``
    Per observation ``var_i = sigma^2 (1 + k |d mu_i / d n|^2)``: the error of a normal
    (``Normal_gt`` against photometric-stereo normals: 1.8 deg median) moves the
    prediction by ``|d mu / d n|`` times its angle, which is large on the narrow highlight.
    ``d mu / d n`` is the tangential gradient of the one-region fit's prediction; the
    noise floor and the normal-error sd (``k = sd_n^2 / s0^2``) are the maximum-likelihood
    values on its residuals.
``normal error``
    The same error without linearising (the lobe is about as narrow as the normal errors,
    and at its peak the gradient vanishes while the spread does not): with the lobe
    ``L exp(-g' theta^2 / 2)`` (theta the angle between h and n) and a normal error
    ``N(0, sd_n^2)`` per tangent axis, ``var_i = s0^2 + L_i^2 (E2_i - E1_i^2)``, where
    ``E1 = exp(-g' theta^2 / (2 (1 + g' sd_n^2))) / (1 + g' sd_n^2)`` and ``E2`` the same
    with ``2 g'``. The fitted lobe is taken as the blurred one, so ``g' = g / (1 - g sd_n^2)``
    and ``L = b E <l.n> (1 + g' sd_n^2)``; s0 and sd_n by maximum likelihood.
``margin K`` (with ``--clip-margin K ...``)
    Constant noise without the observations within K pixels of a clipped (saturated) pixel
    of the same image: the highlight's peak, where the one-lobe fit's residuals concentrate
    (on the ball, the 0.1 % of observations within 2 px hold 46 % of the one-region fit's
    squared residuals, in a profile that falls off alike along rows and columns, so it is
    the highlight itself, not a sensor's column blooming). What remains is the evidence
    for a split that the rest of the ball carries; zeta is recomputed on the kept
    observations.
``student-t NU`` (with ``--student-t NU ...``; about 3 min per NU)
    A heavy-tailed likelihood: Student-t residuals with NU degrees of freedom and one scale
    per region, so a misfit confined to a few observations (the highlight's peak) costs
    their log, not their square. Each region's fit is the profile over the exponent grid
    of an EM fit (scale-mixture weights) of the amplitudes and the scale; zeta from the
    one-region fit's weights.

    .venv/bin/python validation/ball_split_study.py [../shared/data/diligent-ball] [--clip-margin 3 6 12]
        [--student-t 1 4]
"""
from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace

import numpy as np

# boxes (row0, row1, col0, col1) in the 512 x 612 frame: the best box of a search around the
# highlight's centre (rows 245-282, cols 277-338), a larger and a smaller one, and a wide one
BOXES = ((245, 282, 277, 338), (230, 300, 260, 360), (250, 275, 290, 330), (200, 330, 230, 400))
GAMMAS = np.geomspace(0.1, 4000.0, 90)


def fit_region(A, C, log_hn, y, weight, select):
    """Best (ssr, gamma, a, b) of ``y ~ a A + b C <h.n>^gamma`` over the grid, a, b >= 0, weighted."""
    w = weight[select]
    yw, Aw, Cw, lh = y[select] * w, A[select] * w, C[select] * w, log_hn[select]
    yy, ya, aa = yw @ yw, yw @ Aw, Aw @ Aw
    best = (np.inf, np.nan, np.nan, np.nan)
    for g in GAMMAS:
        Bw = Cw * np.exp(g * lh)
        yb, ab, bb = yw @ Bw, Aw @ Bw, Bw @ Bw
        det = aa * bb - ab * ab
        candidates = []
        if det > 1e-12 * aa * bb:
            a, b = (bb * ya - ab * yb) / det, (aa * yb - ab * ya) / det
            if a >= 0 and b >= 0:
                candidates.append((a, b))
        candidates += [(max(ya / aa, 0.0), 0.0), (0.0, max(yb / bb, 0.0) if bb > 0 else 0.0)]
        for a, b in candidates:
            with np.errstate(over="ignore", invalid="ignore"):     # a vanishing lobe: b = SyB / SBB blows up
                ssr = yy - 2 * a * ya - 2 * b * yb + a * a * aa + 2 * a * b * ab + b * b * bb
            if np.isfinite(ssr) and ssr < best[0]:
                best = (ssr, g, a, b)
    return best


def fit_region_student(A, C, log_hn, y, select, nu, em_steps=20):
    """Best (log-likelihood, gamma, weights) of ``y ~ a A + b C <h.n>^gamma`` with Student-t(nu) residuals.

    For each exponent of a coarser grid, EM on the scale mixture: weighted least squares for
    (a, b >= 0), then the scale and the weights ``(nu + 1) / (nu + r^2 / s^2)``.
    """
    from scipy.special import gammaln

    ys, As, Cs, lh = y[select], A[select], C[select], log_hn[select]
    n = ys.size
    constant = n * (gammaln((nu + 1) / 2) - gammaln(nu / 2) - 0.5 * math.log(nu * math.pi))
    best = (-np.inf, np.nan, None)
    for g in GAMMAS[::2]:
        B = Cs * np.exp(g * lh)
        w, s2 = np.ones(n), None
        for _ in range(em_steps):
            aa, ab, bb, ya, yb = w @ (As * As), w @ (As * B), w @ (B * B), w @ (ys * As), w @ (ys * B)
            det = aa * bb - ab * ab
            candidates = [(max(ya / aa, 0.0), 0.0), (0.0, max(yb / bb, 0.0) if bb > 0 else 0.0)]
            if det > 1e-12 * aa * bb:
                a, b = (bb * ya - ab * yb) / det, (aa * yb - ab * ya) / det
                if a >= 0 and b >= 0:
                    candidates.append((a, b))
            a, b = min(candidates, key=lambda ab_: w @ (ys - ab_[0] * As - ab_[1] * B) ** 2)
            r = ys - a * As - b * B
            s2 = np.sum(w * r * r) / n
            w = (nu + 1) / (nu + r * r / s2)
        log_lik = constant - 0.5 * n * math.log(s2) - (nu + 1) / 2 * np.sum(np.log1p(r * r / (nu * s2)))
        if log_lik > best[0]:
            best = (log_lik, g, w)
    return best


def observation_arrays(obs):
    """``(y, A, C, log <h.n>, rows, cols)`` of the observations, float64 (A = C / pi, C = E <l.n>)."""
    width = obs.image_shape[1]
    y = np.asarray(obs.y, float)
    C = np.asarray(obs.irradiance, float) * np.asarray(obs.cos_ln, float)
    log_hn = np.log(np.clip(np.asarray(obs.cos_hn, float), 1e-300, None))
    return y, C / math.pi, C, log_hn, obs.pixel // width, obs.pixel % width


def clip_distance(dataset, obs):
    """Distance (px) of each observation to the nearest clipped pixel of its own image (inf: none)."""
    from scipy import ndimage

    width = obs.image_shape[1]
    return np.stack([ndimage.distance_transform_edt(~clipped) if clipped.any() else np.full(clipped.shape, np.inf)
                     for clipped in dataset.saturated])[obs.light, obs.pixel // width, obs.pixel % width]


def split_evidence(obs, weight, kept, boxes=BOXES):
    """The evidence for splitting the kept observations at each box, under known noise scales 1 / weight.

    One region (a Lambert + Blinn lobe, its own sigma^2) against two, inside and outside the
    box. Returns one dict per box: ``box``, ``zeta`` (``--likelihood-power auto`` on the kept,
    weighted observations), ``gain`` (log-likelihood), ``penalty`` (``4 / 2 log(zeta n)``, the
    split's 4 extra parameters), ``gamma_in``, ``gamma_out`` and ``n``.
    """
    from rjfit.data.coarsen import suggest_likelihood_power

    y, A, C, log_hn, rows, cols = observation_arrays(obs)
    fields = ("pixel", "light", "y", "cos_ln", "cos_hn", "irradiance")
    scaled = replace(obs, **{f: getattr(obs, f)[kept] for f in fields})
    scaled = replace(scaled, y=scaled.y * weight[kept], irradiance=scaled.irradiance * weight[kept])
    zeta = suggest_likelihood_power(scaled)["likelihood_power"]
    n = int(kept.sum())
    one_region = fit_region(A, C, log_hn, y, weight, kept)[0]
    rows_out = []
    for r0, r1, c0, c1 in boxes:
        inside = kept & (rows >= r0) & (rows < r1) & (cols >= c0) & (cols < c1)
        outside = kept & ~inside
        ssr_in, gamma_in = fit_region(A, C, log_hn, y, weight, inside)[:2]
        ssr_out, gamma_out = fit_region(A, C, log_hn, y, weight, outside)[:2]
        n_in, n_out = int(inside.sum()), int(outside.sum())
        gain = (0.5 * n * math.log(one_region / n) - 0.5 * n_in * math.log(ssr_in / n_in)
                - 0.5 * n_out * math.log(ssr_out / n_out))
        rows_out.append({"box": (r0, r1, c0, c1), "zeta": zeta, "gain": gain, "penalty": 2.0 * math.log(zeta * n),
                         "gamma_in": gamma_in, "gamma_out": gamma_out, "n": n})
    return rows_out


def main(argv=None):
    from scipy.optimize import minimize

    from rjfit.data.coarsen import suggest_likelihood_power
    from rjfit.render.datasets import load_dataset

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", nargs="?", default="../shared/data/diligent-ball")
    parser.add_argument("--student-t", type=float, nargs="*", default=[], metavar="NU",
                        help="also the Student-t rows, one per degrees of freedom NU (about 3 min each)")
    parser.add_argument("--clip-margin", type=int, nargs="*", default=[], metavar="K",
                        help="also constant-noise rows without the observations within K px of a clipped pixel "
                             "of the same image (the highlight's peak), one row set per K")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    dataset = load_dataset(args.folder)
    obs = dataset.observations()
    y, A, C, log_hn, rows, cols = observation_arrays(obs)
    cos_hn = np.exp(log_hn)
    normals = dataset.normals.reshape(-1, 3)[obs.pixel].astype(float)
    lights = np.array([light.direction for light in dataset.lights], float)
    lights /= np.linalg.norm(lights, axis=1, keepdims=True)
    l_dir = lights[obs.light]
    h_dir = l_dir + np.array([0.0, 0.0, 1.0])
    h_dir /= np.linalg.norm(h_dir, axis=1, keepdims=True)
    everything = np.ones(y.size, bool)
    print(f"{args.folder}: {y.size:,} observations, {obs.object_mask.sum():,} pixels, loaded in "
          f"{time.perf_counter() - started:.0f} s")

    # one region, constant noise: the prediction and its gradient with respect to the normal
    ssr, g, a, b = fit_region(A, C, log_hn, y, np.ones_like(y), everything)
    mu = a * A + b * C * cos_hn ** g
    E = np.asarray(obs.irradiance, float)
    grad = (E * (a / math.pi + b * cos_hn ** g))[:, None] * l_dir \
        + (b * E * np.asarray(obs.cos_ln, float) * g * cos_hn ** (g - 1))[:, None] * h_dir
    grad -= np.sum(grad * normals, axis=1, keepdims=True) * normals       # tangential part
    slope = np.linalg.norm(grad, axis=1)
    resid = y - mu

    def negative_log_lik(p):
        var = np.exp(2 * p[0]) + np.exp(2 * p[1]) * slope ** 2
        return 0.5 * np.sum(np.log(var) + resid ** 2 / var)

    p = minimize(negative_log_lik, [math.log(np.std(resid)), math.log(0.02)], method="Nelder-Mead").x
    s0, sd_n = np.exp(p)
    print(f"one region: gamma {g:.4g}, rms {math.sqrt(ssr / y.size):.1f} ({100 * math.sqrt(ssr / y.size) / y.mean():.1f} % "
          f"of the mean); geometric noise fit: floor {s0:.1f}, normal-error sd {math.degrees(sd_n):.2f} deg")

    theta2 = np.arccos(np.minimum(cos_hn, 1.0)) ** 2

    def normal_error_variance(p):
        floor, sd = np.exp(p)
        sharp = g / max(1.0 - g * sd * sd, 1e-3)            # the lobe before the normal errors blur it
        spread = sharp * sd * sd
        e1 = np.exp(-sharp * theta2 / (2.0 * (1.0 + spread))) / (1.0 + spread)
        e2 = np.exp(-sharp * theta2 / (1.0 + 2.0 * spread)) / (1.0 + 2.0 * spread)
        return floor ** 2 + (b * C * (1.0 + spread)) ** 2 * np.maximum(e2 - e1 * e1, 0.0)

    def negative_log_lik_normal_error(p):
        var = normal_error_variance(p)
        return 0.5 * np.sum(np.log(var) + resid ** 2 / var)

    q = minimize(negative_log_lik_normal_error, [math.log(np.std(resid)), math.log(0.02)], method="Nelder-Mead").x
    print(f"normal-error noise fit: floor {math.exp(q[0]):.1f}, normal-error sd {math.degrees(math.exp(q[1])):.2f} deg")
    models = {"constant": (np.ones_like(y), everything),
              "geometric": (1.0 / np.sqrt(1.0 + (sd_n / s0) ** 2 * slope ** 2), everything),
              "normal error": (math.exp(q[0]) / np.sqrt(normal_error_variance(q)), everything)}
    if args.clip_margin:
        distance = clip_distance(dataset, obs)
        for margin in args.clip_margin:
            models[f"margin {margin}"] = (np.ones_like(y), distance > margin)
    print(f"\n{'noise':12s} {'zeta':>7s} {'box (rows, cols)':>26s} {'gain':>11s} {'gain x zeta':>12s} "
          f"{'penalty':>8s} {'gamma in / out':>16s} {'n':>10s}")
    for name, (weight, kept) in models.items():
        for row in split_evidence(obs, weight, kept):
            box = "{}-{}, {}-{}".format(*row["box"])
            print(f"{name:12s} {row['zeta']:7.4f} {box:>26s} {row['gain']:11.0f} {row['zeta'] * row['gain']:12.0f} "
                  f"{row['penalty']:8.1f} {row['gamma_in']:7.3g} / {row['gamma_out']:<7.3g} {row['n']:10,d}", flush=True)
    for nu in args.student_t:
        name = f"student-t {nu:g}"
        L1, g1, w1 = fit_region_student(A, C, log_hn, y, everything, nu)
        weight = np.sqrt(w1)
        zeta = suggest_likelihood_power(replace(obs, y=y * weight, irradiance=E * weight))["likelihood_power"]
        penalty = 4 * 0.5 * math.log(zeta * y.size)
        for r0, r1, c0, c1 in BOXES:
            inside = (rows >= r0) & (rows < r1) & (cols >= c0) & (cols < c1)
            LB, gB, _ = fit_region_student(A, C, log_hn, y, inside, nu)
            LO, gO, _ = fit_region_student(A, C, log_hn, y, ~inside, nu)
            gain = LB + LO - L1
            box = f"{r0}-{r1}, {c0}-{c1}"
            print(f"{name:12s} {zeta:7.4f} {box:>26s} {gain:11.0f} {zeta * gain:12.0f} {penalty:8.1f} "
                  f"{gB:7.3g} / {gO:<7.3g}", flush=True)
    print(f"\n{time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
