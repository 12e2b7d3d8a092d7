"""Checks of a scene definition (``scenes/*.json`` or a user's scene JSON) before it is rendered.

A bad value in a scene file used to surface deep inside rendering: ``kd 1.5`` or ``gamma -2``
as a ``ValueError`` raised in the Mitsuba plugin's constructor (wrapped in Mitsuba's parser
error), a missing ``camera`` as ``KeyError: 'camera'``. :func:`check_scene_definition`
checks every entry the renderer reads, up front, and raises :class:`~rjfit.errors.SceneError`
(a ``DatasetError``, so the command line prints one line) naming the scene file, the entry
(``materials[0].kd``) and what values it allows.

The format (see ``scenes/paper_sphere.json``)::

    name               non-empty string
    resolution         [height, width], integers >= 1
    camera             {kind: perspective | orthographic, origin, target, up: 3 numbers,
                        fov: degrees in (0, 180) or focal_px > 0, principal_point: [cx, cy] in
                        pixels (optional; default the frame's centre) (perspective)
                        | half_width > 0 (orthographic)}
    geometry           {generator: sphere_quadrants | dented_slab, its arguments}
    materials          non-empty list of {I0 > 0, kd in [0, 1], gamma > 0, name (optional)}
    lights             non-empty list of {kind: point, position: 3 numbers, intensity > 0}
                        or {kind: directional, direction: 3 numbers (towards the light), intensity > 0}
    reference_intensity > 0 (optional, default 1)      noise_variance >= 0 (optional, default 0)
    spp                integer >= 1 (optional)          max_depth integer >= 2 (optional)
    seed               integer >= 0 (optional)          description, units: strings (optional)
"""
from __future__ import annotations

import inspect
import math
from numbers import Integral, Real

import numpy as np

from rjfit.data.formats import DATASET_FORMAT, MESH_STACK_FORMAT
from rjfit.data.meshes import GENERATORS
from rjfit.errors import SceneError

__all__ = ["check_scene_definition", "check_stack_description", "check_dataset_description"]

_TOP_LEVEL = {"name", "description", "units", "resolution", "camera", "geometry", "materials", "lights",
              "reference_intensity", "noise_variance", "spp", "max_depth", "seed"}
_REQUIRED = ("name", "resolution", "camera", "geometry", "materials", "lights")
_EXAMPLE = "see scenes/paper_sphere.json for a complete scene"


class _Checker:
    def __init__(self, source, hint=f"fix it in the scene file ({_EXAMPLE})", noun="a scene"):
        self.source = str(source)
        self.hint = hint
        self.noun = noun            # what needs a missing entry: "a scene needs a camera ..."

    def fail(self, field, message):
        raise SceneError(f"{self.source}: {field} {message}; {self.hint}")

    def _is_number(self, value):
        return isinstance(value, Real) and not isinstance(value, bool)

    def number(self, value, field, *, low=None, high=None, low_open=False, high_open=False, allowed=None):
        """A finite real number within the given bounds; ``allowed`` describes them in words."""
        ok = self._is_number(value) and math.isfinite(float(value))
        if ok and low is not None:
            ok = value > low if low_open else value >= low
        if ok and high is not None:
            ok = value < high if high_open else value <= high
        if not ok:
            self.fail(field, f"is {value!r}; it must be {allowed or 'a finite number'}")
        return float(value)

    def integer(self, value, field, *, low, allowed):
        if not (isinstance(value, Integral) and not isinstance(value, bool) and value >= low):
            self.fail(field, f"is {value!r}; it must be {allowed}")
        return int(value)

    def vector3(self, value, field):
        if not (isinstance(value, (list, tuple)) and len(value) == 3
                and all(self._is_number(v) and math.isfinite(float(v)) for v in value)):
            self.fail(field, f"is {value!r}; it must be a list of 3 finite numbers [x, y, z]")
        return [float(v) for v in value]

    def text(self, value, field, what):
        """A non-empty string; ``what`` says what it names (e.g. "a file name relative to the folder")."""
        if not (isinstance(value, str) and value.strip()):
            self.fail(field, f"is {value!r}; it must be {what}, a non-empty string")
        return value

    def texts(self, value, field, what, each):
        """A non-empty list of non-empty strings: ``what`` describes the list, ``each`` one entry."""
        if not (isinstance(value, list) and value):
            self.fail(field, f"is {value!r}; it must be a non-empty list of {what}")
        for index, entry in enumerate(value):
            self.text(entry, f"{field}[{index}]", each)
        return value

    def mapping(self, value, field, what):
        if not isinstance(value, dict):
            self.fail(field, f"is {value!r}; it must be an object {what}")
        return value

    def require(self, entry, key, field, what):
        if key not in entry:
            self.fail(f"{field}.{key}" if field else f"'{key}'", f"is missing; {self.noun} needs {what}")
        return entry[key]


