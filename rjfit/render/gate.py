"""The cross-check gate: the closed form (eq. 2) against Mitsuba's path tracer.

For every light, the data set's scene is path-traced with rjfit's plugin (the ``path``
integrator, several bounces) along the data set's own camera rays (one per pixel centre),
and the closed form is evaluated from the geometry of the same rays: position, shading
normal, view direction and shadow-ray visibility. On a convex object with point or
directional lights both must agree to float rounding; what the closed form does not explain
(interreflection on concave objects, a wrong light unit, a wrong lobe) shows up as error.

Definitions used in ``validation.json``:

- an observation is compared where the pixel hits the object and the path-traced radiance
  exceeds ``1e-6`` times the image's maximum (black pixels have no relative error);
- ``rel_err = max_c |L_path,c - L_closed| / L_path`` per compared observation, over the
  colour channels c of the path-traced radiance (materials and lights are grey);
- ``unexplained_fraction = sum(L_path - L_closed) / sum(L_path)`` over compared observations,
  and its per-pixel map (summed over lights): the share of radiance the closed form misses;
- ``observations_over_p99_tolerance``: how many compared observations differ by more than the
  p99 tolerance (a passing gate allows up to 1 %: ``max_rel_err`` alone says nothing of how many).

The gate passes when ``median_rel_err <= 1e-4`` and ``p99_rel_err <= 1e-3``.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from rjfit.data.dataset import read_validation_result
from rjfit.data.exr import write_exr
from rjfit.data.fingerprint import dataset_fingerprint
from rjfit.data.lights import geometry_terms
from rjfit.data.loading import is_dataset
from rjfit.io import atomic_path, publish, staging_dir, write_json_atomic
from rjfit.model.blinn import radiance
from rjfit.plotting import map_figure
from rjfit.progress import phase, tracked

# purpose tag of the validation's path-tracing streams (see rjfit.render.render.RENDER_STREAM)
VALIDATE_STREAM = 2

__all__ = ["closed_form_radiance", "validate_dataset", "require_validated",
           "MEDIAN_TOLERANCE", "P99_TOLERANCE", "ValidationRequiredError", "outlier_note"]

MEDIAN_TOLERANCE = 1e-4
P99_TOLERANCE = 1e-3
_DARK_FRACTION = 1e-6


class ValidationRequiredError(RuntimeError):
    """The data set's forward model has not passed the cross-check gate."""


def closed_form_radiance(positions, normals, view_dirs, light, material, reference_intensity):
    """Eq. 2 at surface points for one light and per-pixel material parameters.

    ``material`` maps ``I0``, ``kd``, ``gamma`` to arrays of the image shape (or floats).
    This is the default forward model that :func:`validate_dataset` checks; a replacement
    with the same signature can be passed to it (the tests pass deliberately wrong ones).
    """
    cos_ln, cos_hn, irradiance = geometry_terms(positions, normals, view_dirs, light, reference_intensity)
    return radiance(material["I0"], material["kd"], material["gamma"], cos_ln, cos_hn, irradiance)


#: Materials the gate renders a data set with when it has no truth (measured data): both lobes.
PROBE_MATERIALS = [{"name": "probe", "I0": 1.0, "kd": 0.5, "gamma": 10.0}]


def _angle_deg(a, b):
    """Angle between vectors in degrees, per pixel; atan2 of |a x b| and a.b stays accurate near 0
    (arccos of the dot product of float32 unit vectors cannot resolve less than about 0.03 deg)."""
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


def _facet_camera(camera_meta, height, width):
    """The Mitsuba camera of the facet scene and the principal point ``(cx, cy)`` in pixels.

    Orthographic: one world unit per pixel, the frame centred on the origin. Perspective: the
    pinhole at distance ``f`` (the focal length in pixels) from the plane z = 0, so a pixel
    there is again one world unit wide, and the principal point falls on the origin.
    """
    if (camera_meta or {}).get("kind") != "perspective":
        return ({"kind": "orthographic", "origin": [0.0, 0.0, 10.0], "target": [0.0, 0.0, 0.0], "up": [0, 1, 0],
                 "half_width": width / 2.0}, (width / 2.0, height / 2.0))
    focal = float(camera_meta["focal_px"])
    cx, cy = (float(v) for v in camera_meta["principal_point"])
    camera = {"kind": "perspective", "origin": [0.0, 0.0, focal], "target": [0.0, 0.0, 0.0], "up": [0, 1, 0],
              "focal_px": focal, "principal_point": [cx, cy]}
    return camera, (cx, cy)


