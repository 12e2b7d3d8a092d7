"""Photometric-stereo folders: the DiLiGenT layout, and generic folders laid out like it.

Layout (DiLiGenT: Shi et al., "A Benchmark Dataset and Evaluation for Non-Lambertian and
Uncalibrated Photometric Stereo", CVPR 2016)::

    FOLDER/filenames.txt          image file names, one per line; line i is the image of light i
    FOLDER/light_directions.txt   one unit vector "x y z" per line, *towards* the (distant) light
    FOLDER/light_intensities.txt  one RGB triple "r g b" (or one value) per line: relative intensities
    FOLDER/mask.png               object mask, non-zero on the object (8- or 16-bit, grey or RGB)
                                  in its colour channels; an alpha channel is not part of it
                                  (another file of the folder with ``mask="NAME"``)
    FOLDER/Normal_gt.mat          normal map (H, W, 3), MATLAB variable ``Normal_gt``; or one of
                                  ``NORMAL_MAP_NAMES`` (.npy / .mat / .exr), or ``normals=`` given
    FOLDER/001.png ...            the images: 16-bit linear PNG or TIFF (read whole with OpenCV),
                                  float EXR or TIFF; 8-bit (or 8-bit codes widened to 16 bits, with
                                  ``bits=8``) only as declared: ``encoded="sRGB"``, ``encoded="linear"``
                                  or ``response="unknown"`` (see :mod:`rjfit.data.codes`)
    FOLDER/rjfit.json             optional: how to read the folder, for the command line, e.g.
                                  ``{"encoded": "sRGB", "saturation": 250, "dark": 5}`` (keys: the options of
                                  :func:`load_diligent`; an argument given to it wins). Part of
                                  the folder, so the cross-check's fingerprint covers it.

Conventions (DiLiGenT's): an orthographic camera looking along -z, so the view direction is
v = (0, 0, 1) at every pixel; x to the right, y up, z towards the camera, for normals and light
directions alike; image rows run top to bottom (row index grows as y falls).

A perspective (pinhole) camera is declared with ``camera={"kind": "perspective", "focal_px": f,
"principal_point": [cx, cy]}`` (``rjfit.json`` or :func:`load_diligent`): the focal length in
pixels (square pixels) and the principal point in pixel coordinates of the files' full frame,
where pixel (row r, column c) spans [c, c + 1] x [r, r + 1] (default: the frame's centre,
[W / 2, H / 2]). The camera sits at the origin of the same axes, looking along -z. With
distant lights the radiance then depends on the point only through its normal and the
direction towards the camera, which for a pinhole is minus the pixel-centre ray's
direction, whatever the depth: ``v = normalise(-(c + 0.5 - cx) / f, (r + 0.5 - cy) / f, 1)``.
So no depth map is needed.

Units of the loaded images: for integer images, raw sensor counts divided by the light's
intensity in that channel (``raw / intensity[l, c]``); for sRGB-encoded images, the decoded linear
value in [0, 1] divided by the intensity; for float images, the stored value divided by the
intensity. ``response="unknown"``: the raw codes, not decoded (``Dataset.response`` says so, and
:func:`rjfit.data.response.estimate_power_response` estimates a power-law response), divided by
the intensity, which must then be the same for every light (per channel): an intensity cannot be
divided out of codes that are not linear in it. Integer codes read as linear or raw carry a
known quantisation noise floor, ``Dataset.quantisation_variance`` (1/12 code squared, in these
units). Every light is then a ``Light(kind="directional", intensity=1.0)``: its intensity has
been divided out of its image.

Saturation: an observation (pixel, light) is saturated when any channel's raw value is at or
above the threshold (default: the largest code of the file's integer type, 65535 for 16 bits;
none for float images). Dividing by per-channel intensities makes the threshold differ per light
and channel in the stored units, so the loader stores the flags, ``Dataset.saturated`` (L, H, W),
which ``Dataset.valid_mask`` excludes.

Dark: with a declared ``dark`` threshold (raw code values, as for saturation), an observation
whose every channel is at or below it is flagged in ``Dataset.too_dark`` and excluded too; a
photometric-stereo folder has no shadow rays, so this is how cast shadows are kept out.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rjfit.data.checks import check_lights_face_object, check_mask, check_unit_normals
from rjfit.data.codes import BITS, ENCODINGS, QUANTISATION_VARIANCE_CODES, RESPONSES, response_of
from rjfit.data.dataset import Dataset
from rjfit.data.diligent_files import (
    NORMAL_MAP_NAMES,
    check_reading,
    find_normal_map,
    numbered_lines,
    read_images,
    read_mask,
    read_normal_map,
    read_vectors,
    require_file,
    size_text,
)
from rjfit.data.folder_camera import CAMERA_KINDS, camera_meta, check_camera, is_finite_number, view_directions
from rjfit.data.lights import Light
from rjfit.errors import DatasetError, DatasetFileNotFoundError
from rjfit.io import read_json

__all__ = ["is_diligent_folder", "load_diligent", "crop_to_mask", "check_camera", "view_directions", "LAYOUT_FILES",
           "NORMAL_MAP_NAMES", "ENCODINGS", "CAMERA_KINDS"]

FILENAMES = "filenames.txt"
DIRECTIONS = "light_directions.txt"
INTENSITIES = "light_intensities.txt"
LIGHT_DIRECTION_TOLERANCE = 0.01      # largest | |d| - 1 | of a light direction read from DIRECTIONS
MASK = "mask.png"
LAYOUT_FILES = (FILENAMES, DIRECTIONS, INTENSITIES, MASK)
OPTIONS_FILE = "rjfit.json"
_OPTIONS = ("saturation", "dark", "encoded", "response", "bits", "mask", "normals", "crop", "camera")


def is_diligent_folder(path) -> bool:
    """Whether ``path`` is a folder laid out as a photometric-stereo (DiLiGenT-style) stack.

    True when the folder holds ``filenames.txt`` or ``light_directions.txt``: such a folder is
    meant to be one, and :func:`load_diligent` then names whichever other file is missing.
    """
    path = Path(path)
    return path.is_dir() and ((path / FILENAMES).is_file() or (path / DIRECTIONS).is_file())


def folder_options(folder) -> dict:
    """The loader options declared in ``FOLDER/rjfit.json`` ({} without one).

    Raises
    ------
    DatasetError
        If the file is not a JSON object of known options.
    """
    path = Path(folder) / OPTIONS_FILE
    if not path.is_file():
        return {}
    options = read_json(path)
    unknown = sorted(set(options) - set(_OPTIONS)) if isinstance(options, dict) else None
    if unknown is None or unknown:
        raise DatasetError(f"{path}: must be a JSON object with keys among {', '.join(_OPTIONS)}"
                           + (f"; unknown: {', '.join(unknown)}" if unknown else ""))
    rules = {"saturation": (lambda v: v is None or (is_finite_number(v) and v > 0), "a raw value > 0, or null"),
             "dark": (lambda v: v is None or (is_finite_number(v) and v >= 0), "a raw value >= 0, or null"),
             "encoded": (lambda v: v is None or v in ENCODINGS,
                         "null (linear 16-bit or float data), \"linear\" (integer codes linear in radiance, 8-bit "
                         "allowed) or \"sRGB\" (sRGB-encoded integer codes, decoded)"),
             "response": (lambda v: v is None or v in RESPONSES,
                          "\"unknown\" (the camera response is not known: the images are read as raw codes and a "
                          "later stage estimates it) or null (known: linear, or as \"encoded\" says)"),
             "bits": (lambda v: v is None or (isinstance(v, int) and not isinstance(v, bool) and v in BITS),
                      "8 (the integer files hold 8-bit codes; 16-bit files holding them widened by 257 or 256 are "
                      "divided back), 16 (the files' 16 bits are real: no check for widened 8-bit data) or null "
                      "(the files' own type)"),
             "mask": (lambda v: v is None or _is_plain_name(v),
                      "the file name of the object mask in this folder (no folder part), or null for mask.png"),
             "normals": (lambda v: v is None or (isinstance(v, str) and v), "a file name, or null"),
             "crop": (lambda v: isinstance(v, bool) or (isinstance(v, int) and v >= 0),
                      "true, false or a margin in pixels >= 0"),
             "camera": (lambda v: v is None or isinstance(v, dict), "an object such as {\"kind\": \"orthographic\"}")}
    for key, value in options.items():
        valid, allowed = rules[key]
        if not valid(value):
            raise DatasetError(f"{path}: {key} is {value!r}; it must be {allowed}")
    if options.get("camera") is not None:
        check_camera(options["camera"], f"{path}: camera")
    return options


def _is_plain_name(value) -> bool:
    """A file name without a folder part: a mask elsewhere would escape the gate's fingerprint of the folder."""
    return isinstance(value, str) and value not in ("", ".", "..") and "/" not in value and "\\" not in value