def check_scene_definition(definition, source="the scene definition") -> dict:
    """Check a scene definition; return it unchanged.

    Parameters
    ----------
    definition : dict
        The parsed scene JSON.
    source : str or Path
        What to name in messages: the scene file's path.

    Raises
    ------
    SceneError
        (a ``DatasetError`` / ``ValueError``) naming ``source``, the entry and its allowed values.
    """
    check = _Checker(source)
    if not isinstance(definition, dict):
        raise SceneError(f"{source}: a scene definition is a JSON object {{name, resolution, camera, geometry, "
                         f"materials, lights, ...}}, got {type(definition).__name__}; {_EXAMPLE}")
    for key, what in (("name", "a name"), ("resolution", "a resolution [height, width]"),
                      ("camera", "a camera {kind, origin, target, up, fov or half_width}"),
                      ("geometry", "a geometry {generator, ...}"),
                      ("materials", "a list of materials {I0, kd, gamma}"),
                      ("lights", "a list of lights {kind, position or direction, intensity}")):
        check.require(definition, key, "", what)
    unknown = sorted(set(definition) - _TOP_LEVEL)
    if unknown:
        check.fail(f"entr{'ies' if len(unknown) > 1 else 'y'} {', '.join(map(repr, unknown))}",
                   f"{'are' if len(unknown) > 1 else 'is'} not part of a scene (a misspelling?); known entries: "
                   f"{', '.join(sorted(_TOP_LEVEL))}")
    if not (isinstance(definition["name"], str) and definition["name"].strip()):
        check.fail("name", f"is {definition['name']!r}; it must be a non-empty string")
    for key in ("description", "units"):
        if key in definition and not isinstance(definition[key], str):
            check.fail(key, f"is {definition[key]!r}; it must be a string")
    _check_view(check, definition)
    n_materials = _check_materials(check, definition["materials"])
    _check_geometry(check, definition["geometry"], n_materials)
    if "noise_variance" in definition:
        check.number(definition["noise_variance"], "noise_variance", low=0.0, allowed="a number >= 0")
    if "spp" in definition:
        check.integer(definition["spp"], "spp", low=1, allowed="an integer >= 1 (samples per pixel)")
    if "max_depth" in definition:
        check.integer(definition["max_depth"], "max_depth", low=2,
                      allowed="an integer >= 2 (path length; 2 = direct light only)")
    if "seed" in definition:
        check.integer(definition["seed"], "seed", low=0, allowed="an integer >= 0")
    return definition


def _check_view(check, entry, *, camera=True):
    """What scenes, mesh stacks and data sets share: resolution, camera (unless ``camera`` is
    False), lights, reference intensity."""
    resolution = entry["resolution"]
    if not (isinstance(resolution, (list, tuple)) and len(resolution) == 2):
        check.fail("resolution", f"is {resolution!r}; it must be [height, width], two integers >= 1")
    for index, size in enumerate(resolution):
        check.integer(size, f"resolution[{index}]", low=1, allowed="an integer >= 1 (pixels)")
    if camera:
        _check_camera(check, entry["camera"])
    _check_lights(check, entry["lights"])
    if "reference_intensity" in entry:
        check.number(entry["reference_intensity"], "reference_intensity", low=0.0, low_open=True,
                     allowed="a number > 0 (the intensity a region's I0 is relative to)")


