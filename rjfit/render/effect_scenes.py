"""Rendering a fitted (extended) model with Mitsuba: the scenes the criticism's effects need.

- :func:`trace_centre_rays`: many samples per pixel-centre ray in one wavefront;
- :func:`region_parts`, :func:`region_materials`: a data set's mesh cut by a fit's
  regions and their materials (a rendered data set's parts cut along the fit's regions, a measured mesh by them);
- :func:`render_model`: every light with those materials and a
  :class:`rjfit.render.scene_change.MitsubaChange` (the Mitsuba side of the effects);
- :func:`render_indirect`: the indirect radiance (interreflection's feature);
- :func:`mitsuba_visibility`: shadow-ray visibility (cast shadows' feature).

Nothing here knows the criticism's context or effects (:mod:`rjfit.effects` and
:mod:`rjfit.diagnose` call these with a data set, labels and region parameters): the render
layer imports nothing above it.
"""
from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path

import numpy as np

from rjfit.data.lights import Light
from rjfit.data.meshes import split_by_face_label
from rjfit.render.ext_plugin import EXT_PLUGIN_NAME, register_ext
from rjfit.render.mitsuba_scene import (activate, light_scenes, mitsuba_seed, shadow_visibility, shape_materials,
                                        trace_pixels)
from rjfit.render.render import scene_from_dataset_meta
from rjfit.render.scene_change import MitsubaChange

__all__ = ["trace_centre_rays", "region_parts", "region_materials", "render_model",
           "render_indirect", "mitsuba_visibility", "MODEL_STREAM", "ENVIRONMENT_STREAM", "INDIRECT_STREAM"]

# purpose tags of the diagnosis' path-tracing streams (rjfit.render.mitsuba_scene.mitsuba_seed)
MODEL_STREAM, ENVIRONMENT_STREAM, INDIRECT_STREAM = 11, 12, 13


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
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(mitsuba_seed(*np.atleast_1d(seed)), n_pix * int(spp))
    radiance, _, _ = scene.integrator().sample(scene, sampler, rays, None, True)
    values = np.array(radiance, dtype=np.float64)
    values = values.reshape(-1, n_pix * int(spp)).mean(axis=0) if values.ndim > 1 else values
    return values.reshape(int(spp), int(height), int(width)).mean(axis=0)


def _mesh_material_map(dataset):
    """(H, W) mesh material index per pixel (truth labels of a rendered data set, else traced; -1: no surface)."""
    if dataset.truth_labels is not None:
        return dataset.truth_labels
    scene = scene_from_dataset_meta(dataset.meta, dataset.path, lights=[])
    return trace_pixels(scene, [e["material"] for e in dataset.meta["meshes"]])["material"]


def region_materials(region_params):
    """``{I0, kd, gamma}`` of each region: the materials of the parts :func:`region_parts` cuts."""
    return [{"I0": float(p[0]), "kd": float(p[1]), "gamma": float(p[2])} for p in np.asarray(region_params)]