_UNSET = object()


def load_diligent(path, *, saturation=_UNSET, dark=_UNSET, encoded=_UNSET, response=_UNSET, bits=_UNSET,
                  mask=_UNSET, normals=_UNSET, crop=_UNSET, camera=_UNSET):
    """Load a photometric-stereo folder (DiLiGenT layout; see the module docstring) as a Dataset.

    Each option not given here is read from the folder's ``rjfit.json`` if it declares it
    (see the module docstring), else takes the default below.

    Parameters
    ----------
    path : path-like
        The folder.
    saturation : float or None
        Raw value (in the declared codes, before decoding or dividing by the light's
        intensity) at or above which a channel counts as clipped; an observation is saturated when
        any of its channels is. None: the largest code (65535 for 16-bit, 255 for 8-bit codes,
        also with ``bits=8``), and no threshold for float images.
    dark : float or None
        Raw value (the file's own code values, like ``saturation``) at or below which an
        observation is too dark to measure the surface (a cast shadow, the background, the
        sensor's floor) when every channel is; such observations never enter the likelihood
        (``Dataset.too_dark``). None (default): no threshold; attached shadows (light behind
        the surface) are left out by the geometry in any case.
    encoded : None, "linear" or "sRGB"
        None: the images are linear (16-bit integer or float). ``"linear"``: integer codes linear
        in radiance, 8-bit ones included. ``"sRGB"``: integer images are sRGB-encoded and are
        decoded with ``colour.cctf_decoding(value / max_code, "sRGB")``.
    response : None or "unknown"
        ``"unknown"``: the camera response is not known; integer images of any depth are read as
        raw codes, not decoded, and ``Dataset.response`` is ``"unknown"`` (``encoded`` must be None).
    bits : None, 8 or 16
        Declared depth of the integer codes: 8 divides 16-bit files holding 8-bit codes (every
        value a multiple of 257, or of 256) back to them; 16 reads 16-bit files as they are;
        None refuses 16-bit files holding 8-bit codes (see :mod:`rjfit.data.codes`).
    mask : str or None
        File name of the object mask in the folder; None: ``mask.png``.
    normals : path-like or None
        The normal map, relative to the folder; None looks for ``NORMAL_MAP_NAMES``.
    crop : bool or int
        False: keep the whole frame. True or a margin in pixels (True means 2): crop every array
        to the mask's bounding box plus the margin (see :func:`crop_to_mask`); the DiLiGenT ball
        then shrinks from 612 x 512 to 146 x 146 pixels and per-pixel work ~15 times.
    camera : dict or None
        None or ``{"kind": "orthographic"}``: view direction (0, 0, 1) everywhere (DiLiGenT's).
        ``{"kind": "perspective", "focal_px": f, "principal_point": [cx, cy]}``: a pinhole camera
        (see the module docstring); the principal point defaults to the frame's centre.

    Returns
    -------
    Dataset
        ``images`` float32 (L, H, W, 3) in the units of the module docstring; directional lights of
        intensity 1; ``view_dirs`` from the camera; ``positions`` and ``visibility`` None; ``saturated``
        (L, H, W) flags; ``response`` (``"linear"``, ``"sRGB"`` or ``"unknown"``) and
        ``quantisation_variance`` (L, 3) for integer codes read as linear or raw (else None).

    Raises
    ------
    DatasetFileNotFoundError
        A layout file, the (named) mask, the normal map or an image (a light without an image) is
        missing.
    DatasetError
        Any other problem: the message names the file (and line) and what is wrong.
    """
    folder = Path(path)
    if not folder.is_dir():
        raise DatasetFileNotFoundError(f"{folder}: no such folder")
    declared = {**dict.fromkeys(_OPTIONS), "crop": False, **folder_options(folder)}
    saturation, dark, encoded, response, bits, mask_name, normals, crop, camera = (
        declared[name] if given is _UNSET else given for name, given in
        (("saturation", saturation), ("dark", dark), ("encoded", encoded), ("response", response), ("bits", bits),
         ("mask", mask), ("normals", normals), ("crop", crop), ("camera", camera)))
    camera = check_camera(camera, f"{folder}: camera")
    check_reading(folder, encoded, response, bits)
    lights = _read_lights(folder, response)
    geometry = _read_geometry(folder, mask_name, normals, camera, lights)
    reading = read_images(lights.image_files, geometry[1], geometry[0], lights.intensities, encoded, response, bits,
                          saturation, dark)
    dataset = _measured_dataset(folder, camera, lights, geometry, reading, response_of(encoded, response), encoded,
                                dark)
    return dataset if crop is False or crop is None else crop_to_mask(dataset, margin=2 if crop is True else int(crop))