def _check_camera(check, camera):
    check.mapping(camera, "camera", "{kind, origin, target, up, fov or focal_px or half_width}")
    kind = check.require(camera, "kind", "camera", "a camera kind ('perspective' or 'orthographic')")
    if kind not in ("perspective", "orthographic"):
        check.fail("camera.kind", f"is {kind!r}; it must be 'perspective' or 'orthographic'")
    points = {}
    for key in ("origin", "target", "up"):
        points[key] = check.vector3(check.require(camera, key, "camera", f"a camera {key} [x, y, z]"), f"camera.{key}")
    view = [t - o for t, o in zip(points["target"], points["origin"])]
    if math.hypot(*view) == 0.0:
        check.fail("camera.target", f"is {points['target']}, the same point as camera.origin; the camera must "
                                    f"look at a point away from it")
    up = points["up"]
    cross = [view[1] * up[2] - view[2] * up[1], view[2] * up[0] - view[0] * up[2], view[0] * up[1] - view[1] * up[0]]
    if math.hypot(*cross) <= 1e-9 * math.hypot(*view) * max(math.hypot(*up), 1e-300):
        check.fail("camera.up", f"is {up}, parallel to the viewing direction {view} (or zero); it must point "
                                f"across it (e.g. [0, 1, 0] for a camera on the z axis)")
    if kind == "perspective":
        # a calibrated pinhole gives its focal length (and principal point) in pixels instead
        if "focal_px" in camera and "fov" in camera:
            check.fail("camera", "gives both fov and focal_px; give one (fov in degrees along x, or the focal "
                                 "length in pixels)")
        if "focal_px" in camera:
            check.number(camera["focal_px"], "camera.focal_px", low=0.0, low_open=True,
                         allowed="a focal length in pixels, > 0 (square pixels)")
        else:
            fov = check.require(camera, "fov", "camera", "a field of view in degrees (or focal_px, a focal length "
                                                         "in pixels) for a perspective camera")
            check.number(fov, "camera.fov", low=0.0, high=180.0, low_open=True, high_open=True,
                         allowed="a horizontal field of view in degrees, in (0, 180)")
        if camera.get("principal_point") is not None:
            point = camera["principal_point"]
            if not (isinstance(point, list) and len(point) == 2):
                check.fail("camera.principal_point", f"is {point!r}; it must be [cx, cy] in pixels (x right, y down "
                                                     f"from the frame's top-left corner)")
            for axis, value in zip("xy", point):
                check.number(value, f"camera.principal_point ({axis})", allowed="a finite number of pixels")
    else:
        half_width = check.require(camera, "half_width", "camera", "a half width for an orthographic camera")
        check.number(half_width, "camera.half_width", low=0.0, low_open=True,
                     allowed="a number > 0 (half the visible width, in scene units)")


def _check_materials(check, materials):
    if not (isinstance(materials, list) and materials):
        check.fail("materials", f"is {materials!r}; it must be a non-empty list of {{I0, kd, gamma}}")
    for index, material in enumerate(materials):
        field = f"materials[{index}]"
        check.mapping(material, field, "{I0, kd, gamma}")
        for key, what in (("I0", "I0 > 0"), ("kd", "kd in [0, 1]"), ("gamma", "gamma > 0")):
            check.require(material, key, field, f"{what} for every material")
        check.number(material["I0"], f"{field}.I0", low=0.0, low_open=True,
                     allowed="a number > 0 (the region's intensity, reference_intensity x the material's scale)")
        check.number(material["kd"], f"{field}.kd", low=0.0, high=1.0,
                     allowed="a number in [0, 1] (the diffuse fraction; ks = 1 - kd)")
        check.number(material["gamma"], f"{field}.gamma", low=0.0, low_open=True,
                     allowed="a number > 0 (the Blinn-Phong exponent)")
        unknown = sorted(set(material) - {"name", "I0", "kd", "gamma"})
        if unknown:
            check.fail(f"{field}", f"has unknown entries {unknown}; a material holds name, I0, kd and gamma")
    return len(materials)


