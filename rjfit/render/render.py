"""``rjfit render``: a scene definition -> a data set on disk (see rjfit.data.dataset)."""
from __future__ import annotations

import json
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from rjfit.data.exr import write_exr
from rjfit.data.formats import DATASET_FORMAT
from rjfit.data.lights import Light
from rjfit.data.meshes import build_parts
from rjfit.errors import DatasetError
from rjfit.io import read_json, write_json_atomic
from rjfit.progress import tracked

__all__ = ["SCENES_DIR", "load_scene_definition", "available_scenes", "render_dataset", "write_mesh_parts",
           "scene_from_dataset_meta", "GEOMETRY_MATERIAL"]

SCENES_DIR = Path(__file__).resolve().parents[2] / "scenes"
# purpose tag of the rendering's path-tracing streams (rjfit.render.mitsuba_scene.mitsuba_seed):
# the validation traces the same scenes with the same user seed, and must not reuse these samples
RENDER_STREAM = 1


def available_scenes() -> list[str]:
    """Names of the built-in scene definitions in ``scenes/``."""
    return sorted(p.stem for p in SCENES_DIR.glob("*.json"))


def load_scene_definition(scene) -> dict:
    """A scene definition from a built-in name, a JSON path, or a dict (copied).

    Raises
    ------
    FileNotFoundError
        If neither a built-in scene nor a file of that name exists.
    SceneError
        If the definition has a missing or out-of-range entry (a ``DatasetError`` naming the
        file, the entry and its allowed values; see :mod:`rjfit.data.descriptions`).
    """
    from rjfit.data.descriptions import check_scene_definition

    if isinstance(scene, dict):
        return check_scene_definition(json.loads(json.dumps(scene)))
    candidate = Path(scene)
    if not candidate.is_file():
        candidate = SCENES_DIR / f"{scene}.json"
    if not candidate.is_file():
        raise FileNotFoundError(f"scene {scene!r}: no such file and no built-in scene of that name "
                                f"(built-in: {', '.join(available_scenes())})")
    return check_scene_definition(read_json(candidate), candidate)


def write_mesh_parts(geometry: dict, mesh_dir: Path) -> list[dict]:
    """Generate the scene's meshes and write one PLY (with vertex normals) per part."""
    mesh_dir.mkdir(parents=True, exist_ok=True)
    entries = []
    for index, (mesh, material_index) in enumerate(build_parts(geometry)):
        file_name = f"part_{index:03d}.ply"
        mesh.export(mesh_dir / file_name, file_type="ply", vertex_normal=True)
        entries.append({"file": f"meshes/{file_name}", "material": int(material_index),
                        "faces": int(len(mesh.faces))})
    return entries


#: The BSDF of a scene rebuilt without known materials (a measured mesh stack's): enough for its
#: geometry (pixel-centre hits, shadow rays); callers that render radiance pass materials.
GEOMETRY_MATERIAL = {"I0": 1.0, "kd": 1.0, "gamma": 1.0}


def scene_from_dataset_meta(meta: dict, dataset_dir: Path, *, materials=None, lights=None, max_depth=None,
                            light_format="rgb", bsdf_override=None, extra=None):
    """Rebuild the Mitsuba scene of a data set with a mesh (the active variant is used).

    ``meta`` is ``Dataset.meta``: a rendered data set's ``dataset.json``, or a measured mesh
    stack's ``stack.json`` as :func:`rjfit.render.mesh_stack.load_mesh_stack` completes it (its
    mesh as the one entry of ``meshes``, material 0). Mesh files are relative to
    ``dataset_dir``. Without ``materials`` the data set's own are used, or, when it has none
    (a measured stack), :data:`GEOMETRY_MATERIAL` for every part.

    Raises
    ------
    DatasetError
        If Mitsuba cannot load the scene (a damaged mesh file): one line naming the data set
        and Mitsuba's reason, which names the file.
    """
    from rjfit.render.mitsuba_scene import build_scene

    parts = [(Path(dataset_dir) / entry["file"], entry["material"]) for entry in meta["meshes"]]
    if materials is None:
        materials = meta.get("materials") or [GEOMETRY_MATERIAL] * (max(m for _, m in parts) + 1)
    try:
        return build_scene(meta["camera"], meta["resolution"], parts, materials,
                           lights if lights is not None else [Light.from_json(e) for e in meta["lights"]],
                           reference_intensity=meta["reference_intensity"],
                           max_depth=max_depth if max_depth is not None else meta.get("max_depth", 8),
                           light_format=light_format, bsdf_override=bsdf_override, extra=extra)
    except RuntimeError as error:      # Mitsuba's loader reports a damaged file as a RuntimeError
        reason = " ".join(str(error).split())
        files = ", ".join(str(path) for path, _ in parts)
        fix = "export the stack's mesh again" if meta.get("layout") == "mesh-stack" else "render the data set again"
        raise DatasetError(f"{dataset_dir}: Mitsuba cannot load the data set's scene: {reason}; is a mesh file "
                           f"({files}) damaged? If so, {fix}") from error