def _facet_mesh(normals, object_mask, size=0.1, principal_point=None):
    """A small square facet (``size`` pixels wide) per object pixel, centred where the
    pixel-centre ray meets the plane z = 0 (x right, y up; :func:`_facet_camera`'s frame, whose
    principal point ``(cx, cy)`` lies on the origin), tilted to the pixel's normal; the
    pixel-centre ray hits each facet at its centre."""
    import trimesh

    height, width = object_mask.shape
    cx, cy = principal_point if principal_point is not None else (width / 2.0, height / 2.0)
    rows, cols = np.nonzero(object_mask)
    centres = np.stack([cols + 0.5 - cx, cy - rows - 0.5, np.zeros(rows.size)], axis=-1)
    n = normals[rows, cols]
    helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)
    half = size / 2.0
    corners = np.stack([centres + half * (a * t1 + b * t2) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))], axis=1)
    base = 4 * np.arange(rows.size)[:, None]
    faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]])
    # Orient every triangle so that its geometric normal agrees with the pixel normal.
    vertices = corners.reshape(-1, 3)
    geometric = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]])
    flip = np.sum(geometric * n[np.tile(np.arange(rows.size), 2)], axis=1) < 0
    faces[flip] = faces[flip][:, ::-1]
    return trimesh.Trimesh(vertices=vertices, faces=faces, vertex_normals=np.repeat(n, 4, axis=0), process=False)


def _material_maps(material_index_map, materials):
    maps = {}
    for key in ("I0", "kd", "gamma"):
        table = np.array([float(m[key]) for m in materials] + [0.0])
        maps[key] = table[material_index_map]          # index -1 picks the trailing 0
    return maps


def _gate_scene(dataset, dataset_dir, out_dir, materials, max_depth):
    """The gate's scene maker ``make_scene(lights, depth, light_format)``, the materials it renders
    with, each part's material index and a sentence naming where the geometry comes from."""
    from rjfit.render.mitsuba_scene import build_scene
    from rjfit.render.render import scene_from_dataset_meta

    meta = dataset.meta
    if meta.get("meshes"):
        materials = materials if materials is not None else meta.get("materials", PROBE_MATERIALS[:1])

        def make_scene(scene_lights, depth, value_format="rgb"):
            return scene_from_dataset_meta(meta, dataset_dir, materials=materials, lights=scene_lights,
                                           max_depth=depth, light_format=value_format)
        return make_scene, materials, [entry["material"] for entry in meta["meshes"]], "the data set's meshes"
    # A normal-map data set has no mesh: each object pixel becomes a small facet with the
    # pixel's normal, seen by the folder's camera (orthographic or a pinhole), so Mitsuba
    # checks the conventions (axes, light directions and units, the view directions) the
    # loader assumed.
    materials = materials if materials is not None else PROBE_MATERIALS[:1]
    facet_path = out_dir / "facets.ply"
    height, width = dataset.image_shape
    camera, principal_point = _facet_camera(meta.get("camera"), height, width)
    with atomic_path(facet_path) as temporary:
        _facet_mesh(dataset.normals, dataset.object_mask, principal_point=principal_point).export(
            temporary, file_type="ply", vertex_normal=True)

    def make_scene(scene_lights, depth, value_format="rgb"):
        return build_scene(camera, (height, width), [(facet_path, 0)], materials, scene_lights,
                           reference_intensity=dataset.reference_intensity, max_depth=depth,
                           light_format=value_format)
    return make_scene, materials, [0], "one facet per pixel from the normal map"