def _check_geometry(check, geometry, n_materials):

    check.mapping(geometry, "geometry", "{generator, ...}")
    name = check.require(geometry, "generator", "geometry", f"a generator ({', '.join(sorted(GENERATORS))})")
    if name not in GENERATORS:
        check.fail("geometry.generator", f"is {name!r}; it must be one of {', '.join(sorted(GENERATORS))}")
    parameters = inspect.signature(GENERATORS[name]).parameters
    unknown = sorted(set(geometry) - {"generator"} - set(parameters))
    if unknown:
        check.fail("geometry", f"has entries {unknown} that the {name!r} generator does not take; it takes "
                               f"{', '.join(parameters)}")
    arguments = {key: value.default for key, value in parameters.items()}
    arguments.update({key: value for key, value in geometry.items() if key != "generator"})
    if name == "sphere_quadrants":
        check.number(arguments["radius"], "geometry.radius", low=0.0, low_open=True, allowed="a number > 0")
        n_lon = check.integer(arguments["n_longitude"], "geometry.n_longitude", low=4,
                              allowed="an integer >= 4, a multiple of 4")
        if n_lon % 4:
            check.fail("geometry.n_longitude", f"is {n_lon}; it must be a multiple of 4 (no triangle may "
                                               f"straddle a quadrant boundary)")
        n_lat = check.integer(arguments["n_latitude"], "geometry.n_latitude", low=2, allowed="an even integer >= 2")
        if n_lat % 2:
            check.fail("geometry.n_latitude", f"is {n_lat}; it must be even (no triangle may straddle the equator)")
        parts = 4
    else:                                   # dented_slab
        size = check.number(arguments["size"], "geometry.size", low=0.0, low_open=True, allowed="a number > 0")
        check.integer(arguments["resolution"], "geometry.resolution", low=1, allowed="an integer >= 1 (grid cells)")
        check.number(arguments["boundary_x"], "geometry.boundary_x", low=-size / 2, high=size / 2,
                     allowed=f"a number in [-size/2, size/2] = [{-size / 2:g}, {size / 2:g}]")
        for key, fields in (("dents", ("x", "y", "depth", "width")), ("grooves", ("x", "depth", "width"))):
            entries = arguments[key]
            if not isinstance(entries, (list, tuple)):
                check.fail(f"geometry.{key}", f"is {entries!r}; it must be a list of [{', '.join(fields)}]")
            for index, entry in enumerate(entries):
                field = f"geometry.{key}[{index}]"
                if not (isinstance(entry, (list, tuple)) and len(entry) == len(fields)):
                    check.fail(field, f"is {entry!r}; it must be [{', '.join(fields)}]")
                for value, part in zip(entry, fields):
                    if part == "width":
                        check.number(value, f"{field} {part}", low=0.0, low_open=True, allowed="a number > 0")
                    else:
                        check.number(value, f"{field} {part}")
        parts = 2
        texels = arguments.get("material_map")
        if texels is not None:
            shape = np.shape(texels) if isinstance(texels, (list, tuple)) else ()
            if len(shape) != 2 or min(shape) < 1:
                check.fail("geometry.material_map", "must be a 2-D list of material indices (rows of texels)")
            values = np.asarray(texels)
            if not (np.issubdtype(values.dtype, np.integer) and values.min() >= 0):
                check.fail("geometry.material_map", "must hold integers >= 0 (indices into geometry.materials)")
            parts = int(values.max()) + 1
    indices = arguments["materials"]
    if not (isinstance(indices, (list, tuple)) and len(indices) == parts):
        check.fail("geometry.materials", f"is {indices!r}; the {name!r} generator needs {parts} material indices")
    for index, value in enumerate(indices):
        check.integer(value, f"geometry.materials[{index}]", low=0, allowed=f"a material index in [0, {n_materials - 1}]")
        if value >= n_materials:
            check.fail(f"geometry.materials[{index}]",
                       f"is {value}; it must index the {n_materials} entries of 'materials', i.e. lie in "
                       f"[0, {n_materials - 1}]")


def _check_lights(check, lights):
    if not (isinstance(lights, list) and lights):
        check.fail("lights", f"is {lights!r}; it must be a non-empty list of {{kind, position or direction, intensity}}")
    for index, light in enumerate(lights):
        field = f"lights[{index}]"
        check.mapping(light, field, "{kind, position or direction, intensity}")
        kind = check.require(light, "kind", field, "a light kind ('point' or 'directional')")
        if kind not in ("point", "directional"):
            check.fail(f"{field}.kind", f"is {kind!r}; it must be 'point' or 'directional'")
        check.number(check.require(light, "intensity", field, "an intensity > 0 for every light"),
                     f"{field}.intensity", low=0.0, low_open=True,
                     allowed="a number > 0 (point: radiant intensity; directional: irradiance)")
        if kind == "point":
            check.vector3(check.require(light, "position", field, "a position [x, y, z] for a point light"),
                          f"{field}.position")
        else:
            direction = check.vector3(check.require(light, "direction", field,
                                                    "a direction [x, y, z] (towards the light) for a directional light"),
                                      f"{field}.direction")
            if math.hypot(*direction) == 0.0:
                check.fail(f"{field}.direction", "is [0, 0, 0]; it must point towards the light")


