"""Mitsuba scenes from rjfit scene definitions, and per-pixel tracing at pixel centres.

Every image rjfit renders is traced along exactly one camera ray per pixel, through the
pixel's centre, with Mitsuba's own integrator (``integrator.sample``); the geometry of the
data set (positions, shading normals, shadow-ray visibility) comes from the same rays. The
film's pixel-footprint average is avoided on purpose: it averages radiance over a footprint
while the geometry is one point, which costs the cross-check ~1e-4 (see the design notes).
Several samples per pixel (``spp``) repeat the same ray, so they only average the random
part of path tracing (indirect light), never the geometry.
"""
from __future__ import annotations

import math
import os
import warnings
from pathlib import Path

import numpy as np

from rjfit.data.lights import Light

__all__ = ["activate", "resolve_variant", "supported_variant", "is_scalar_variant", "UnsupportedVariantError", "camera_dict", "light_dict", "material_dict", "build_scene", "light_scenes", "trace_pixels",
           "path_trace", "shadow_visibility", "shape_materials", "DEFAULT_VARIANT"]

DEFAULT_VARIANT = "llvm_ad_rgb"

#: Why the last ``resolve_variant("auto")`` fell back from ``cuda_ad_rgb`` to
#: :data:`DEFAULT_VARIANT` (``"ImportError: ..."``), or None when it did not fall back. On a
#: machine without a CUDA GPU or driver the fallback is the normal case and is not warned
#: about (``RJFIT_DEBUG=1`` makes the CLI print it); read it with ``rjfit.render.mitsuba_scene.CUDA_FALLBACK_REASON`` (module attribute, not a
#: from-import, which would copy the value at import time).
CUDA_FALLBACK_REASON: str | None = None


class UnsupportedVariantError(ValueError):
    """A Mitsuba variant rjfit cannot compare with its closed form (spectral, polarized)."""


def supported_variant(variant: str) -> bool:
    """Whether rjfit renders and cross-checks in ``variant``: the RGB and mono variants
    (``scalar_rgb``, ``llvm_ad_rgb``, ``llvm_ad_mono``, ``cuda_ad_rgb``, ``cuda_ad_mono``).

    Spectral variants return radiance at a few randomly sampled wavelengths (an RGB light
    becomes an upsampled spectrum times D65), so one pixel-centre sample is not the RGB value
    the closed form predicts; polarized variants return Stokes vectors. Either would make the
    cross-check report a setup mismatch as a failure of the forward model.
    """
    return variant.endswith("_rgb") or variant.endswith("_mono")


def _check_supported(variant: str) -> None:
    import mitsuba as mi

    if supported_variant(variant):
        return
    kind = "polarized" if "polarized" in variant else "spectral" if "spectral" in variant else "non-RGB"
    usable = [v for v in mi.variants() if supported_variant(v)]
    raise UnsupportedVariantError(
        f"Mitsuba variant {variant!r} is not supported: it is {kind}, and rjfit renders and cross-checks "
        f"RGB (or mono) radiance along one ray per pixel against its closed form, so a {kind} render would "
        f"fail the gate for the set-up, not the model. Use --variant auto or one of: {', '.join(usable)}")


def resolve_variant(variant: str = "auto") -> str:
    """The Mitsuba variant to use: ``"auto"`` picks ``cuda_ad_rgb`` when a CUDA GPU and driver
    answer, else ``llvm_ad_rgb``; any other name is returned as it is once it is known to be
    installed and supported (see :func:`supported_variant`).

    A CUDA variant is listed by every Mitsuba wheel, GPU or not; only initialising it tells.
    When ``"auto"`` falls back, the reason is kept in :data:`CUDA_FALLBACK_REASON`; it is
    also emitted as a ``RuntimeWarning`` when a CUDA GPU seems present (the NVIDIA driver is
    loaded, or Dr.Jit's CUDA backend initialised), since the fallback then points at a broken
    CUDA or OptiX set-up. Without a GPU the fallback stays quiet.

    Raises
    ------
    UnsupportedVariantError
        For spectral and polarized variants (a ``ValueError``).
    ValueError
        If the variant is not available in the installed Mitsuba.
    """
    global CUDA_FALLBACK_REASON
    import mitsuba as mi

    if variant != "auto":
        if variant not in mi.variants():
            raise ValueError(f"Mitsuba variant {variant!r} is not available; installed: {', '.join(mi.variants())}")
        _check_supported(variant)
        return variant
    CUDA_FALLBACK_REASON = None
    if "cuda_ad_rgb" in mi.variants():
        try:
            mi.set_variant("cuda_ad_rgb")
            import drjit as dr

            dr.eval(mi.Float(1.0) + 1.0)      # fails here without a GPU or driver
            return "cuda_ad_rgb"
        except (ImportError, RuntimeError) as error:
            # Not an error: "auto" means "CUDA if it works". Keep why, and say it only when a
            # GPU is there (without one this is every CPU machine's normal path).
            CUDA_FALLBACK_REASON = f"{type(error).__name__}: {error}"
            if _cuda_gpu_present():
                warnings.warn(f"variant 'auto': cuda_ad_rgb could not be used although a CUDA GPU seems present "
                              f"({CUDA_FALLBACK_REASON}); falling back to {DEFAULT_VARIANT}",
                              RuntimeWarning, stacklevel=2)
    return DEFAULT_VARIANT