def region_parts(dataset, labels):
    """A data set's mesh cut into one part per fit region (``labels``, (H, W) region index, -1 off
    the object): (data set, temporary folder).

    Each face of the mesh as Mitsuba loads it (positions, shading normals and faces taken from
    the loaded shape, so the geometry is unchanged) takes the region of the nearest traced
    pixel-centre point of its own mesh part (:func:`_mesh_material_map`; a measured mesh stack's
    one mesh is one part), so a part that one region covers is rendered whole with that region's
    parameters, the faces no pixel sees included, and a boundary between regions inside a part
    falls where the fit puts it. The parts are written as PLY files into a temporary folder that
    lives as long as the returned object, and the data set returned names them as its ``meshes``
    (material = region index): keep the pair while the data set is rendered.
    """
    import mitsuba as mi
    from scipy.spatial import cKDTree

    activate()
    labelled = (labels >= 0) & dataset.object_mask
    parts = _mesh_material_map(dataset)
    scene = scene_from_dataset_meta(dataset.meta, dataset.path, lights=[])
    shapes = scene.shapes()
    nearest = {}        # per mesh material: its labelled pixels' tree and labels (Mitsuba may split a part)
    folder = tempfile.TemporaryDirectory(prefix="rjfit-regions-")
    meshes = []
    for shape, material in zip(shapes, shape_materials([s.id() for s in shapes],
                                                       [e["material"] for e in dataset.meta["meshes"]])):
        if material not in nearest:
            own = labelled & (parts == material)
            seen = own if own.any() else labelled          # a part no pixel sees: the nearest of any
            nearest[material] = cKDTree(dataset.positions[seen]), labels[seen]
        tree, seen_labels = nearest[material]
        params = mi.traverse(shape)
        vertices = np.array(params["vertex_positions"], dtype=np.float64).reshape(-1, 3)
        normals = np.array(params["vertex_normals"], dtype=np.float64).reshape(-1, 3)
        faces = np.array(params["faces"], dtype=np.int64).reshape(-1, 3)
        face_region = seen_labels[tree.query(vertices[faces].mean(axis=1))[1]]
        for mesh, region in split_by_face_label(vertices, faces, normals, face_region):
            meshes.append({"file": str(Path(folder.name) / f"part_{len(meshes):03d}.ply"), "material": region})
            mesh.export(meshes[-1]["file"], file_type="ply", vertex_normal=True)
    return dataclasses.replace(dataset, meta=dict(dataset.meta, meshes=meshes)), folder


def _bsdf_override(materials, reference_intensity, bsdf_params):
    if not bsdf_params:
        return None

    def override(material_index):
        material = materials[material_index]
        return {"type": EXT_PLUGIN_NAME, "kd": material["kd"], "gamma": material["gamma"],
                "scale": material["I0"] / reference_intensity, **{k: float(v) for k, v in bsdf_params.items()}}
    return override


def render_model(dataset, materials, change, *, spp=1, seed=0, max_depth=None, batches=1, env_spp_factor=16):
    """Path-trace every light of the data set with ``materials`` and a
    :class:`rjfit.render.scene_change.MitsubaChange`.

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
    scaled = [Light(kind=light.kind, intensity=light.intensity * scale, position=light.position,
                    direction=light.direction) for light, scale in zip(lights, scales)]
    scenes = light_scenes(lambda one: scene_from_dataset_meta(meta, dataset.path, materials=materials, lights=one,
                                                              max_depth=depth, bsdf_override=override), scaled)
    for index, scene in enumerate(scenes):
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


def render_indirect(dataset, materials, *, seed, spp=32, max_depth=8, batches=8):
    """Mitsuba's indirect radiance of a model per light: path(max_depth) - path(2).

    ``dataset`` and ``materials`` as :func:`render_model` takes them (a fitted model: see
    :func:`region_parts`); ``seed`` the diagnosis' seed, which
    with :data:`INDIRECT_STREAM` keys the paths' streams. Returns the (L, H, W) mean and its
    Monte Carlo standard error (from ``batches`` independent batches).
    """
    seed = (seed, INDIRECT_STREAM)
    full, se = render_model(dataset, materials, MitsubaChange(), spp=max(spp // batches, 1), seed=seed,
                            max_depth=max_depth, batches=batches)
    direct = render_model(dataset, materials, MitsubaChange(), spp=1, seed=seed, max_depth=2)
    return full - direct, se


def mitsuba_visibility(dataset):
    """(L, H, W) shadow-ray visibility from the data set's scene, traced by Mitsuba."""
    activate()
    meta = dataset.meta
    scene = scene_from_dataset_meta(meta, dataset.path, lights=[])
    traced = trace_pixels(scene, [entry["material"] for entry in meta["meshes"]])
    shape = traced["hit"].shape
    return np.stack([shadow_visibility(scene, traced["_interaction"], Light.from_json(entry), shape)
                     for entry in meta["lights"]])