def check_stack_description(meta, source) -> dict:
    """Check a mesh stack's ``stack.json`` (:mod:`rjfit.render.mesh_stack`) by the rules it
    shares with a scene: format, resolution, camera, lights, reference intensity and the
    optional saturation and dark levels and noise variance; return it unchanged.

    Raises
    ------
    SceneError
        (a ``DatasetError``) naming ``source``, the entry and its allowed values.
    """

    check = _Checker(source, hint="see docs/dataset-format.md, 'Measured mesh stacks'", noun="a mesh stack")
    check.mapping(meta, "the description", "{format, images, mesh, camera, resolution, lights, ...}")
    for key, what in (("format", f"its format {MESH_STACK_FORMAT!r}"), ("images", "a list of image files"),
                      ("mesh", "a mesh file"), ("camera", "a camera {kind, origin, target, up, fov or half_width}"),
                      ("resolution", "a resolution [height, width]"), ("lights", "a list of lights")):
        check.require(meta, key, "", what)
    if meta["format"] != MESH_STACK_FORMAT:
        check.fail("format", f"is {meta['format']!r}; it must be {MESH_STACK_FORMAT!r}")
    check.texts(meta["images"], "images", "image file names relative to the folder, one per light",
                "an image file name relative to the folder")
    check.text(meta["mesh"], "mesh", "the mesh's file name relative to the folder")
    _check_view(check, meta)
    if meta.get("saturation") is not None:
        check.number(meta["saturation"], "saturation", low=0.0, low_open=True,
                     allowed="a raw value > 0 at which a pixel clips, or null")
    _check_noise_and_dark(check, meta)
    return meta


def check_dataset_description(meta, source) -> dict:
    """Check an rjfit-layout ``dataset.json`` (:mod:`rjfit.data.dataset`, documented in
    ``docs/dataset-format.md``) for every entry the loader, the cross-check and the diagnosis
    read from it; return it unchanged.

    Required: ``format``, ``resolution``, ``lights`` (as in a scene), ``images`` (one file name
    per light) and ``geometry`` (a file name). Optional: ``visibility`` and ``truth_labels``
    (file names, or null), ``camera`` (as in a scene; required with ``meshes``),
    ``reference_intensity`` > 0 (required with ``meshes``: the scene is rebuilt from it),
    ``materials`` (``{I0 > 0, kd in [0, 1], gamma > 0}`` per material, plus ``sigma2 >= 0`` when
    ``truth_labels`` is set, which then requires them), ``meshes`` (``{file, material}`` per
    part, the material an index into ``materials``), ``max_depth`` (integer >= 2) and
    ``saturation`` (> 0, or null), ``dark`` (>= 0, or null), ``noise_variance`` (>= 0, or null).
    Other entries (name, units, versions, ...) are free.

    Parameters
    ----------
    meta : object
        The parsed ``dataset.json``.
    source : str or Path
        What to name in messages: the ``dataset.json`` path.

    Returns
    -------
    dict
        ``meta``, unchanged.

    Raises
    ------
    SceneError
        (a ``DatasetError`` / ``ValueError``) naming ``source``, the entry and its allowed values.
    """

    check = _Checker(source, hint="see docs/dataset-format.md for the dataset.json keys", noun="a data set")
    if not isinstance(meta, dict):
        raise SceneError(f"{source}: a data set description is a JSON object {{format, resolution, lights, images, "
                         f"geometry, ...}}, got {type(meta).__name__}; see docs/dataset-format.md")
    for key, what in (("format", f"its format {DATASET_FORMAT!r}"), ("resolution", "a resolution [height, width]"),
                      ("lights", "a list of lights {kind, position or direction, intensity}"),
                      ("images", "a list of image files, one per light"),
                      ("geometry", "its geometry file (geometry.exr)")):
        check.require(meta, key, "", what)
    if meta["format"] != DATASET_FORMAT:
        check.fail("format", f"is {meta['format']!r}; it must be {DATASET_FORMAT!r}")
    meshes = meta.get("meshes")
    if meshes:
        for key, what in (("camera", "a camera {kind, origin, target, up, fov or half_width} when it has meshes"),
                          ("reference_intensity", "a reference_intensity > 0 when it has meshes")):
            check.require(meta, key, "", what)
    _check_view(check, meta, camera="camera" in meta)
    images = check.texts(meta["images"], "images", "image file names relative to the folder, one per light",
                         "an image file name relative to the folder")
    if len(images) != len(meta["lights"]):
        check.fail("images", f"lists {len(images)} files but 'lights' has {len(meta['lights'])}; every light needs "
                             f"exactly one image, in light order")
    check.text(meta["geometry"], "geometry", "the geometry file's name relative to the folder")
    for key in ("visibility", "truth_labels"):
        if meta.get(key) is not None:
            check.text(meta[key], key, "a file name relative to the folder (or null)")
    truth = meta.get("truth_labels") is not None
    if truth:
        check.require(meta, "materials", "", "its materials {I0, kd, gamma, sigma2} when it has truth_labels")
    n_materials = None
    if meta.get("materials") is not None:
        n_materials = _check_dataset_materials(check, meta["materials"], with_sigma2=truth)
    if meshes is not None:
        _check_meshes(check, meshes, n_materials)
    if meta.get("max_depth") is not None:
        check.integer(meta["max_depth"], "max_depth", low=2,
                      allowed="an integer >= 2 (path length; 2 = direct light only)")
    if meta.get("saturation") is not None:
        check.number(meta["saturation"], "saturation", low=0.0, low_open=True,
                     allowed="a value > 0 at which a pixel clips, or null")
    _check_noise_and_dark(check, meta)
    return meta