def _read_geometry(folder: Path, mask_name, normals, camera, lights):
    """``(mask file, mask, normal map file, normal map, view directions)`` of :func:`load_diligent`'s folder,
    checked: the mask ``mask_name`` (None: ``mask.png``) and the normal map ``normals`` (None: the first of
    ``NORMAL_MAP_NAMES``) of one size, unit normals inside the mask (zero outside it) and every light in front of
    part of the object as ``camera`` sees it. Raises as :func:`load_diligent` does."""
    mask_file = folder / (mask_name or MASK)
    if mask_name is not None and not mask_file.is_file():
        raise DatasetFileNotFoundError(f"{mask_file}: no such file (the object mask that mask={mask_name!r} names, "
                                       f"in {OPTIONS_FILE} or as an argument)")
    require_file(mask_file, "object mask")
    normals_file = find_normal_map(folder, normals)
    mask = read_mask(mask_file)
    check_mask(mask, mask_file)
    normal_map = read_normal_map(normals_file)
    if normal_map.shape[:2] != mask.shape:
        raise DatasetError(f"{normals_file}: normal map is {size_text(normal_map)}, but {mask_file.name} is "
                           f"{size_text(mask)}; the mask, the normal map and every image must have one size")
    check_unit_normals(normal_map, mask, normals_file)
    normal_map = np.where(mask[..., None], normal_map, 0.0)
    view_dirs = view_directions(camera, *mask.shape)
    check_lights_face_object(lights.lights, normal_map, None, view_dirs, mask, lights.describe)
    return mask_file, mask, normals_file, normal_map, view_dirs