def _cuda_gpu_present() -> bool:
    """Whether this machine seems to have a CUDA GPU: the NVIDIA kernel driver is loaded
    (Linux) or Dr.Jit's CUDA backend initialised. Used only to decide whether a CUDA
    fallback is worth a warning."""
    if os.path.exists("/proc/driver/nvidia/version"):
        return True
    try:
        import drjit as dr

        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except (ImportError, AttributeError, RuntimeError):   # an old Dr.Jit without has_backend: say nothing
        return False


def activate(variant: str = DEFAULT_VARIANT):
    """Set the Mitsuba variant (``"auto"``: see :func:`resolve_variant`), register rjfit's
    BSDF for it and return the ``mitsuba`` module; ``mi.variant()`` then says which ran.

    Raises
    ------
    ValueError
        If the variant is not available in the installed Mitsuba, or is spectral or
        polarized (:class:`UnsupportedVariantError`).
    """
    import mitsuba as mi

    variant = resolve_variant(variant)
    mi.set_variant(variant)
    from rjfit.render.plugin import register

    register()
    return mi


def camera_dict(camera: dict, resolution) -> dict:
    """The Mitsuba sensor of a scene definition's ``camera`` entry (perspective or orthographic)."""
    import mitsuba as mi

    height, width = int(resolution[0]), int(resolution[1])
    to_world = mi.ScalarTransform4f().look_at(origin=camera["origin"], target=camera["target"], up=camera["up"])
    sensor = {"to_world": to_world, "film": {"type": "hdrfilm", "width": width, "height": height,
                                             "rfilter": {"type": "box"}, "pixel_format": "rgb"}}
    if camera["kind"] == "perspective":
        # a calibrated pinhole: focal length and principal point in pixels (pixel (r, c) spans
        # [c, c + 1] x [r, r + 1]); Mitsuba takes the field of view along x and the principal
        # point's offset from the film's centre as fractions of its width and height
        fov = (float(camera["fov"]) if "fov" in camera
               else math.degrees(2.0 * math.atan(width / (2.0 * float(camera["focal_px"])))))
        sensor.update(type="perspective", fov=fov, fov_axis="x")
        if camera.get("principal_point") is not None:
            cx, cy = (float(v) for v in camera["principal_point"])
            sensor.update(principal_point_offset_x=(width / 2.0 - cx) / width,
                          principal_point_offset_y=(height / 2.0 - cy) / height)
    elif camera["kind"] == "orthographic":
        half_width = float(camera["half_width"])
        sensor.update(type="orthographic",
                      to_world=to_world @ mi.ScalarTransform4f().scale([half_width, half_width, 1.0]))
    else:
        raise ValueError(f"camera kind must be 'perspective' or 'orthographic', got {camera['kind']!r}")
    return sensor


def light_dict(light: Light, value_format: str = "rgb") -> dict:
    """The Mitsuba emitter of a light.

    ``value_format="rgb"`` passes the intensity as an RGB triple, which Mitsuba takes
    exactly. ``"spectrum"`` passes it as an equal-energy spectrum, which an RGB variant
    turns into (1.205, 0.948, 0.909) x I: kept only so tests can show that the cross-check
    catches that mistake.
    """
    if value_format == "rgb":
        value = {"type": "rgb", "value": [light.intensity] * 3}
    elif value_format == "spectrum":
        value = {"type": "spectrum", "value": light.intensity}
    else:
        raise ValueError(f"value_format must be 'rgb' or 'spectrum', got {value_format!r}")
    if light.kind == "point":
        return {"type": "point", "position": list(light.position), "intensity": value}
    direction = -np.asarray(light.direction, dtype=float)       # Mitsuba: direction of travel
    return {"type": "directional", "direction": direction.tolist(), "irradiance": value}