def check_replaceable(out_dir: Path) -> None:
    """Refuse to replace a folder that is not a rendered data set (or empty): ``--out`` pointed
    at the wrong folder must not delete it.

    Raises
    ------
    DatasetError
        If ``out_dir`` is the working folder or one of its parents, or a non-empty folder
        without ``dataset.json``.
    """
    out_dir = Path(out_dir).resolve()
    if out_dir == Path.cwd().resolve() or out_dir in Path.cwd().resolve().parents:
        raise DatasetError(f"{out_dir}: refusing to write a data set over the working folder or one of its "
                           f"parents; pass a new folder, e.g. --out {out_dir / 'dataset'}")
    if out_dir.exists() and (not out_dir.is_dir() or (any(out_dir.iterdir())
                                                      and not (out_dir / "dataset.json").is_file())):
        raise DatasetError(f"{out_dir}: exists and is not a data set (no dataset.json), so it is not replaced; "
                           f"pass a new or empty folder, or delete it yourself")


def _render_settings(definition, resolution, seed, spp, noise_variance):
    """``(seed, spp, noise_variance)`` from the arguments or the definition; ``definition``'s
    resolution overridden in place.

    Raises
    ------
    ValueError
        For a resolution or spp below 1, or a negative noise variance.
    """
    if resolution is not None:
        definition["resolution"] = [int(resolution), int(resolution)] if np.isscalar(resolution) else list(resolution)
    seed = int(definition.get("seed", 0) if seed is None else seed)
    spp = int(definition.get("spp", 1) if spp is None else spp)
    noise_variance = float(definition.get("noise_variance", 0.0) if noise_variance is None else noise_variance)
    if noise_variance < 0:
        raise ValueError(f"noise variance must be >= 0, got {noise_variance}")
    if spp < 1:
        raise ValueError(f"spp (samples per pixel) must be >= 1, got {spp}")
    if min(definition["resolution"]) < 1:
        raise ValueError(f"resolution must be >= 1 pixel, got {definition['resolution']}")
    return seed, spp, noise_variance


def _write_geometry(staging, geometry_scene, traced, lights):
    """The data set's truth: geometry.exr (P, N, V, mask), truth_labels.exr and visibility.exr."""
    from rjfit.render.mitsuba_scene import shadow_visibility

    height, width = traced["hit"].shape
    write_exr(staging / "geometry.exr", {
        **{f"P.{a}": traced["positions"][..., i] for i, a in enumerate("XYZ")},
        **{f"N.{a}": traced["normals"][..., i] for i, a in enumerate("XYZ")},
        **{f"V.{a}": traced["view_dirs"][..., i] for i, a in enumerate("XYZ")},
        "mask": traced["hit"]})
    write_exr(staging / "truth_labels.exr", {"label": traced["material"]})
    write_exr(staging / "visibility.exr", {
        f"light_{i:03d}": shadow_visibility(geometry_scene, traced["_interaction"], light, (height, width))
        for i, light in enumerate(lights)})


def _render_lights(meta, staging, lights, scene_args, shape, *, seed, spp, noise_variance, progress):
    """The noisy (L, H, W, 3) stack: each light path-traced alone, plus achromatic Gaussian noise
    drawn from ``seed``'s noise stream."""
    from rjfit.render.mitsuba_scene import light_scenes, path_trace

    height, width = shape
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5EED]))
    images = []
    scenes = light_scenes(lambda one: scene_from_dataset_meta(meta, staging, lights=one, **scene_args), lights,
                          scene_args["light_format"])
    iterator = range(len(lights))
    if progress:        # a bar on a terminal, plain lines in a log
        iterator = tracked(iterator, f"render {meta['name']}", "light")
    for light_index, light_scene in zip(iterator, scenes):
        radiance = path_trace(light_scene, spp=spp, seed=(seed, RENDER_STREAM, light_index))
        if radiance.shape[-1] == 1:
            radiance = np.repeat(radiance, 3, axis=-1)
        noise = rng.normal(0.0, np.sqrt(noise_variance), size=(height, width, 1)) if noise_variance else 0.0
        images.append(radiance + noise)
    return np.stack(images)


