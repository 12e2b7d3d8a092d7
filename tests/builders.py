"""Builders shared by several test files: small data sets and problems made in code.

Each section belongs to the tests of one package; a builder used by one file only stays in
that file. (pytest puts this folder on sys.path: ``pythonpath = ["tests"]`` in pyproject.toml.)
"""
from __future__ import annotations

import importlib.util
import json
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import integrate, stats
from scipy.special import gammaln

from rjfit.data.exr import write_exr
from rjfit.data.formats import DATASET_FORMAT
from rjfit.data.observations import Observations
from rjfit.model.blinn import radiance
from rjfit.sampler.moves.region_proposals import sigma2_prior_as_invgamma, ssr_min
from rjfit.sampler.priors import ParamPrior, Prior
from rjfit.sampler.regions.changepoints.grid import pixel_region_labels
from rjfit.sampler.regions.materials.layout import boundary_count

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"     # ../shared beside the checkout (measured data)


def validation_script(name: str):
    """``validation/<name>.py`` as a module: validation/ on sys.path while it runs (a script imports the scripts
    beside it) and the module in sys.modules under ``name`` (a dataclass looks its module up there)."""
    folder = str(REPO_ROOT / "validation")
    sys.path.insert(0, folder)
    try:
        spec = importlib.util.spec_from_file_location(name, REPO_ROOT / "validation" / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(folder)
    return module

# == data: tiny photometric-stereo folders (16-bit PNGs) and rjfit-layout folders ======================

HEIGHT, WIDTH = 8, 10
DIRECTIONS = np.array([[0.0, 0.0, 1.0], [0.3, 0.3, 0.9], [-0.3, 0.2, 0.93], [0.2, -0.4, 0.89]])
DIRECTIONS /= np.linalg.norm(DIRECTIONS, axis=1, keepdims=True)
INTENSITIES = np.array([[1.0, 1.2, 1.5], [0.8, 1.0, 1.1], [1.3, 1.4, 2.0], [1.1, 0.9, 1.0]])


def sphere_geometry():
    """A disc mask and the unit normals of a sphere cap (x right, y up, z to the camera)."""
    rows, cols = np.mgrid[0:HEIGHT, 0:WIDTH]
    x, y = (cols - 4.5) / 4.5, -(rows - 3.5) / 4.5
    mask = x * x + y * y < 0.8
    normals = np.zeros((HEIGHT, WIDTH, 3))
    normals[..., 0], normals[..., 1] = x, y
    normals[..., 2] = np.sqrt(np.clip(1 - x * x - y * y, 0, None))
    normals[~mask] = 0.0
    return mask, normals


MASK_PIXELS = int(sphere_geometry()[0].sum())


def shading(mask, normals, seed=0):
    """Raw 16-bit RGB images (L, H, W, 3): Lambertian shading times intensity, plus noise."""
    rng = np.random.default_rng(seed)
    cos = np.clip(np.einsum("hwc,lc->lhw", normals, DIRECTIONS), 0, None) * mask
    raw = 20000.0 * cos[..., None] * INTENSITIES[:, None, None, :] + rng.integers(100, 300, cos.shape + (3,))
    return np.clip(raw, 0, 65535).astype(np.uint16)


def write_png(path, rgb):
    import cv2

    assert cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1]))


def write_lines(path, rows):
    Path(path).write_text("".join(" ".join(f"{v:.6g}" for v in row) + "\n" for row in rows))


