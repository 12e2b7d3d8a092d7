"""Measured stacks with a mesh, a calibrated camera and point (or directional) lights.

A folder with ``stack.json``::

    {"format": "rjfit-mesh-stack/1",
     "images": ["img_000.exr", ...],            # linear HDR: EXR, or 16-bit PNG / TIFF
     "mesh": "object.ply",                       # PLY / OBJ / ... (trimesh), in scene units
     "camera": {"kind": "perspective", "origin": [...], "target": [...], "up": [...], "fov": 20},
     "resolution": [height, width],
     "lights": [{"kind": "point", "position": [...], "intensity": 1.0}, ...],
     "reference_intensity": 1.0,
     "saturation": 65535}                        # optional: raw value at which a pixel clips
                                                 # (default: the integer type's largest code; none for float)

The per-pixel geometry (positions, shading normals, view directions, shadow-ray
visibility) comes from tracing the mesh with Mitsuba from the camera, through each pixel
centre, exactly as for rendered data sets; the gate then path-traces the same mesh. The
loaded ``Dataset.meta`` is ``stack.json`` plus ``meshes`` (the mesh as the one part, material
0), which is what :func:`rjfit.render.render.scene_from_dataset_meta` rebuilds the scene
from, here and for diagnose's Mitsuba features (shadow rays, indirect light, simulation).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rjfit.data.dataset import Dataset, dark_flags
from rjfit.data.lights import Light
from rjfit.errors import DatasetError, DatasetFileNotFoundError
from rjfit.io import read_json

__all__ = ["load_mesh_stack"]


def load_mesh_stack(path, *, variant: str = "auto") -> Dataset:
    """Load a mesh stack (see the module docstring); the geometry is traced with Mitsuba.

    Raises
    ------
    DatasetFileNotFoundError
        If ``stack.json``, the mesh or an image is missing.
    DatasetError
        If the description is incomplete, images and lights do not pair up, sizes differ,
        pixels are NaN/Inf, 8-bit data is given as linear, the mesh has no faces, or the
        camera sees no part of the mesh.
    """
    from rjfit.data.checks import check_lights_face_object, check_radiance, radiance_floor
    from rjfit.data.diligent_files import check_depth, read_raw_image
    from rjfit.data.mesh import load_mesh
    from rjfit.render.mitsuba_scene import activate, shadow_visibility, trace_pixels
    from rjfit.render.render import scene_from_dataset_meta

    path = Path(path)
    description = path / "stack.json"
    if not description.is_file():
        raise DatasetFileNotFoundError(f"{description}: no such file")
    from rjfit.data.descriptions import check_stack_description

    meta = check_stack_description(read_json(description), description)
    lights = [Light.from_json(entry) for entry in meta["lights"]]
    if len(lights) != len(meta["images"]):
        raise DatasetError(f"{description}: {len(lights)} lights but {len(meta['images'])} images; every light "
                           f"needs exactly one image")
    height, width = (int(n) for n in meta["resolution"])
    load_mesh(path / meta["mesh"])      # clear errors for a missing file or a mesh without faces
    images, reference = [], None
    for name in meta["images"]:
        image_path = path / name
        if not image_path.is_file():
            raise DatasetFileNotFoundError(f"{image_path}: no such file; {description} names it as an image")
        raw = read_raw_image(image_path)
        check_depth(raw, image_path, None, reference)
        reference = reference or (raw.dtype, image_path)
        if raw.shape[:2] != (height, width):
            raise DatasetError(f"{image_path}: image is {raw.shape[1]} x {raw.shape[0]}, {description} says "
                               f"{width} x {height}")
        check_radiance(raw, image_path, radiance_floor(meta.get("noise_variance")))
        images.append(raw)
    images = np.stack(images)
    saturation = meta.get("saturation")
    if saturation is None and np.issubdtype(images.dtype, np.integer):
        saturation = np.iinfo(images.dtype).max          # an integer image clips at its largest code
    saturated = (images >= saturation).any(axis=-1) if saturation is not None else None
    mi = activate(variant)
    # The stack in the rjfit layout's terms (its mesh is the one part, material 0): the scene is
    # rebuilt from this meta here and wherever Mitsuba needs it again (diagnose's features).
    dataset_meta = dict(meta, kind="measured", layout="mesh-stack", variant=mi.variant(),
                        meshes=[{"file": meta["mesh"], "material": 0}],
                        reference_intensity=float(meta.get("reference_intensity", 1.0)))
    scene = scene_from_dataset_meta(dataset_meta, path, lights=[])
    traced = trace_pixels(scene, [0])
    if not traced["hit"].any():
        raise DatasetError(f"{description}: the camera sees no part of {path / meta['mesh']}; check the camera's "
                           f"origin, target and field of view and the mesh's units")
    visibility = np.stack([shadow_visibility(scene, traced["_interaction"], light, (height, width))
                           for light in lights])
    check_lights_face_object(lights, traced["normals"], traced["positions"], traced["view_dirs"], traced["hit"],
                             lambda i: f"{description}" if i is None else f"{description} light {i}")
    return Dataset(path=path, meta=dataset_meta, images=images.astype(np.float32), normals=traced["normals"],
                   view_dirs=traced["view_dirs"], positions=traced["positions"], visibility=visibility,
                   object_mask=traced["hit"], lights=lights, saturated=saturated,
                   too_dark=dark_flags(images, meta.get("dark")))