def _measured_dataset(folder: Path, camera, lights, geometry, reading, dataset_response, encoded, dark) -> Dataset:
    """:func:`load_diligent`'s Dataset before any crop, from ``geometry`` (:func:`_read_geometry`'s) and ``reading``
    (:func:`rjfit.data.diligent_io.read_images`'): its arrays, and a ``meta`` that says where it came from, its
    camera, units, codes, lights and the saturation and dark rules with their counts inside the mask."""
    mask_file, mask, normals_file, normal_map, view_dirs = geometry
    images, saturated, too_dark, threshold_used, pixel_type, max_code = reading
    quantised = max_code is not None and dataset_response != "sRGB"
    meta = {
        "name": folder.resolve().name, "kind": "measured", "layout": "diligent",
        "source": "photometric-stereo folder, DiLiGenT layout (Shi et al., CVPR 2016)",
        "description": _first_heading(folder / "README.md"), "path": str(folder),
        "camera": {**camera_meta(camera, *mask.shape),
                   "axes": "x right, y up, z towards the camera; image rows top to bottom"},
        "resolution": list(mask.shape), "units": _units(dataset_response, encoded, max_code),
        "pixel_type": pixel_type, "encoded": encoded, "response": dataset_response,
        "bits": None if max_code is None else int(max_code).bit_length(),
        "quantisation": ({"step_raw": 1.0, "variance_raw": QUANTISATION_VARIANCE_CODES,
                          "rule": "uniform rounding to integer codes: variance step^2 / 12 in raw codes; "
                                  "Dataset.quantisation_variance holds it per light and channel in the images' "
                                  "units"} if quantised else None),
        "images": [str(file.relative_to(folder)) for file in lights.image_files], "normal_map": normals_file.name,
        "mask": mask_file.name, "mask_pixels": int(mask.sum()),
        "lights": [light.to_json() for light in lights.lights],
        "light_intensities_rgb": lights.intensities.tolist(),
        "saturation": {"raw_threshold": None if threshold_used is None else float(threshold_used),
                       "rule": "an observation is saturated when any channel's raw value >= raw_threshold",
                       "saturated_observations_in_mask": int(saturated[:, mask].sum())},
        "dark": {"raw_threshold": dark, "rule": "an observation is too dark when every channel's raw value <= "
                 "raw_threshold (null: no threshold)",
                 "dark_observations_in_mask": None if too_dark is None else int(too_dark[:, mask].sum())},
        "reference_intensity": 1.0,
    }
    return Dataset(path=folder, meta=meta, images=images, normals=normal_map, view_dirs=view_dirs,
                   positions=None, visibility=None, object_mask=mask, lights=lights.lights, saturation=None,
                   saturated=saturated, too_dark=too_dark, response=dataset_response,
                   quantisation_variance=QUANTISATION_VARIANCE_CODES / lights.intensities ** 2 if quantised else None)


