"""The Mitsuba side of the effects: a plugin variant, rendering a fitted (extended) model, the
indirect-radiance feature, and the cross-check gate for extended models.

``rjfit_blinn_ext`` is rjfit's plugin (``rjfit.render.plugin``) with two more parameters on the
specular lobe, implemented separately from the numpy closed form (drjit, in the BSDF):

    f = scale ( kd/pi + (1 - kd) N(g) <h.n>^g F(<h.v>)/F0 ((1 - w) + w G1(v) G1(l)) )

``f0`` (default 1: no Fresnel) and ``mask_w`` (default 0: no masking), both traverse-able and
opaque. Sampling is the plugin's (the lobe factors are <= 1/F0 and smooth, so the Blinn
importance sampling stays valid; only its efficiency changes).
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from rjfit.data.lights import Light

__all__ = ["EXT_PLUGIN_NAME", "register_ext", "materials_for_parts", "model_scene", "render_model", "indirect_radiance",
           "gate"]

EXT_PLUGIN_NAME = "rjfit_blinn_ext"
STOCHASTIC_RATIO = 1.5
# purpose tags of the diagnosis' path-tracing streams (rjfit.render.mitsuba_scene.mitsuba_seed)
MODEL_STREAM, ENVIRONMENT_STREAM, INDIRECT_STREAM = 11, 12, 13
_REGISTERED: dict = {}


def register_ext():
    """Register ``rjfit_blinn_ext`` for the active variant (idempotent); return its class."""
    import drjit as dr
    import mitsuba as mi
    from mitsuba.mitsuba_ext import ParamFlags

    from rjfit.render.plugin import register

    variant = mi.variant()
    if variant in _REGISTERED:
        return _REGISTERED[variant]
    base = register()
    m = getattr(mi, variant)
    inv_pi = 1.0 / math.pi

    def smith_g1(cos_theta, alpha):
        cos_theta = dr.clip(cos_theta, 1e-6, 1.0)
        tan_theta = dr.safe_sqrt(1.0 - cos_theta * cos_theta) / cos_theta
        a = 1.0 / dr.maximum(alpha * tan_theta, 1e-12)
        g = (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)
        return dr.select(a >= 1.6, 1.0, g)

    class RjfitBlinnExtBSDF(base):
        def __init__(self, props):
            base.__init__(self, props)
            f0 = float(props.get("f0", 1.0))
            mask_w = float(props.get("mask_w", 0.0))
            if not (0.0 < f0 <= 1.0) or not (0.0 <= mask_w <= 1.0):
                raise ValueError(f"{EXT_PLUGIN_NAME}: need 0 < f0 <= 1 and 0 <= mask_w <= 1, got {f0}, {mask_w}")
            self.f0 = m.Float(f0)
            self.mask_w = m.Float(mask_w)
            dr.make_opaque(self.f0, self.mask_w)

        def traverse(self, callback):
            base.traverse(self, callback)
            callback.put("f0", self.f0, ParamFlags.Differentiable)
            callback.put("mask_w", self.mask_w, ParamFlags.Differentiable)

        def parameters_changed(self, keys=None):
            base.parameters_changed(self, keys)
            dr.make_opaque(self.f0, self.mask_w)

        def _eval_pdf(self, ctx, si, wo, active):
            has_diffuse, has_glossy, prob_d = self._lobe_probabilities(ctx)
            cos_i = m.Frame3f.cos_theta(si.wi)
            cos_o = m.Frame3f.cos_theta(wo)
            active = active & (cos_i > 0.0) & (cos_o > 0.0)
            h = dr.normalize(si.wi + wo)
            cos_h = dr.maximum(m.Frame3f.cos_theta(h), 0.0)
            g = self.gamma
            cos_h_pow_g = dr.power(cos_h, g)
            value = m.Float(0.0)
            pdf = m.Float(0.0)
            if has_diffuse:
                value += self.kd * inv_pi
                pdf += prob_d * cos_o * inv_pi
            if has_glossy:
                norm = (g + 2.0) * (g + 4.0) / ((8.0 * math.pi) * (dr.exp2(-0.5 * g) + g))
                cos_hv = dr.clip(dr.dot(h, si.wi), 0.0, 1.0)
                one_minus = 1.0 - cos_hv
                fresnel = 1.0 + (1.0 / self.f0 - 1.0) * (one_minus * one_minus) * (one_minus * one_minus) * one_minus
                alpha = dr.sqrt(2.0 / (g + 2.0))
                masking = (1.0 - self.mask_w) + self.mask_w * smith_g1(cos_i, alpha) * smith_g1(cos_o, alpha)
                value += (1.0 - self.kd) * norm * cos_h_pow_g * fresnel * masking
                pdf_h = (g + 1.0) * (0.5 / math.pi) * cos_h_pow_g
                wo_dot_h = dr.dot(wo, h)
                pdf += (1.0 - prob_d) * dr.select(wo_dot_h > 0.0, pdf_h / (4.0 * wo_dot_h), 0.0)
            value = self.scale * value * cos_o
            return dr.select(active, value, 0.0), dr.select(active, pdf, 0.0)

    m.register_bsdf(EXT_PLUGIN_NAME, lambda props: RjfitBlinnExtBSDF(props))
    _REGISTERED[variant] = RjfitBlinnExtBSDF
    return RjfitBlinnExtBSDF


def trace_centre_rays(scene, spp=1, seed=0):
    """Radiance along the pixel-centre rays, ``spp`` samples per pixel in ONE wavefront.

    ``seed``: an int or a sequence of ints, the keys of the sampler's stream
    (:func:`rjfit.render.mitsuba_scene.mitsuba_seed`).

    The same rays as ``rjfit.render.mitsuba_scene.path_trace`` (pixel centres, shared by the
    data set's geometry), but all samples are traced in a single kernel launch instead of one
    launch per sample: what makes hundreds of samples per pixel affordable for Monte Carlo
    terms (an environment emitter, indirect light). Returns (H, W) channel means.
    """
    import drjit as dr
    import mitsuba as mi

    sensor = scene.sensors()[0]
    width, height = sensor.film().size()
    n_pix = int(width) * int(height)
    index = dr.arange(mi.UInt32, n_pix * int(spp)) % n_pix
    film_position = mi.Point2f((mi.Float(index % width) + 0.5) / width, (mi.Float(index // width) + 0.5) / height)
    rays, _ = sensor.sample_ray(mi.Float(0.0), mi.Float(0.5), film_position, mi.Point2f(0.5, 0.5))
    from rjfit.render.mitsuba_scene import mitsuba_seed

    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(mitsuba_seed(*np.atleast_1d(seed)), n_pix * int(spp))
    radiance, _, _ = scene.integrator().sample(scene, sampler, rays, None, True)
    values = np.array(radiance, dtype=np.float64)
    values = values.reshape(-1, n_pix * int(spp)).mean(axis=0) if values.ndim > 1 else values
    return values.reshape(int(spp), int(height), int(width)).mean(axis=0)


def _mesh_material_map(dataset):
    """(H, W) mesh material index per pixel (truth labels of a rendered data set, else traced)."""
    if dataset.truth_labels is not None:
        return dataset.truth_labels
    from rjfit.render.mitsuba_scene import trace_pixels
    from rjfit.render.render import scene_from_dataset_meta

    scene = scene_from_dataset_meta(dataset.meta, dataset.path, lights=[])
    return trace_pixels(scene, [e["material"] for e in dataset.meta["meshes"]])["material"]


def materials_for_parts(ctx, region_params):
    """``{I0, kd, gamma}`` per mesh material index from the fit's regions.

    A Mitsuba BSDF is constant per mesh part, the fit's regions are pixel sets: each mesh
    material gets the parameters of the region covering most of its pixels (exact when the
    segmentation follows the parts, e.g. the truth labels or a good MAP segmentation).
    For a data set without materials (a measured mesh stack) see :func:`model_scene`.
    """
    region_params = np.asarray(region_params, dtype=float)
    parts = _mesh_material_map(ctx.dataset)
    n_materials = max(e["material"] for e in ctx.dataset.meta["meshes"]) + 1
    fallback = np.median(region_params[:, :3], axis=0)
    out = []
    for material in range(n_materials):
        regions = ctx.labels[(parts == material) & (ctx.labels >= 0)]
        params = region_params[np.bincount(regions).argmax(), :3] if regions.size else fallback
        out.append({"I0": float(params[0]), "kd": float(params[1]), "gamma": float(params[2])})
    return out


def _region_parts(ctx):
    """A measured data set's mesh cut into one part per fit region: (data set, temporary folder).

    Each face of the mesh as Mitsuba loads it (positions, shading normals and faces taken from
    the loaded shape, so the geometry is unchanged) takes the region of the nearest traced
    pixel-centre point of the object; the parts are written as PLY files into a temporary
    folder that lives as long as the returned object, and the data set returned names them as
    its ``meshes`` (material = region index).
    """
    import dataclasses
    import tempfile

    import mitsuba as mi
    from scipy.spatial import cKDTree

    from rjfit.data.meshes import split_by_face_label
    from rjfit.render.mitsuba_scene import activate
    from rjfit.render.render import scene_from_dataset_meta

    activate()
    dataset = ctx.dataset
    labelled = (ctx.labels >= 0) & dataset.object_mask
    tree = cKDTree(dataset.positions[labelled])
    folder = tempfile.TemporaryDirectory(prefix="rjfit-regions-")
    meshes = []
    for shape in scene_from_dataset_meta(dataset.meta, dataset.path, lights=[]).shapes():
        params = mi.traverse(shape)
        vertices = np.array(params["vertex_positions"], dtype=np.float64).reshape(-1, 3)
        normals = np.array(params["vertex_normals"], dtype=np.float64).reshape(-1, 3)
        faces = np.array(params["faces"], dtype=np.int64).reshape(-1, 3)
        face_region = ctx.labels[labelled][tree.query(vertices[faces].mean(axis=1))[1]]
        for mesh, region in split_by_face_label(vertices, faces, normals, face_region):
            meshes.append({"file": str(Path(folder.name) / f"part_{len(meshes):03d}.ply"), "material": region})
            mesh.export(meshes[-1]["file"], file_type="ply", vertex_normal=True)
    return dataclasses.replace(dataset, meta=dict(dataset.meta, meshes=meshes)), folder


def model_scene(ctx, region_params):
    """The data set to render the fitted model on, and its materials (``{I0, kd, gamma}``).

    A rendered data set's mesh parts are its materials: :func:`materials_for_parts`. A data
    set without materials (a measured mesh stack: one mesh) is cut into one part per fit
    region (:func:`_region_parts`, once per context), each region's parameters its material.
    """
    if ctx.dataset.meta.get("materials") is not None:
        return ctx.dataset, materials_for_parts(ctx, region_params)
    dataset, _ = ctx.feature("region_parts", lambda: _region_parts(ctx))
    return dataset, [{"I0": float(p[0]), "kd": float(p[1]), "gamma": float(p[2])} for p in np.asarray(region_params)]


def _bsdf_override(materials, reference_intensity, bsdf_params):
    if not bsdf_params:
        return None

    def override(material_index):
        material = materials[material_index]
        return {"type": EXT_PLUGIN_NAME, "kd": material["kd"], "gamma": material["gamma"],
                "scale": material["I0"] / reference_intensity, **{k: float(v) for k, v in bsdf_params.items()}}
    return override


def render_model(dataset, materials, change, *, spp=1, seed=0, max_depth=None, batches=1, env_spp_factor=16):
    """Path-trace every light of the data set with ``materials`` and a :class:`MitsubaChange`.

    Returns the channel-mean radiance (L, H, W) along the data set's pixel-centre rays, after
    the change's light scales and post-process; with ``batches > 1`` also the Monte Carlo
    standard error per value (from independent batches of ``spp`` samples each).

    Extra emitters (an environment) light every image alike: by the linearity of light
    transport they are rendered ONCE, without the data set's lights, at ``env_spp_factor x spp``
    samples, and added to each light's image; that spends the samples where the Monte Carlo
    noise is. Lights alone are rendered with ``spp`` samples when paths go beyond direct light
    (``max_depth`` > 2) and with one otherwise (direct light from point / directional emitters
    is deterministic).
    """
    from rjfit.render.mitsuba_scene import activate
    from rjfit.render.render import scene_from_dataset_meta

    activate()
    register_ext()
    meta = dataset.meta
    reference = float(meta["reference_intensity"])
    lights = [Light.from_json(e) for e in meta["lights"]]
    scales = np.ones(len(lights)) if change.light_scales is None else np.asarray(change.light_scales, dtype=float)
    depth = max_depth if max_depth is not None else (change.max_depth or 2)
    override = _bsdf_override(materials, reference, change.bsdf_params)
    light_spp = spp if depth > 2 else 1
    light_batches = batches if depth > 2 else 1
    stacks = []
    keys = tuple(int(k) for k in np.atleast_1d(seed))     # one stream per (seed, light, batch) and environment batch
    for index, light in enumerate(lights):
        scaled = Light(kind=light.kind, intensity=light.intensity * scales[index], position=light.position,
                       direction=light.direction)
        scene = scene_from_dataset_meta(meta, dataset.path, materials=materials, lights=[scaled], max_depth=depth,
                                        bsdf_override=override)
        stacks.append(np.stack([trace_centre_rays(scene, spp=light_spp, seed=(*keys, MODEL_STREAM, index, b))
                                for b in range(light_batches)]))
    stacks = np.stack(stacks, axis=1)          # (batches, L, H, W)
    mean = stacks.mean(axis=0)
    var = stacks.var(axis=0, ddof=1) / light_batches if light_batches > 1 else np.zeros_like(mean)
    if change.extra:
        scene = scene_from_dataset_meta(meta, dataset.path, materials=materials, lights=[], max_depth=max(depth, 2),
                                        bsdf_override=override, extra=change.extra)
        env = np.stack([trace_centre_rays(scene, spp=spp * env_spp_factor, seed=(*keys, ENVIRONMENT_STREAM, b))
                        for b in range(batches)])
        mean = mean + env.mean(axis=0)[None]
        if batches > 1:
            var = var + (env.var(axis=0, ddof=1) / batches)[None]
    if change.post_process is not None:
        mean = change.post_process(mean)
    return (mean, np.sqrt(var)) if batches > 1 else mean


def indirect_radiance(ctx, region_params, *, spp=32, max_depth=8, seed=None, batches=8):
    """Mitsuba's indirect radiance of the fitted model per light: path(max_depth) - path(2).

    ``seed`` defaults to the diagnosis' seed (``ctx.seed``).

    Returns the (L, H, W) mean; its Monte Carlo standard error (from ``batches`` independent
    batches) is kept in ``ctx.features["indirect_se"]``.
    """
    from rjfit.diagnose.effects.base import MitsubaChange

    seed = (ctx.seed if seed is None else seed, INDIRECT_STREAM)
    dataset, materials = model_scene(ctx, region_params)
    full, se = render_model(dataset, materials, MitsubaChange(), spp=max(spp // batches, 1), seed=seed,
                            max_depth=max_depth, batches=batches)
    direct = render_model(dataset, materials, MitsubaChange(), spp=1, seed=seed, max_depth=2)
    ctx.features["indirect_se"] = se
    return full - direct


def _verdict(path, closed, se, stochastic):
    """Compare path-traced and closed-form values of the same observations."""
    from rjfit.render.gate import MEDIAN_TOLERANCE, P99_TOLERANCE

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
    matters. Returns ``{"extended": verdict, "reference": verdict, ...}``.
    """
    from rjfit.diagnose.context import build_context
    from rjfit.diagnose.effects.base import merge_changes
    from rjfit.diagnose.model import order_effects, predict
    from rjfit.render.datasets import load_dataset

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
    result["passed"] = result["extended"]["passed"]
    result["seconds"] = round(time.perf_counter() - started, 3)
    return result