def _trace_and_compare(dataset, make_scene, geometry_scene, traced, hit, material_maps, forward_model, *, max_depth,
                       spp, seed, light_format, progress):
    """Per light: the path-traced radiance, its worst colour channel and the closed form (0 off
    ``hit``; the closed form also 0 where the shadow ray is blocked), each stacked (L, H, W)."""
    from rjfit.render.mitsuba_scene import light_scenes, path_trace, shadow_visibility

    positions = dataset.positions if dataset.positions is not None else np.zeros_like(dataset.normals)
    path_stack, closed_stack, worst_stack = [], [], []
    # a bar on a terminal, plain lines in a log
    iterator = tracked(list(enumerate(dataset.lights)), "validate: path tracing", "light", enabled=progress)
    scenes = light_scenes(lambda one: make_scene(one, max_depth, light_format), dataset.lights, light_format)
    for (light_index, light), scene in zip(iterator, scenes):
        path_colour = path_trace(scene, spp=spp, seed=(seed, VALIDATE_STREAM, light_index))
        path_radiance = path_colour.mean(axis=-1)
        # The materials are grey, so every channel must match the closed form on its own; the
        # worst channel's deviation is kept (a colour slip in the lights shows up here).
        worst_channel = np.take_along_axis(
            path_colour, np.abs(path_colour - path_radiance[..., None]).argmax(axis=-1)[..., None], axis=-1)[..., 0]
        visible = shadow_visibility(geometry_scene, traced["_interaction"], light, hit.shape)
        # The closed form sees the data set's own geometry, as the fitter will.
        closed = forward_model(positions, dataset.normals, dataset.view_dirs, light, material_maps,
                               dataset.reference_intensity)
        path_stack.append(np.where(hit, path_radiance, 0.0))
        worst_stack.append(np.where(hit, worst_channel, 0.0))
        closed_stack.append(np.where(hit & visible, closed, 0.0))
    return np.stack(path_stack), np.stack(closed_stack), np.stack(worst_stack)


def _verdict(dataset_dir, hit, path_stack, closed_stack, worst_stack):
    """The gate's figures from the stacks of :func:`_trace_and_compare` (the module docstring's
    definitions): ``(result dict, compared, rel_err, unexplained_map)``.

    Raises
    ------
    ValueError
        If no lit object pixel is left to compare.
    """
    n_lights = path_stack.shape[0]
    image_max = path_stack.reshape(n_lights, -1).max(axis=1)[:, None, None]
    compared = hit[None] & (path_stack > _DARK_FRACTION * np.maximum(image_max, 1e-30))
    rel_err = np.maximum(np.abs(path_stack - closed_stack), np.abs(worst_stack - closed_stack)) / np.where(
        compared, path_stack, 1.0)
    errors = rel_err[compared]
    if errors.size == 0:
        raise ValueError(f"{dataset_dir}: no lit object pixel to compare; check the lights and the camera")
    missing = path_stack - closed_stack
    unexplained_map = np.where(hit, (missing * compared).sum(0) / np.maximum((path_stack * compared).sum(0), 1e-30), 0)
    result = {
        "dataset": str(Path(dataset_dir).resolve()),
        "dataset_sha256": dataset_fingerprint(dataset_dir),
        "passed": bool(np.median(errors) <= MEDIAN_TOLERANCE and np.quantile(errors, 0.99) <= P99_TOLERANCE),
        "median_rel_err": float(np.median(errors)),
        "p99_rel_err": float(np.quantile(errors, 0.99)),
        "max_rel_err": float(errors.max()),
        "observations_over_p99_tolerance": int(np.sum(errors > P99_TOLERANCE)),
        "observations_compared": int(errors.size),
        "pixels_compared": int(compared.any(axis=0).sum()),
        "unexplained_fraction": float((missing * compared).sum() / (path_stack * compared).sum()),
        "per_light_median_rel_err": [float(np.median(rel_err[i][compared[i]])) if compared[i].any() else None
                                     for i in range(n_lights)],
    }
    return result, compared, rel_err, unexplained_map