def _units(response: str, encoded, max_code) -> str:
    if response == "unknown":
        return "raw camera codes, response unknown (not linear in radiance) / light intensity (per channel)"
    if encoded == "sRGB":
        return "sRGB-decoded linear value in [0, 1] / light intensity (per channel)"
    if max_code is not None:
        return "raw sensor counts / light intensity (per channel)"
    return "stored float value / light intensity (per channel)"


@dataclass(frozen=True)
class _FolderLights:
    """The lights of a folder paired one to one with their images, and how to name a light in a message."""

    lights: list
    intensities: np.ndarray      # (L, 3)
    image_files: list
    describe: object             # describe(index or None) -> text naming the light's line


def _read_lights(folder: Path, response) -> _FolderLights:
    """The image list, light directions and intensities, checked to pair up one to one."""
    names_file = require_file(folder / FILENAMES, "list of images")
    directions_file = require_file(folder / DIRECTIONS, "light directions")
    intensities_file = require_file(folder / INTENSITIES, "light intensities")
    listed = numbered_lines(names_file)
    if not listed:
        raise DatasetError(f"{names_file}: the file is empty (no images listed)")
    seen = {}
    for number, name in listed:
        if name in seen:
            raise DatasetError(f"{names_file} line {number}: {name} is listed twice (also on line {seen[name]}); "
                               f"each light needs its own image")
        seen[name] = number
    directions, direction_lines = read_vectors(directions_file, (3,), "a light direction x y z")
    intensities, intensity_lines = read_vectors(intensities_file, (1, 3), "a light intensity (r g b)")
    for other, rows, lines in ((directions_file, directions, direction_lines),
                               (intensities_file, intensities, intensity_lines)):
        if len(rows) < len(listed):
            number, name = listed[len(rows)]
            raise DatasetError(f"{names_file} lists {len(listed)} images but {other} has {len(rows)} lights: "
                               f"image {name} (line {number}) and any after it have no light")
        if len(rows) > len(listed):
            raise DatasetError(f"{other} has {len(rows)} lights but {names_file} lists {len(listed)} images: "
                               f"the light on line {lines[len(listed)]} and any after it have no image")
    image_files = [folder / name for _, name in listed]
    for index, (number, name) in enumerate(listed):
        if not image_files[index].is_file():
            raise DatasetFileNotFoundError(
                f"{image_files[index]}: no such file; {names_file} line {number} names it as the image of light "
                f"{index + 1} (a light without an image)")
    directions = _unit_directions(directions, directions_file, direction_lines)
    intensities = _intensities(intensities, intensities_file, intensity_lines, response)
    lights = [Light(kind="directional", intensity=1.0, direction=tuple(float(c) for c in d)) for d in directions]

    def describe(index):
        if index is None:
            return str(directions_file)
        d = directions[index]
        return (f"{directions_file} line {direction_lines[index]} (light {index + 1}, image {listed[index][1]}, "
                f"direction {d[0]:.4g} {d[1]:.4g} {d[2]:.4g})")

    return _FolderLights(lights=lights, intensities=intensities, image_files=image_files, describe=describe)