def make_ps_folder(folder, *, images="png", normals_name="Normal_gt.mat"):
    """A valid DiLiGenT-style folder of four lights; returns it."""
    import scipy.io

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    mask, normals = sphere_geometry()
    raw = shading(mask, normals)
    raw[0, 3, 4] = 65535  # one saturated observation
    names = [f"{i + 1:03d}.{images}" for i in range(len(DIRECTIONS))]
    for name, image in zip(names, raw):
        if images == "png":
            write_png(folder / name, image)
        else:
            write_exr(folder / name, {c: image[..., i].astype(np.float32) for i, c in enumerate("RGB")})
    (folder / "filenames.txt").write_text("".join(name + "\n" for name in names))
    write_lines(folder / "light_directions.txt", DIRECTIONS)
    write_lines(folder / "light_intensities.txt", INTENSITIES)
    write_png(folder / "mask.png", np.repeat((mask * 255).astype(np.uint8)[..., None], 3, axis=-1))
    if normals_name.endswith(".mat"):
        scipy.io.savemat(folder / normals_name, {"Normal_gt": normals})
    else:
        np.save(folder / normals_name, normals)
    return folder


def make_rjfit_folder(folder, *, lights=None, full=False):
    """A valid rjfit-layout data set (dataset.json, EXR images, geometry.exr) of point lights.

    ``full``: also what a rendered data set has: camera, reference intensity, two materials,
    a mesh part per material, visibility.exr and truth_labels.exr (left half 0, right half 1).
    """
    folder = Path(folder)
    mask, normals = sphere_geometry()
    lights = lights or [{"kind": "point", "intensity": 10.0, "position": [0.0, 0.0, 5.0]},
                        {"kind": "point", "intensity": 10.0, "position": [2.0, 1.0, 4.0]}]
    images = []
    for index in range(len(lights)):
        name = f"images/light_{index:03d}.exr"
        write_exr(folder / name, {c: np.full((HEIGHT, WIDTH), 0.5, np.float32) for c in "RGB"})
        images.append(name)
    channels = {f"{p}.{a}": normals[..., i] for p in "PN" for i, a in enumerate("XYZ")}
    channels.update({"V.X": np.zeros((HEIGHT, WIDTH)), "V.Y": np.zeros((HEIGHT, WIDTH)),
                     "V.Z": np.ones((HEIGHT, WIDTH)), "mask": mask.astype(np.float32)})
    write_exr(folder / "geometry.exr", channels)
    meta = {"format": DATASET_FORMAT, "lights": lights, "images": images, "resolution": [HEIGHT, WIDTH],
            "geometry": "geometry.exr"}
    if full:
        import trimesh

        (folder / "meshes").mkdir()
        for part in range(2):
            trimesh.creation.box().export(folder / f"meshes/part_{part:03d}.ply")
        write_exr(folder / "visibility.exr", {f"light_{i:03d}": np.ones((HEIGHT, WIDTH)) for i in range(len(lights))})
        labels = np.where(mask, (np.arange(WIDTH) >= WIDTH // 2)[None, :].astype(float), -1.0)
        write_exr(folder / "truth_labels.exr", {"label": labels})
        meta.update({
            "camera": {"kind": "orthographic", "origin": [0, 0, 8], "target": [0, 0, 0], "up": [0, 1, 0],
                       "half_width": 1.2},
            "reference_intensity": 10.0,
            "materials": [{"name": "left", "I0": 10.0, "kd": 0.5, "gamma": 8.0, "sigma2": 0.0},
                          {"name": "right", "I0": 5.0, "kd": 0.9, "gamma": 20.0, "sigma2": 0.0}],
            "meshes": [{"file": f"meshes/part_{part:03d}.ply", "material": part, "faces": 12} for part in range(2)],
            "visibility": "visibility.exr", "truth_labels": "truth_labels.exr", "max_depth": 8, "saturation": None})
    (folder / "dataset.json").write_text(json.dumps(meta))
    return folder


def edit_description(folder, edit):
    """Apply ``edit(meta)`` to the folder's dataset.json (``edit`` may return a replacement)."""
    path = Path(folder) / "dataset.json"
    meta = json.loads(path.read_text())
    replaced = edit(meta)
    path.write_text(json.dumps(meta if replaced is None else replaced))
    return path


def raises(error, *parts):
    """``pytest.raises`` whose message must contain each of ``parts`` (literal text), in order."""
    return pytest.raises(error, match=".*".join(re.escape(str(part)) for part in parts))


def smooth_shading_observations(shape, n_lights, reflected, *, cos_ln_mean=0.65):
    """Every pixel of an object filling ``shape`` seen under every one of ``n_lights`` lights, its shading smooth
    across neighbouring pixels as a real surface's is: ``<l.n> = cos_ln_mean + 0.3 sin(0.25 col + 0.15 row + light)``,
    ``<h.n> = 0.8 + 0.15 cos(0.2 col - 0.1 row + 2 light)``, irradiance 1. ``reflected(col, cos_ln, cos_hn)`` gives
    the observations' values (noise included)."""
    height, width = shape
    pixel = np.repeat(np.arange(height * width), n_lights)
    light = np.tile(np.arange(n_lights), height * width)
    row, col = pixel // width, pixel % width
    cos_ln = cos_ln_mean + 0.3 * np.sin(0.25 * col + 0.15 * row + light)
    cos_hn = 0.8 + 0.15 * np.cos(0.2 * col - 0.1 * row + 2 * light)
    return Observations(image_shape=shape, n_lights=n_lights, pixel=pixel.astype(np.int64),
                        light=light.astype(np.int32), y=reflected(col, cos_ln, cos_hn), cos_ln=cos_ln, cos_hn=cos_hn,
                        irradiance=np.ones(pixel.size), object_mask=np.ones(shape, bool))


# == sampler (tests/sampler/): the exactness tests by enumeration and by simulation-based calibration ==

#: (shape, scale) of the inverse-gamma prior of sigma^2 in :func:`tiny_problem`'s prior.
TINY_SIGMA2_PRIOR = (3.0, 0.6)


def tiny_problem(seed=5, width=2):
    """A 2 x ``width`` image under 3 lights (12 observations for width 2) of two regions split down the middle
    (the left half of the columns, rounded up, and the rest), and a proper prior.

    The regions' truth is ``(I0, kd, gamma, sigma^2) = (10, 0.75, 4, 0.3)`` left and
    ``(10, 0.3, 15, 0.3)`` right; the prior is lognormal around the truth's I0 and gamma,
    uniform kd and inverse-gamma :data:`TINY_SIGMA2_PRIOR` sigma^2 (so sigma^2 integrates
    out analytically in the enumeration tests). Returns ``(observations, prior)``.
    """
    rng = np.random.default_rng(seed)
    H, W, L = 2, width, 3
    pixel = np.repeat(np.arange(H * W), L)
    light = np.tile(np.arange(L), H * W).astype(np.int32)
    cos_ln = rng.uniform(0.3, 1.0, pixel.size)
    cos_hn = rng.uniform(0.6, 1.0, pixel.size)
    irradiance = rng.uniform(0.5, 1.5, pixel.size)
    col = pixel % W
    truth = np.array([[10.0, 0.75, 4.0, 0.3], [10.0, 0.3, 15.0, 0.3]])[(2 * col >= W).astype(int)]
    mu = radiance(truth[:, 0], truth[:, 1], truth[:, 2], cos_ln, cos_hn, irradiance)
    y = mu + rng.normal(0, np.sqrt(0.3), pixel.size)
    obs = Observations(image_shape=(H, W), n_lights=L, pixel=pixel.astype(np.int64), light=light, y=y,
                       cos_ln=cos_ln, cos_hn=cos_hn, irradiance=irradiance, object_mask=np.ones((H, W), bool))
    prior = Prior(params=(ParamPrior("lognormal", np.log(10.0), 0.3), ParamPrior("uniform", 0.0, 1.0),
                          ParamPrior("lognormal", np.log(8.0), 0.6), ParamPrior("invgamma", *TINY_SIGMA2_PRIOR)))
    return obs, prior


#: (I0 per channel, kd per channel) of the two regions of :func:`tiny_colour_problem` (gamma 4 left, 15 right)
TINY_COLOUR_TRUTH = (((9.0, 11.0, 10.0), (0.75, 0.5, 0.6)), ((11.0, 9.0, 10.0), (0.3, 0.45, 0.35)))


def tiny_colour_problem(seed=5, width=2):
    """:func:`tiny_problem`'s image, geometry and prior, observed in three channels (a joint colour fit).

    Region left: gamma 4, right: gamma 15; per channel the I0 and kd of
    :data:`TINY_COLOUR_TRUTH`, sigma^2 0.3. Returns ``(per-channel observations, stacked
    observations, prior)`` (:func:`rjfit.data.observations.stack_channels`).
    """
    from rjfit.data.observations import stack_channels

    base, prior = tiny_problem(seed=seed, width=width)
    rng = np.random.default_rng(seed + 100)
    left = (2 * (base.pixel % width) < width)
    per_channel = []
    for c in range(3):
        I0 = np.where(left, TINY_COLOUR_TRUTH[0][0][c], TINY_COLOUR_TRUTH[1][0][c])
        kd = np.where(left, TINY_COLOUR_TRUTH[0][1][c], TINY_COLOUR_TRUTH[1][1][c])
        gamma = np.where(left, 4.0, 15.0)
        mu = radiance(I0, kd, gamma, base.cos_ln, base.cos_hn, base.irradiance)
        y = mu + rng.normal(0, np.sqrt(0.3), mu.size)
        per_channel.append(Observations(image_shape=base.image_shape, n_lights=base.n_lights, pixel=base.pixel,
                                        light=base.light, y=y, cos_ln=base.cos_ln, cos_hn=base.cos_hn,
                                        irradiance=base.irradiance, object_mask=base.object_mask))
    return per_channel, stack_channels(per_channel), prior


class Quadrature:
    """Evidence of any subset of observations, and parameter marginals, on a phi grid (the enumeration tests' oracle).

    sigma^2 has :func:`tiny_problem`'s inverse-gamma prior :data:`TINY_SIGMA2_PRIOR` and is
    integrated analytically; I0, kd, gamma by the trapezoid rule on a 3-D grid in the
    sampler's phi coordinates (``points`` per axis). ``likelihood_power``: the likelihood
    raised to it (coarsened posterior).
    """

    def __init__(self, obs, prior, points=81, likelihood_power=1.0):
        self.power = likelihood_power
        a0, s0 = prior.params[0].a, prior.params[0].b
        a2, s2 = prior.params[2].a, prior.params[2].b
        self.axes = [np.linspace(a0 - 6 * s0, a0 + 6 * s0, points), np.linspace(-14, 14, points),
                     np.linspace(a2 - 6 * s2, a2 + 6 * s2, points)]
        g0, g1, g2 = np.meshgrid(*self.axes, indexing="ij")
        phi = np.stack([g0, g1, g2, np.zeros_like(g0)], axis=-1)
        self.log_prior = prior.logpdf_phi_components(phi)[..., :3].sum(-1)
        I0, kd, g = np.exp(g0), 1 / (1 + np.exp(-g1)), np.exp(g2)
        self.sq = np.stack([(obs.y[i] - radiance(I0, kd, g, obs.cos_ln[i], obs.cos_hn[i], obs.irradiance[i])) ** 2
                            for i in range(obs.n_obs)])
        self.weights = [np.gradient(ax) for ax in self.axes]   # trapezoid weights on a uniform grid
        for w in self.weights:
            w[0] *= 0.5 / 1.0
            w[-1] *= 0.5 / 1.0
        self.pixel = np.asarray(obs.pixel)
        self._cache = {}

    def _log_integrand(self, obs_idx):
        # likelihood ** zeta: n and SSR scaled by zeta (sigma^2 still integrates analytically)
        n = self.power * len(obs_idx)
        ssr = self.power * self.sq[obs_idx].sum(0)
        alpha, beta = TINY_SIGMA2_PRIOR
        log_inner = (-0.5 * n * np.log(2 * np.pi) + alpha * np.log(beta) - gammaln(alpha) + gammaln(alpha + n / 2)
                     - (alpha + n / 2) * np.log(beta + ssr / 2))
        return self.log_prior + log_inner, ssr

    def log_evidence(self, pixels):
        key = frozenset(int(p) for p in pixels)
        if not key:
            return 0.0
        if key not in self._cache:
            f, _ = self._log_integrand(np.flatnonzero(np.isin(self.pixel, list(key))))
            m = f.max()
            w = self.weights[0][:, None, None] * self.weights[1][None, :, None] * self.weights[2][None, None, :]
            self._cache[key] = float(m + np.log(np.sum(np.exp(f - m) * w)))
        return self._cache[key]

    def marginal_cdfs(self, pixels, with_sigma2=True):
        """CDFs of I0, kd, gamma, sigma^2 (the last only ``with_sigma2``) for the region made of ``pixels``."""
        idx = np.flatnonzero(np.isin(self.pixel, list(pixels)))
        f, ssr = self._log_integrand(idx)
        w = self.weights[0][:, None, None] * self.weights[1][None, :, None] * self.weights[2][None, None, :]
        p = np.exp(f - f.max()) * w
        p /= p.sum()
        cdfs = []
        for k, transform in enumerate((np.exp, lambda x: 1 / (1 + np.exp(-x)), np.exp)):
            marginal = p.sum(axis=tuple(j for j in range(3) if j != k))
            # trapezoid mass between grid nodes -> piecewise-linear CDF on the transformed nodes
            cdf = np.concatenate([[0.0], np.cumsum(0.5 * (marginal[1:] + marginal[:-1]))])
            cdf /= cdf[-1]
            nodes = transform(self.axes[k])
            cdfs.append(lambda x, nodes=nodes, cdf=cdf: np.interp(x, nodes, cdf))
        if not with_sigma2:
            return cdfs
        shape, scale = TINY_SIGMA2_PRIOR[0] + self.power * len(idx) / 2, TINY_SIGMA2_PRIOR[1] + ssr / 2
        flat_p, flat_scale = p.ravel(), scale.ravel()
        keep = flat_p > 1e-8 * flat_p.max()
        flat_p, flat_scale = flat_p[keep] / flat_p[keep].sum(), flat_scale[keep]
        # the sigma^2 marginal is a mixture of inverse gammas: tabulate its CDF, interpolate
        lo = stats.invgamma.ppf(1e-9, shape, scale=flat_scale.min())
        hi = stats.invgamma.ppf(1 - 1e-9, shape, scale=flat_scale.max())
        nodes = np.geomspace(lo, hi, 400)
        table = np.array([np.dot(flat_p, stats.invgamma.cdf(x, shape, scale=flat_scale)) for x in nodes])
        cdfs.append(lambda x: np.interp(x, nodes, table))
        return cdfs


def ess_scaled_chi2(cells, draws, probs):
    """Chi-square p-value of ``draws`` (cell index per iteration) against ``probs``, scaled by the ESS.

    ``X^2 = N_eff sum (p_hat - p)^2 / p`` with N_eff the smallest ArviZ bulk ESS of the cell
    indicators (chain draws are autocorrelated), df = cells - 1. A chain that never left one
    cell has no ESS: it counts as one effective draw (the most lenient reading). Returns
    ``(p_value, frequencies, n_eff)``.
    """
    import arviz as az

    freq = np.array([np.mean(draws == c) for c in cells])
    n_eff = min((float(az.ess((draws == c).astype(float)[None], method="bulk")) for c in cells
                 if 0 < np.mean(draws == c) < 1), default=1.0)
    x2 = n_eff * np.sum((freq - probs) ** 2 / probs)
    return float(stats.chi2.sf(x2, len(cells) - 1)), freq, n_eff


#: probabilities of the three change-point intervals of [-1, 3] in the enumeration below
INTERVALS = np.array([1.5, 1.0, 1.5]) / 4.0   # probabilities of the three intervals of [-1, 3]


CP_SMOOTH_SD = 1.0   # sd of the smooth change-point prior in the enumeration below (the tests set cp_smooth_sd to it)
CP_EDGES = np.array([-1.0, 0.5, 1.5, 3.0])   # interval edges of the change points of a 2 x 2 image


def interval_pair_log_weight(a, b, cp_prior):
    """Log prior mass of a 2-element vector with elements in intervals a and b."""
    if cp_prior == "paper":
        return float(np.log(INTERVALS[a]) + np.log(INTERVALS[b]))
    # smooth prior: x0 ~ U(-1, 3) (density 1/4), x1 - x0 ~ N(0, s^2), both truncated to [-1, 3] (unnormalised)
    def inner(x0):
        upper = stats.norm.cdf((CP_EDGES[b + 1] - x0) / CP_SMOOTH_SD)
        return (upper - stats.norm.cdf((CP_EDGES[b] - x0) / CP_SMOOTH_SD)) / 4.0

    value, _ = integrate.quad(inner, CP_EDGES[a], CP_EDGES[a + 1], epsabs=1e-13, epsrel=1e-11)
    return float(np.log(value))


def exact_changepoint_posterior(quad, jacobian_power=None, cp_prior="paper", log_norm=False):
    """Exact posterior over (model, u interval of row 0) and over models, for the 2 x 2 image
    of :func:`tiny_problem` with at most one change-point vector per direction.

    ``jacobian_power``: if given, weight each model by 3^(-4 * splits) with ``splits`` the
    number of region splits needed to reach it from (0, 0): the posterior that a chain
    dropping the paper map's Jacobian (|det| = 3 per component) targets instead.
    ``log_norm``: also return the log of the normaliser (the data's evidence), as a pair.
    """
    H = W = 2
    joint = {}
    for n_u in (0, 1):
        for n_v in (0, 1):
            for cu in np.ndindex(*(3,) * (H * n_u)):
                for cv in np.ndindex(*(3,) * (W * n_v)):
                    u = np.array([[(-1.0, 1.0, 2.0)[k]] for k in cu]).reshape(H, n_u)
                    v = np.array([[(-1.0, 1.0, 2.0)[k]] for k in cv]).reshape(W, n_v)
                    labels = pixel_region_labels(u, v, (H, W)).ravel()
                    log_w = np.log(0.25)
                    if n_u:
                        log_w += interval_pair_log_weight(cu[0], cu[1], cp_prior)
                    if n_v:
                        log_w += interval_pair_log_weight(cv[0], cv[1], cp_prior)
                    log_w += sum(quad.log_evidence(np.flatnonzero(labels == r)) for r in range((n_u + 1) * (n_v + 1)))
                    if jacobian_power is not None:
                        splits = {(0, 0): 0, (1, 0): 1, (0, 1): 1, (1, 1): 3}[(n_u, n_v)]
                        log_w -= jacobian_power * splits
                    key = (n_u, n_v, cu[0] if n_u else -1)
                    joint[key] = np.logaddexp(joint.get(key, -np.inf), log_w)
    keys = sorted(joint)
    log_w = np.array([joint[k] for k in keys])
    norm = np.logaddexp.reduce(log_w)
    prob = dict(zip(keys, np.exp(log_w - norm)))
    return (prob, float(norm)) if log_norm else prob


def set_partitions(n):
    """Every set partition of n items as a restricted growth string (first appearance order)."""
    if n == 0:
        yield ()
        return
    for rest in set_partitions(n - 1):
        for label in range(max(rest, default=-1) + 2):
            yield rest + (label,)


def canonical(labels):
    """A labelling's partition: labels renumbered in order of first appearance."""
    seen = {}
    return tuple(seen.setdefault(int(z), len(seen)) for z in labels)


def exact_partition_posterior(quad, shape, beta, rho, n_blocks=None, max_blocks=None, log_norm=False):
    """{partition: probability} over the partitions of the pixels of ``shape`` (optionally K fixed or capped)
    under the material model's prior (Potts beta, rho per material); with ``log_norm`` also the log
    of the sum of the unnormalised weights (the evidence up to the prior's partition-free constant)."""
    log_w = {}
    for part in set_partitions(shape[0] * shape[1]):
        k = max(part) + 1
        if (n_blocks is not None and k != n_blocks) or (max_blocks is not None and k > max_blocks):
            continue
        z = np.array(part).reshape(shape)
        log_w[part] = (k * np.log(rho) - beta * boundary_count(z)
                       + sum(quad.log_evidence(np.flatnonzero(z.ravel() == b)) for b in range(k)))
    values = np.array(list(log_w.values()))
    total = float(np.logaddexp.reduce(values))
    probs = dict(zip(log_w, np.exp(values - total)))
    return (probs, total) if log_norm else probs


def laplace_objective(data, prior, count_of=None):
    """The region proposals' Laplace objective h(l) of ``data``'s sums (the count of ``count_of``, default
    ``data``), evaluated from its definition: ``ssr_min`` of the statistics at each gamma."""
    a0, b0 = sigma2_prior_as_invgamma(prior)
    count_of = data if count_of is None else count_of
    k = 0.5 * count_of.n * count_of.weight - 1.0 + a0

    def h(ell):
        ssr, det = ssr_min(data.stats_at(math.exp(ell)))
        return -k * math.log(0.5 * ssr + b0) - 0.5 * math.log(det) + prior.params[2].logpdf_scalar(math.exp(ell)) + ell
    return h


def parabola_at_grid_max(h, centre, scale, half_width, points):
    """(mode, sd) of ``h`` from the parabola through the best three of ``points`` on ``centre +- half_width
    scale``; the best point must lie inside the grid."""
    grid = centre + scale * np.linspace(-half_width, half_width, points)
    values = np.array([h(e) for e in grid])
    best = int(np.argmax(values))
    assert 0 < best < grid.size - 1
    c2, c1, _ = np.polyfit(grid[best - 1:best + 2] - grid[best], values[best - 1:best + 2], 2)
    return grid[best] - c1 / (2 * c2), 1.0 / np.sqrt(-2 * c2)

# == criticism (rjfit.diagnose): hidden-effect data sets and fit folders for `rjfit diagnose` ========

def hidden_data_sets(tmp_path_factory, resolution=32):
    """A function ``get(kind)`` that renders the hidden-effect data set ``kind``
    (:func:`rjfit.render.hidden.render_hidden`, e.g. "ambient", "ambient+light_calibration") at
    ``resolution`` once, into a folder of ``tmp_path_factory``, and returns its path: a
    module-scoped fixture returns it so that each kind is rendered once per test file."""
    from rjfit.render.hidden import render_hidden

    cache = {}

    def get(kind):
        if kind not in cache:
            folder = tmp_path_factory.mktemp(kind.replace("+", "_")) / "dataset"
            cache[kind] = render_hidden(kind, folder, resolution=resolution)
        return cache[kind]
    return get


def truth_fit_folder(dataset_path, folder: Path) -> Path:
    """A fit folder as ``rjfit fit`` leaves it for ``rjfit diagnose``: ``summary.json`` naming the
    data set and ``map_labels.exr`` holding its TRUTH labels as the MAP segmentation (created)."""
    from rjfit.data.exr import write_exr
    from rjfit.render.datasets import load_dataset

    folder.mkdir()
    (folder / "summary.json").write_text(json.dumps({"dataset": str(dataset_path)}))
    write_exr(folder / "map_labels.exr", {"labels": load_dataset(dataset_path).truth_labels.astype(float)})
    return folder


def data_diagnose_sees(dataset, summary: dict, folder: Path, monkeypatch):
    """The data set ``rjfit diagnose`` hands its workflow for a fit whose ``summary.json`` holds
    ``summary`` (and the channel, mean), one material as its MAP labels: the workflow itself is
    replaced by a recorder, so only ``diagnose_fit``'s preparation of the data runs."""
    import rjfit.pipeline.diagnose as pipeline_diagnose

    fit_dir = folder / "fit"
    fit_dir.mkdir()
    (fit_dir / "summary.json").write_text(json.dumps({"channel": "mean", **summary}))
    write_exr(fit_dir / "map_labels.exr", {"labels": np.where(dataset.object_mask, 0.0, -1.0).astype(np.float32)})
    seen = {}
    monkeypatch.setattr(pipeline_diagnose, "diagnose", lambda data, labels, out, **options: seen.update(data=data))
    pipeline_diagnose.diagnose_fit(fit_dir, folder / "diagnosis", dataset=dataset)
    return seen["data"]


def perturbed_normals(normals, mask, degrees, seed):
    """Unit normals turned by an isotropic tangential error of ``degrees`` sd per direction."""
    rng = np.random.default_rng(seed)
    first = np.cross(normals, [0.0, 0.0, 1.0])
    first /= np.maximum(np.linalg.norm(first, axis=-1, keepdims=True), 1e-12)
    second = np.cross(normals, first)
    error = np.radians(degrees) * rng.standard_normal(normals.shape[:2] + (2,))
    turned = normals + error[..., :1] * first + error[..., 1:] * second
    turned /= np.maximum(np.linalg.norm(turned, axis=-1, keepdims=True), 1e-12)
    return np.where(mask[..., None], turned, normals)


#: the paint's factor on the albedo and the shadow's per light in :func:`paint_and_shadow_observations`
PAINT_FACTOR = 0.3
SHADOW_FACTORS = np.array([1.0, 0.2, 0.5, 1.0, 0.35, 0.8])


def paint_and_shadow_observations(shape=(20, 24), curved: bool = False):
    """Observations of a Lambertian patch under 6 lights of different strengths, albedo 0.7, with a painted square
    (rows 4-8, columns 4-8; PAINT_FACTOR x the albedo) and a shadowed one (rows 10-15, columns 14-19; SHADOW_FACTORS
    per light, on the intensity, not on the shading ``E <l.n>``); one observation of the paint and one of its
    surroundings left out, as a flagged cast shadow is. Flat (``cos_ln`` 1: every pixel sees each light alike), or
    ``curved``: a cylinder along the columns whose ``cos_ln`` changes across them differently under each light.
    Returns ``(observations, labels)``, ``labels`` 0 body, 1 paint, 2 shadow, -1 off the object (the last column)."""
    lights = SHADOW_FACTORS.size
    labels = np.zeros(shape, int)
    labels[4:9, 4:9] = 1
    labels[10:16, 14:20] = 2
    labels[:, -1] = -1
    strength = np.linspace(0.5, 2.0, lights)
    pixel = np.repeat(np.flatnonzero(labels.ravel() >= 0), lights)
    light = np.tile(np.arange(lights), pixel.size // lights)
    column = pixel % shape[1]
    cos_ln = (np.clip(np.cos(0.12 * (column - shape[1] / 2) - np.linspace(-0.9, 0.9, lights)[light]), 0.05, 1.0)
              if curved else np.ones(pixel.size))
    material = labels.ravel()[pixel]
    y = (0.7 / np.pi * strength[light] * cos_ln * np.where(material == 1, PAINT_FACTOR, 1.0)
         * np.where(material == 2, SHADOW_FACTORS[light], 1.0))
    dropped = [np.flatnonzero((pixel == 6 * shape[1] + 6) & (light == 2))[0],
               np.flatnonzero((pixel == 2 * shape[1] + 2) & (light == 3))[0]]
    keep = np.setdiff1d(np.arange(pixel.size), dropped)
    obs = Observations(image_shape=shape, n_lights=lights, pixel=pixel[keep].astype(np.int64),
                       light=light[keep].astype(np.int32), y=y[keep], cos_ln=cos_ln[keep],
                       cos_hn=np.full(keep.size, 0.5), irradiance=strength[light[keep]], object_mask=labels >= 0)
    return obs, labels