def outlier_note(result: dict) -> str | None:
    """A line on the observations over the p99 tolerance when there are any (``max_rel_err`` alone hides how
    many), else None; older ``validation.json`` files without the count give None too."""
    over = result.get("observations_over_p99_tolerance")
    if not over:
        return None
    share = over / result["observations_compared"]
    return (f"{over} of {result['observations_compared']} observations ({100 * share:.2g} %) differ by more than "
            f"{P99_TOLERANCE:g} (the largest by {result['max_rel_err']:.3g}); the gate allows 1 % of them "
            f"(its p99), relative_error.png shows where")


def _write_gate(out_dir, result, hit, compared, rel_err, unexplained_map):
    """``validation.json`` and its maps, staged and published together."""
    max_rel_map = np.where(compared.any(0), np.where(compared, rel_err, 0).max(0), 0)
    maps = ("validation_maps.exr", "relative_error.png", "unexplained_fraction.png")
    # staged and published together, validation.json last: a reader never pairs a verdict with
    # another run's maps, and an interrupted validation leaves the previous one whole
    with staging_dir(out_dir) as staging:
        write_exr(staging / "validation_maps.exr", {
            "max_rel_err": max_rel_map, "unexplained_fraction": unexplained_map,
            **{f"rel_err_{i:03d}": np.where(compared[i], rel_err[i], 0) for i in range(rel_err.shape[0])}})
        map_figure(staging / "relative_error.png", np.log10(np.maximum(max_rel_map, 1e-9)) * np.where(hit, 1, np.nan),
                   f"log10 max relative error over lights\nmedian {result['median_rel_err']:.2e}, "
                   f"p99 {result['p99_rel_err']:.2e}", cmap="magma", vmin=-9, vmax=0,
                   unit="log10 relative error")
        map_figure(staging / "unexplained_fraction.png", np.where(hit, unexplained_map, np.nan),
                   f"radiance the closed form does not explain\n(total {result['unexplained_fraction']:.2%})",
                   cmap="viridis", unit="fraction of the pixel's radiance")
        write_json_atomic(staging / "validation.json", result)
        publish(staging, out_dir, manifest="validation.json", names=maps, remove=maps)