def _unit_directions(directions, directions_file, direction_lines) -> np.ndarray:
    directions = np.asarray(directions, dtype=np.float64)
    lengths = np.linalg.norm(directions, axis=1)
    if (lengths == 0).any():
        index = int(np.argmax(lengths == 0))
        raise DatasetError(f"{directions_file} line {direction_lines[index]}: light direction (0, 0, 0) has no "
                           f"length")
    # The layout promises unit vectors: a few decimals leave them within a fraction of a per cent
    # of length 1 (they are renormalised); further off is a typo or a position, not a direction.
    off = np.abs(lengths - 1.0) > LIGHT_DIRECTION_TOLERANCE
    if off.any():
        index = int(np.argmax(off))
        raise DatasetError(f"{directions_file} line {direction_lines[index]}: light direction "
                           f"{directions[index].tolist()} has length {lengths[index]:.4g}, not 1 (within "
                           f"{LIGHT_DIRECTION_TOLERANCE:g}); {int(off.sum())} of {len(lengths)} lines are so: the file "
                           f"holds unit vectors towards distant lights (point lights with positions belong in a "
                           f"stack.json mesh stack)")
    return directions / lengths[:, None]


def _intensities(intensities, intensities_file, intensity_lines, response) -> np.ndarray:
    intensities = np.asarray([row * 3 if len(row) == 1 else row for row in intensities], dtype=np.float64)
    if (intensities <= 0).any():
        index = int(np.argmax((intensities <= 0).any(axis=1)))
        raise DatasetError(f"{intensities_file} line {intensity_lines[index]}: light intensities must be positive, "
                           f"got {intensities[index].tolist()}")
    if response == "unknown" and (intensities != intensities[0]).any():
        index = int(np.argmax((intensities != intensities[0]).any(axis=1)))
        raise DatasetError(f"{intensities_file} line {intensity_lines[index]}: intensity {intensities[index].tolist()} "
                           f"differs from line {intensity_lines[0]}'s {intensities[0].tolist()}, but the response is "
                           f"unknown: an intensity cannot be divided out of codes that are not linear in it (give "
                           f"equal intensities, or declare the response)")
    return intensities


def crop_to_mask(dataset, margin=2):
    """The data set cut to its object mask's bounding box plus ``margin`` pixels (clipped to the frame).

    Every per-pixel array is sliced alike (a perspective camera's principal point moves with the
    crop's corner); ``meta["crop"]`` records ``row0``, ``col0`` (the crop's
    top-left pixel in the full frame) and ``full_resolution``; ``meta["resolution"]`` becomes the
    cropped size. Pixel (r, c) of the crop is pixel (r + row0, c + col0) of the files.
    """
    import dataclasses

    mask = dataset.object_mask
    rows, cols = np.nonzero(mask)
    height, width = mask.shape
    r0, r1 = max(int(rows.min()) - margin, 0), min(int(rows.max()) + 1 + margin, height)
    c0, c1 = max(int(cols.min()) - margin, 0), min(int(cols.max()) + 1 + margin, width)
    window = (slice(r0, r1), slice(c0, c1))
    per_light = (slice(None),) + window
    cut = lambda array, index: None if array is None else np.ascontiguousarray(array[index])
    meta = dict(dataset.meta)
    meta["crop"] = {"row0": r0, "col0": c0, "full_resolution": [height, width]}
    meta["resolution"] = [r1 - r0, c1 - c0]
    if meta.get("camera", {}).get("kind") == "perspective":
        # the principal point in the crop's pixel coordinates (the view directions are cut alike)
        cx, cy = meta["camera"]["principal_point"]
        meta["camera"] = {**meta["camera"], "principal_point": [cx - c0, cy - r0]}
    return dataclasses.replace(
        dataset, meta=meta, images=cut(dataset.images, per_light), normals=cut(dataset.normals, window),
        view_dirs=cut(dataset.view_dirs, window), positions=cut(dataset.positions, window),
        visibility=cut(dataset.visibility, per_light), object_mask=cut(dataset.object_mask, window),
        truth_labels=cut(dataset.truth_labels, window), saturated=cut(dataset.saturated, per_light),
        too_dark=cut(dataset.too_dark, per_light))


def _first_heading(readme: Path):
    if not readme.is_file():
        return None
    for line in readme.read_text(errors="replace").splitlines():
        if line.strip():
            return line.strip().lstrip("#").strip()
    return None