def _dataset_meta(definition, lights, meshes, mi, *, noise_variance, seed, spp, hidden_effects):
    """``dataset.json``'s contents but the render time: what was rendered, how, with which versions."""
    from importlib.metadata import version

    import drjit as dr

    materials = [dict(m, sigma2=noise_variance) for m in definition["materials"]]
    meta = {
        "format": DATASET_FORMAT, "name": definition["name"], "kind": "synthetic",
        "description": definition.get("description", ""), "units": definition.get("units", ""),
        "resolution": definition["resolution"], "camera": definition["camera"],
        "lights": [light.to_json() for light in lights],
        "reference_intensity": float(definition.get("reference_intensity", 1.0)),
        "materials": materials, "meshes": meshes, "geometry_definition": definition["geometry"],
        "noise_variance": noise_variance, "seed": seed, "spp": spp,
        "max_depth": int(definition.get("max_depth", 8)), "variant": mi.variant(),
        "sampling": "one camera ray through each pixel centre; spp repeats it",
        "noise": "achromatic Gaussian, the same draw in R, G, B",
        "images": [f"images/light_{i:03d}.exr" for i in range(len(lights))],
        "geometry": "geometry.exr", "visibility": "visibility.exr", "truth_labels": "truth_labels.exr",
        "hidden_effects": list(hidden_effects),
        "versions": {"mitsuba": mi.__version__, "drjit": dr.__version__, "rjfit": version("rjfit")},
    }
    return meta


def render_dataset(scene, out_dir, *, resolution=None, seed=None, spp=None, noise_variance=None,
                   variant="auto", progress=False, bsdf_override=None, extra=None, light_format="rgb",
                   post_process=None, hidden_effects=()):
    """Render a scene definition into a data set folder (written atomically, as a whole).

    Each light is rendered alone (a scene with that one emitter, built once and its emitter moved
    from light to light: :func:`rjfit.render.mitsuba_scene.light_scenes`): the path integrator picks
    one emitter per sample, so lights switched off in a shared scene would add variance.

    Parameters
    ----------
    scene : str, Path or dict
        Built-in scene name, scene JSON file, or a definition.
    out_dir : path
        The data set folder; replaced if it exists and is a data set (or empty).
    resolution : int or (int, int), optional
        Overrides the definition's ``[height, width]``.
    seed : int, optional
        Seeds path tracing and the noise (default: the definition's seed).
    spp : int, optional
        Samples per pixel (same ray each time; only indirect light is random).
    noise_variance : float, optional
        Variance of the Gaussian noise added to every pixel (achromatic: the same draw in
        R, G, B, so each channel and their mean have exactly this variance).
    variant : str
        Mitsuba variant; "auto" takes cuda_ad_rgb where a GPU answers, else llvm_ad_rgb
        (scalar_rgb traces one pixel at a time: slow, for checks and benchmarks; spectral and
        polarized variants are refused). The one that ran is recorded.
    bsdf_override, extra, light_format, post_process, hidden_effects
        For data sets with a hidden effect: replace the plugin by other BSDFs, add scene
        entries (e.g. an environment emitter), pass light values as spectra, or transform
        the noisy images (``post_process(images) -> images``); recorded in the JSON.

    Returns
    -------
    Path
        The data set folder.

    Raises
    ------
    DatasetError
        If ``out_dir`` exists and is neither empty nor a data set (see :func:`check_replaceable`).
    ValueError
        For a resolution or spp below 1, or a negative noise variance.
    """
    from rjfit.render.mitsuba_scene import activate, trace_pixels

    started = time.perf_counter()
    definition = load_scene_definition(scene)
    seed, spp, noise_variance = _render_settings(definition, resolution, seed, spp, noise_variance)
    out_dir = Path(out_dir).resolve()
    check_replaceable(out_dir)
    mi = activate(variant)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    try:
        meshes = write_mesh_parts(definition["geometry"], staging / "meshes")
        lights = [Light.from_json(entry) for entry in definition["lights"]]
        meta = _dataset_meta(definition, lights, meshes, mi, noise_variance=noise_variance, seed=seed, spp=spp,
                             hidden_effects=hidden_effects)
        scene_args = dict(light_format=light_format, bsdf_override=bsdf_override, extra=extra)
        geometry_scene = scene_from_dataset_meta(meta, staging, lights=[], **scene_args)
        traced = trace_pixels(geometry_scene, [entry["material"] for entry in meshes])
        _write_geometry(staging, geometry_scene, traced, lights)
        images = _render_lights(meta, staging, lights, scene_args, traced["hit"].shape, seed=seed, spp=spp,
                                noise_variance=noise_variance, progress=progress)
        if post_process is not None:
            images = post_process(images)
        for light_index, image in enumerate(images):
            write_exr(staging / meta["images"][light_index], {c: image[..., i] for i, c in enumerate("RGB")})
        meta["render_seconds"] = round(time.perf_counter() - started, 3)
        write_json_atomic(staging / "dataset.json", meta)
        if out_dir.exists():
            shutil.rmtree(out_dir)
        staging.rename(out_dir)
    finally:
        if staging.exists():
            shutil.rmtree(staging)
    return out_dir