def validate_dataset(dataset_dir, out_dir=None, *, forward_model=closed_form_radiance, materials=None,
                     max_depth=8, spp=4, seed=0, variant="auto", light_format="rgb", progress=False):
    """Path-trace a data set's scene and compare it with the closed form; write the gate's verdict.

    Parameters
    ----------
    dataset_dir : path
        A data set: rendered by rjfit (its meshes are path-traced) or a measured normal-map
        folder (path-traced as one facet per pixel with the pixel's normal).
    out_dir : path, optional
        Where ``validation.json`` and the error maps go (default: ``dataset_dir/validation``).
    forward_model : callable
        ``(positions, normals, view_dirs, light, material_maps, reference_intensity) -> radiance``.
    materials : list of dict, optional
        ``{I0, kd, gamma}`` per material index (default: the data set's own materials).
    max_depth : int
        Path length for the path tracer (8: up to 7 bounces of indirect light).
    spp : int
        Path-traced samples per pixel, all along the pixel-centre ray (averages indirect light).
    light_format : str
        How light values reach Mitsuba (``"spectrum"`` reproduces a known unit mistake).

    Returns
    -------
    dict
        The contents of ``validation.json``.

    Raises
    ------
    FileNotFoundError, ValueError
        If the data set cannot be loaded (see :func:`rjfit.render.datasets.load_dataset`), or
        no lit object pixel is left to compare.
    """
    from rjfit.render.datasets import load_dataset
    from rjfit.render.mitsuba_scene import activate, trace_pixels

    started = time.perf_counter()
    dataset_dir = Path(dataset_dir)
    out_dir = Path(out_dir) if out_dir is not None else dataset_dir / "validation"
    dataset = load_dataset(dataset_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    mi_module = activate(variant)      # an unsupported variant is refused in one line, before any progress line
    with phase(f"validate: building the scene's geometry and tracing the pixels ({variant})", progress):
        make_scene, materials, part_materials, geometry_source = _gate_scene(dataset, dataset_dir, out_dir, materials,
                                                                             max_depth)
        geometry_scene = make_scene([], max_depth)
        traced = trace_pixels(geometry_scene, part_materials)
    hit = traced["hit"] & dataset.object_mask
    normal_angle = _angle_deg(traced["normals"], dataset.normals)
    view_angle = _angle_deg(traced["view_dirs"], dataset.view_dirs)
    material_maps = _material_maps(np.where(hit, traced["material"], -1), materials)
    path_stack, closed_stack, worst_stack = _trace_and_compare(
        dataset, make_scene, geometry_scene, traced, hit, material_maps, forward_model, max_depth=max_depth, spp=spp,
        seed=seed, light_format=light_format, progress=progress)
    result, compared, rel_err, unexplained_map = _verdict(dataset_dir, hit, path_stack, closed_stack, worst_stack)
    result.update({
        "geometry": geometry_source,
        "max_normal_angle_deg": float(normal_angle[hit].max()) if hit.any() else None,
        "max_view_angle_deg": float(view_angle[hit].max()) if hit.any() else None,
        "thresholds": {"median_rel_err": MEDIAN_TOLERANCE, "p99_rel_err": P99_TOLERANCE},
        "settings": {"integrator": "path", "max_depth": max_depth, "spp": spp, "seed": seed,
                     "variant": mi_module.variant(),
                     "rays": "one per pixel centre, shared by the path tracer and the closed form"},
        "maps": {"error_exr": "validation_maps.exr", "relative_error_png": "relative_error.png",
                 "unexplained_png": "unexplained_fraction.png"},
        "seconds": round(time.perf_counter() - started, 3),
    })
    _write_gate(out_dir, result, hit, compared, rel_err, unexplained_map)
    return result


def require_validated(dataset_dir, validation_path=None, *, allow_unvalidated=False):
    """Refuse a data set whose forward model has not passed the gate.

    Looks for ``validation.json`` (default ``dataset_dir/validation/validation.json``),
    checks ``passed`` and that it belongs to this data set's current files.

    Returns
    -------
    dict or None
        The validation result (with ``stale`` True when overridden and it passed on other
        files), or None when overridden and none exists.

    Raises
    ------
    ValidationRequiredError
        When no passing validation of this data set exists and ``allow_unvalidated`` is False.
    """
    dataset_dir = Path(dataset_dir)
    if not is_dataset(dataset_dir):
        raise FileNotFoundError(f"{dataset_dir}: not a data set (no dataset.json, stack.json or DiLiGenT-style "
                                f"light_directions.txt); `rjfit render` writes one")
    if validation_path is not None and not Path(validation_path).is_file():
        raise FileNotFoundError(f"{validation_path}: no such validation file (--validation); `rjfit validate "
                                f"{dataset_dir} --out DIR` writes DIR/validation.json")
    explicit = validation_path is not None
    validation_path = Path(validation_path) if explicit else dataset_dir / "validation" / "validation.json"
    override = " (or pass --allow-unvalidated to fit anyway, at your own risk)"
    if not validation_path.is_file():
        if allow_unvalidated:
            return None
        raise ValidationRequiredError(
            f"{dataset_dir}: its forward model has not been cross-checked (no {validation_path}); run `rjfit validate "
            f"{dataset_dir}` first, or pass --validation FILE if you wrote it elsewhere with `validate --out`"
            f"{override}")
    result = read_validation_result(validation_path)
    problem = None
    if not result.get("passed"):
        problem = (f"failed the cross-check (median rel. err. {result.get('median_rel_err'):.3g}, "
                   f"p99 {result.get('p99_rel_err'):.3g}, unexplained fraction "
                   f"{result.get('unexplained_fraction'):.3g}); see {validation_path}")
    elif result.get("dataset_sha256") != dataset_fingerprint(dataset_dir):
        validated = result.get("dataset")
        other = (f" (it is the cross-check of {validated})"
                 if validated and Path(validated).resolve() != dataset_dir.resolve() else "")
        problem = f"changed since {validation_path} was written{other}; validate it again"
    if problem is None:
        return result
    if allow_unvalidated:
        # a passing result of other files is marked, so the fit's summary can say so
        return dict(result, stale=bool(result.get("passed")))
    raise ValidationRequiredError(f"{dataset_dir}: {problem}{override}")