def _check_noise_and_dark(check, meta):
    if meta.get("noise_variance") is not None:      # how far below 0 its images may dip (rjfit.data.checks)
        check.number(meta["noise_variance"], "noise_variance", low=0.0,
                     allowed="a number >= 0 (the variance of the Gaussian noise in the images), or null")
    if meta.get("dark") is not None:
        check.number(meta["dark"], "dark", low=0.0,
                     allowed="a value >= 0 at or below which an observation (every channel) is too dark, or null")


def _check_dataset_materials(check, materials, *, with_sigma2):
    keys = ("I0", "kd", "gamma") + (("sigma2",) if with_sigma2 else ())
    listed = "{" + ", ".join(keys) + "}"
    if not (isinstance(materials, list) and materials):
        check.fail("materials", f"is {materials!r}; it must be a non-empty list of {listed}")
    rules = {"I0": dict(low=0.0, low_open=True, allowed="a number > 0 (the region's intensity)"),
             "kd": dict(low=0.0, high=1.0, allowed="a number in [0, 1] (the diffuse fraction; ks = 1 - kd)"),
             "gamma": dict(low=0.0, low_open=True, allowed="a number > 0 (the Blinn-Phong exponent)"),
             "sigma2": dict(low=0.0, allowed="a number >= 0 (the noise variance)")}
    for index, material in enumerate(materials):
        field = f"materials[{index}]"
        check.mapping(material, field, listed)
        for key in keys:
            check.number(check.require(material, key, field, f"{key} for every material"), f"{field}.{key}",
                         **rules[key])
    return len(materials)


def _check_meshes(check, meshes, n_materials):
    if not isinstance(meshes, list):
        check.fail("meshes", f"is {meshes!r}; it must be a list of {{file, material}}, one per mesh part")
    for index, part in enumerate(meshes):
        field = f"meshes[{index}]"
        check.mapping(part, field, "{file, material}")
        check.text(check.require(part, "file", field, "a mesh file for every part"), f"{field}.file",
                   "the PLY file's name relative to the folder")
        material = check.require(part, "material", field, "a material index for every part")
        if n_materials is None:
            check.integer(material, f"{field}.material", low=0, allowed="a material index, 0 without 'materials'")
            if material != 0:
                check.fail(f"{field}.material", f"is {material!r}; without 'materials' every part must use "
                                                f"material 0 (the cross-check's probe material)")
            continue
        check.integer(material, f"{field}.material", low=0, allowed=f"a material index in [0, {n_materials - 1}]")
        if material >= n_materials:
            check.fail(f"{field}.material", f"is {material}; it must index the {n_materials} entries of "
                                            f"'materials', i.e. lie in [0, {n_materials - 1}]")