def material_dict(material: dict, reference_intensity: float) -> dict:
    """The plugin BSDF of a material ``{I0, kd, gamma}``: scale = I0 / reference intensity.

    Raises
    ------
    ValueError
        If a value is out of the plugin's range (checked here: raised inside the plugin, the
        error would reach the caller wrapped in Mitsuba's parser error, a ``RuntimeError``).
    """
    from rjfit.render.plugin import PLUGIN_NAME, _check

    values = {"kd": float(material["kd"]), "gamma": float(material["gamma"]),
              "scale": float(material["I0"]) / float(reference_intensity)}
    try:
        _check(values["kd"], values["gamma"], values["scale"])
    except ValueError as error:
        name = material.get("name")
        raise ValueError(f"material {name!r}: {error} (I0 {material['I0']}, reference intensity "
                         f"{reference_intensity})" if name else f"material {material}: {error}") from None
    return {"type": PLUGIN_NAME, **values}


def build_scene(camera: dict, resolution, mesh_parts, materials, lights=(), *, reference_intensity=1.0,
                max_depth=8, light_format="rgb", bsdf_override=None, extra=None):
    """Load a Mitsuba scene.

    Parameters
    ----------
    camera : dict
        The scene definition's camera entry.
    resolution : (height, width)
    mesh_parts : list of (mesh_path, material_index)
        PLY files (``.obj``: Wavefront OBJ).
    materials : list of dict
        ``{I0, kd, gamma}`` per material index.
    lights : sequence of Light
    max_depth : int
        Path length of the ``path`` integrator (2 = direct light only).
    bsdf_override : callable or None
        ``material_index -> Mitsuba BSDF dict`` replacing the plugin (used to hide effects).
    extra : dict or None
        More scene entries (e.g. an ``envmap`` or ``constant`` emitter).
    """
    import mitsuba as mi

    scene = {"type": "scene", "integrator": {"type": "path", "max_depth": int(max_depth)},
             "sensor": camera_dict(camera, resolution)}
    for part_index, (mesh_path, material_index) in enumerate(mesh_parts):
        bsdf = (bsdf_override(material_index) if bsdf_override is not None
                else material_dict(materials[material_index], reference_intensity))
        kind = "obj" if Path(mesh_path).suffix.lower() == ".obj" else "ply"     # a mesh stack's mesh may be OBJ
        scene[f"part_{part_index:03d}"] = {"type": kind, "filename": str(mesh_path), "bsdf": bsdf}
    for light_index, light in enumerate(lights):
        scene[light_id(light_index)] = light_dict(light, light_format)
    scene.update(extra or {})
    return mi.load_dict(scene)


def light_id(index: int) -> str:
    """The id :func:`build_scene` gives its light ``index`` (``light_000``: the one :func:`light_scenes` moves)."""
    return f"light_{index:03d}"


def light_scenes(make_scene, lights, value_format: str = "rgb"):
    """Yield, for each of ``lights`` in turn, a scene lit by that light alone (as :func:`build_scene` names it).

    ``make_scene([light])`` builds the first scene. Each later light moves that scene's emitter instead of
    building a new scene: its parameters (position or orientation, intensity) are those Mitsuba gives the
    light's emitter loaded on its own (:func:`light_dict`), set with ``mi.traverse``. Building a scene (its
    acceleration structure and JIT state) cost about 80 ms a light on a 48 x 48 render, five times the
    render itself; the images are the same to the bit (tests/render/test_light_scenes.py). A light whose
    emitter has other parameters (another kind) gets a scene of its own.

    The scene yielded for one light is changed when the next is drawn: use it before advancing.
    """
    import mitsuba as mi

    params = keys = None
    for light in lights:
        emitter = mi.traverse(mi.load_dict(light_dict(light, value_format)))
        values = {f"{light_id(0)}.{key}": emitter[key] for key in emitter.keys()}
        if params is not None and set(values) <= keys:
            for key, value in values.items():
                params[key] = value
            params.update()
        else:
            scene = make_scene([light])
            params = mi.traverse(scene)
            keys = set(params.keys())
        yield scene


def is_scalar_variant(variant: str | None = None) -> bool:
    """Whether ``variant`` (default: the active one) is a scalar variant: one ray at a time,
    plain Python numbers instead of Dr.Jit arrays (no ``dr.arange``, no vectorised calls)."""
    if variant is None:
        import mitsuba as mi

        variant = mi.variant()
    return str(variant).startswith("scalar_")


def _pixel_centre_rays(scene):
    """The camera rays through the pixel centres, row by row: one vectorised ``Ray3f`` in the
    JIT variants, a list of scalar rays (one per pixel) in the scalar variants."""
    import mitsuba as mi

    sensor = scene.sensors()[0]
    width, height = (int(v) for v in sensor.film().size())
    if is_scalar_variant():
        rays = []
        for row in range(height):
            for col in range(width):
                ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f((col + 0.5) / width, (row + 0.5) / height),
                                           mi.Point2f(0.5, 0.5))
                rays.append(ray)
        return rays, (height, width)
    import drjit as dr

    index = dr.arange(mi.UInt32, width * height)
    film_position = mi.Point2f((mi.Float(index % width) + 0.5) / width, (mi.Float(index // width) + 0.5) / height)
    rays, _ = sensor.sample_ray(mi.Float(0.0), mi.Float(0.5), film_position, mi.Point2f(0.5, 0.5))
    return rays, (height, width)


def _part_index(shape_id: str) -> int | None:
    """The part of a shape named ``part_NNN`` by :func:`build_scene`, or None for another id."""
    prefix, _, number = shape_id.partition("_")
    return int(number) if prefix == "part" and number.isdigit() else None


def shape_materials(shape_ids, mesh_material_indices) -> list[int]:
    """The material index of each of a scene's shapes (by their ids, in ``scene.shapes()`` order).

    Mitsuba merges the meshes that share a BSDF into one shape without the parts' ids (since
    3.5; an empty id in 3.9): when two parts of one material are merged, the merged shape gets
    the material its parts share. Parts of different materials have different BSDFs, so they
    are never merged; if they were, the material of a hit could not be told.

    Raises
    ------
    ValueError
        If shapes without a part's id stand for parts of more than one material.
    """
    parts = [_part_index(shape_id) for shape_id in shape_ids]
    merged = sorted(set(range(len(mesh_material_indices))) - {p for p in parts if p is not None})
    merged_materials = {int(mesh_material_indices[p]) for p in merged}
    if any(p is None for p in parts) and len(merged_materials) != 1:
        raise ValueError(f"Mitsuba merged mesh parts {merged} of materials {sorted(merged_materials)} into shapes "
                         f"without ids, so a hit's material cannot be told; give each material its own BSDF")
    shared = next(iter(merged_materials), -1)
    return [int(mesh_material_indices[p]) if p is not None else shared for p in parts]


def trace_pixels(scene, mesh_material_indices):
    """Geometry at the pixel centres: positions, shading normals, view directions, labels.

    Returns
    -------
    dict of ndarray
        ``positions``, ``normals``, ``view_dirs`` (H, W, 3), ``hit`` (H, W) bool and
        ``material`` (H, W) int (-1 where no surface is hit), from the ``mesh_parts`` order.
        ``_interaction`` holds Mitsuba's surface interactions for :func:`shadow_visibility`
        (one vectorised record, or a list of scalar ones in the scalar variants).
    """
    import mitsuba as mi

    rays, (height, width) = _pixel_centre_rays(scene)
    if isinstance(rays, list):
        return _trace_pixels_scalar(scene, rays, (height, width), mesh_material_indices)
    interaction = scene.ray_intersect(rays)
    hit = np.array(interaction.is_valid(), dtype=bool)
    material = np.full(height * width, -1, dtype=np.int32)
    shapes = scene.shapes()
    for shape, shape_material in zip(shapes, shape_materials([s.id() for s in shapes], mesh_material_indices)):
        on_shape = np.array(interaction.shape == mi.ShapePtr(shape), dtype=bool) & hit
        material[on_shape] = shape_material

    def image(vectors):
        # A value the same for every lane (an orthographic camera's direction) comes back
        # with width 1: broadcast it to the image.
        values = np.array(vectors, dtype=np.float64).reshape(3, -1)
        return np.broadcast_to(values.T, (height * width, 3)).reshape(height, width, 3).copy()

    positions = image(interaction.p)
    normals = image(interaction.sh_frame.n)
    view_dirs = -image(rays.d)
    zero = ~hit.reshape(height, width)
    positions[zero] = normals[zero] = 0.0
    return {"positions": positions, "normals": normals, "view_dirs": view_dirs, "hit": hit.reshape(height, width),
            "material": material.reshape(height, width), "_interaction": interaction}


def _trace_pixels_scalar(scene, rays, shape, mesh_material_indices):
    height, width = shape
    n = height * width
    positions, normals, view_dirs = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
    hit = np.zeros(n, dtype=bool)
    material = np.full(n, -1, dtype=np.int32)
    interactions = []
    shape_ids = [shape.id() for shape in scene.shapes()]
    material_of = dict(zip(shape_ids, shape_materials(shape_ids, mesh_material_indices)))
    for pixel, ray in enumerate(rays):
        interaction = scene.ray_intersect(ray)
        interactions.append(interaction)
        view_dirs[pixel] = -np.array(ray.d, dtype=np.float64)
        if interaction.is_valid():
            hit[pixel] = True
            positions[pixel] = np.array(interaction.p, dtype=np.float64)
            normals[pixel] = np.array(interaction.sh_frame.n, dtype=np.float64)
            material[pixel] = material_of[interaction.shape.id()]
    return {"positions": positions.reshape(height, width, 3), "normals": normals.reshape(height, width, 3),
            "view_dirs": view_dirs.reshape(height, width, 3), "hit": hit.reshape(height, width),
            "material": material.reshape(height, width), "_interaction": interactions}


def shadow_visibility(scene, interaction, light: Light, shape):
    """Whether each pixel's surface point sees ``light`` (shadow ray, Mitsuba's ``ray_test``)."""
    import mitsuba as mi

    if light.kind == "point":
        target = [float(c) for c in light.position]

        def spawn(si):
            return si.spawn_ray_to(mi.Point3f(*target))
    else:
        direction = np.asarray(light.direction, dtype=float)
        direction = [float(c) for c in direction / np.linalg.norm(direction)]

        def spawn(si):
            return si.spawn_ray(mi.Vector3f(*direction))
    if isinstance(interaction, list):             # scalar variants: one interaction per pixel
        visible = [bool(si.is_valid()) and not bool(scene.ray_test(spawn(si))) for si in interaction]
        return np.array(visible, dtype=bool).reshape(shape)
    occluded = scene.ray_test(spawn(interaction), interaction.is_valid())
    return (~np.array(occluded, dtype=bool) & np.array(interaction.is_valid(), dtype=bool)).reshape(shape)


def mitsuba_seed(*keys) -> int:
    """A 32-bit seed for a Mitsuba sampler from non-negative integer keys (user seed, purpose, light, ...).

    Mitsuba's samplers take an unsigned 32-bit seed. Hashing the keys through NumPy's
    ``SeedSequence`` keeps every (seed, purpose, light, pass) on its own stream: sums such
    as ``seed + light`` would give light 1 of seed 0 the stream of light 0 of seed 1, and
    products overflow 32 bits.

    Raises
    ------
    ValueError
        If a key is negative.
    """
    keys = [int(k) for k in keys]
    if any(k < 0 for k in keys):
        raise ValueError(f"seeds must be non-negative integers, got {keys}")
    return int(np.random.SeedSequence(keys).generate_state(1, np.uint32)[0])


def path_trace(scene, spp: int = 1, seed=0):
    """Radiance along the pixel-centre rays with the scene's integrator, averaged over ``spp``.

    Parameters
    ----------
    seed : int or sequence of int
        Keys of the random streams (:func:`mitsuba_seed`): the user's seed, then what the
        trace is for (a purpose tag, the light); pass ``k`` draws from ``(*seed, k)``.

    Returns
    -------
    ndarray, shape (H, W, C)
        C = 3 in RGB variants, 1 in mono variants.
    """
    import mitsuba as mi

    rays, (height, width) = _pixel_centre_rays(scene)
    integrator = scene.integrator()
    total = None
    for sample_index in range(int(spp)):
        sampler = mi.load_dict({"type": "independent"})
        # One stream per (seed keys, sample index): every pass draws fresh indirect paths.
        pass_seed = mitsuba_seed(*np.atleast_1d(seed), sample_index)
        if isinstance(rays, list):
            # Scalar variants: one random stream per pass, which the pixels draw from in turn.
            sampler.seed(pass_seed, 1)
            values = []
            for ray in rays:
                radiance, _, _ = integrator.sample(scene, sampler, ray, None, True)
                values.append(np.atleast_1d(np.array(radiance, dtype=np.float64)))
            values = np.stack(values)
        else:
            import drjit as dr

            sampler.seed(pass_seed, height * width)
            radiance, _, _ = integrator.sample(scene, sampler, rays, None, True)
            values = np.array(radiance, dtype=np.float64)
            values = values.reshape(-1, height * width).T if values.ndim > 1 else values[:, None]
            dr.eval()
        total = values if total is None else total + values
    return (total / int(spp)).reshape(height, width, -1)
