"""Data sets on disk: the rjfit layout (rendered or measured) and its loader.

Layout (``dataset.json`` documents itself; see ``docs/dataset-format.md``)::

    DATASET/dataset.json             description: camera, lights, meshes, units, seed, versions
    DATASET/images/light_NNN.exr     one linear float32 RGB image per light
    DATASET/geometry.exr             P.X P.Y P.Z  N.X N.Y N.Z  V.X V.Y V.Z  mask (pixel centres)
    DATASET/visibility.exr           one channel per light: 1 where a shadow ray reaches it
    DATASET/truth_labels.exr         synthetic only: material index per pixel, -1 off the object
    DATASET/meshes/part_NNN.ply      the scene's meshes, one per material part
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rjfit.data.checks import (check_finite, check_lights_face_object, check_mask, check_radiance,
                               check_unit_normals, radiance_floor)
from rjfit.data.descriptions import check_dataset_description
from rjfit.data.exr import read_exr
from rjfit.data.formats import CHANNELS, COLOUR, COLOUR_CHANNELS
from rjfit.data.lights import Light, cos_light_half, geometry_terms, light_tangent_terms
from rjfit.data.observations import EXCLUSION_RULES, Observations, exclusion_reasons, stack_channels
from rjfit.errors import DatasetError, DatasetFileNotFoundError
from rjfit.io import read_json

__all__ = ["Dataset", "load_rjfit_layout", "read_validation_result", "dark_flags"]



def dark_flags(images, dark):
    """(L, H, W) flags of the observations whose every channel is at or below ``dark`` (None: no threshold).

    ``images`` are the stack's raw values, (L, H, W, 3) or a list of (H, W, 3); every channel
    must be dark, so a channel that saw light keeps the observation.
    """
    if dark is None:
        return None
    return np.stack([(np.asarray(image) <= dark).all(axis=-1) for image in images])


@dataclass(frozen=True)
class Dataset:
    """An image stack with its geometry, lights and (for synthetic data) ground truth.

    Built by :func:`load_dataset` (which checks the files) or by the synthetic and
    photometric-stereo loaders; the constructor stores its arguments as they are, without
    checks. Each parameter is kept as the attribute of the same name.

    Parameters
    ----------
    path : Path
    meta : dict
        The contents of ``dataset.json``.
    images : ndarray, shape (L, H, W, C)
        Linear radiance per light; C = 3 (R, G, B); float32 as stored (observations are float64).
    normals, view_dirs : ndarray, shape (H, W, 3)
    positions : ndarray, shape (H, W, 3) or None
        Needed for point lights (distance); None for directional-light data.
    visibility : ndarray of bool, shape (L, H, W) or None
    object_mask : ndarray of bool, shape (H, W)
    lights : list of Light
    truth_labels : ndarray of int, shape (H, W) or None
        Material index per pixel, -1 off the object.
    truth_params : list of dict or None
        ``{I0, kd, gamma, sigma2}`` per material index.
    saturation : float or None
        Values at or above it are clipped measurements and never enter the likelihood.
    saturated : ndarray of bool, shape (L, H, W) or None
        Observations known to be clipped (any channel), never entering the likelihood; used
        where one threshold on the stored images does not apply (measured images divided by
        per-channel light intensities).
    too_dark : ndarray of bool, shape (L, H, W) or None
        Observations at or below the data set's declared dark threshold in every channel (a
        cast shadow, the background, the sensor's floor: no measurement of the surface's
        reflectance), never entering the likelihood. Set by the loaders from ``dark`` in
        ``dataset.json``, ``stack.json`` or a photometric-stereo folder's ``rjfit.json``.
    max_view_angle : float or None
        Degrees: observations of pixels seen further than this from their normal are left out
        (rule ``grazing_view``); None keeps every view. ``rjfit fit --preset measured`` sets it
        (:data:`rjfit.data.observations.RIM_COS`: docs/results/measured-data.md).
    response : {"linear", "sRGB", "unknown"}
        How the stored values relate to radiance: ``linear`` (rendered data, linear counts),
        ``sRGB`` (decoded by the loader: the images are linear) or ``unknown`` (raw camera codes,
        not decoded: a later stage estimates the response, e.g.
        :func:`rjfit.data.response.estimate_power_response`).
    quantisation_variance : ndarray of float, shape (L, 3) or None
        The variance of integer quantisation per light and colour channel, in the units of
        ``images`` (one code step squared over 12, divided by the light's intensity squared):
        a known noise floor; None for float or sRGB-decoded images. For ``response="unknown"``
        it is in raw-code units (before any response is applied).
    """

    path: Path
    meta: dict
    images: np.ndarray
    normals: np.ndarray
    view_dirs: np.ndarray
    positions: np.ndarray | None
    visibility: np.ndarray | None
    object_mask: np.ndarray
    lights: list
    truth_labels: np.ndarray | None = None
    truth_params: list | None = None
    saturation: float | None = None
    saturated: np.ndarray | None = None
    too_dark: np.ndarray | None = None
    max_view_angle: float | None = None
    response: str = "linear"
    quantisation_variance: np.ndarray | None = None

    @property
    def n_lights(self) -> int:
        """The number of lights (images) L."""
        return len(self.lights)

    @property
    def image_shape(self) -> tuple[int, int]:
        """``(height, width)`` of the images."""
        return tuple(self.object_mask.shape)

    @property
    def reference_intensity(self) -> float:
        """The light intensity the fitted ``I0`` is relative to (``dataset.json``'s
        ``reference_intensity``, 1.0 when absent)."""
        return float(self.meta.get("reference_intensity", 1.0))

    def channel_values(self, channel: str = "mean") -> np.ndarray:
        """The (L, H, W) stack of one colour channel, the channel mean or the luminance.

        ``luminance`` is CIE Y of linear RGB with the sRGB / ITU-R BT.709 primaries
        (colour-science's ``RGB_luminance``).

        Parameters
        ----------
        channel : {"mean", "R", "G", "B", "luminance"}
            Which value per pixel: the mean of R, G and B, one of them, or the luminance
            (see :data:`CHANNELS`).

        Returns
        -------
        numpy.ndarray, shape (L, H, W)
            The values, for every pixel (not only the object's).

        Raises
        ------
        ValueError
            If ``channel`` is not one of :data:`CHANNELS`.
        """
        if channel not in CHANNELS:
            raise ValueError(f"channel must be one of {CHANNELS}, got {channel!r}")
        return self._channel_of(self.images, channel)

    def geometry(self):
        """Per light ``<l.n>``, ``<h.n>`` and relative irradiance, each (L, H, W)."""
        positions = self.positions if self.positions is not None else np.zeros_like(self.normals)
        terms = [geometry_terms(positions, self.normals, self.view_dirs, light, self.reference_intensity)
                 for light in self.lights]
        return tuple(np.stack(stack) for stack in zip(*terms))

    def _channel_of(self, image: np.ndarray, channel: str) -> np.ndarray:
        """One light's values (..., 3) -> (...) for ``channel`` (see :meth:`channel_values`)."""
        if channel == "mean":
            return image.mean(axis=-1)
        if channel == "luminance":
            import colour

            space = colour.RGB_COLOURSPACES["sRGB"]
            return colour.RGB_luminance(image, space.primaries, space.whitepoint)
        return image[..., "RGB".index(channel)]

    def view_angles(self) -> np.ndarray:
        """(H, W) degrees between each object pixel's normal and its view direction; NaN off the object."""
        cos_view = np.clip(np.sum(self.normals * self.view_dirs, axis=-1), -1.0, 1.0)
        return np.where(self.object_mask, np.degrees(np.arccos(cos_view)), np.nan)

    def rim_pixels(self) -> np.ndarray:
        """(H, W) bool: object pixels seen further than ``max_view_angle`` from their normal (none if it is None)."""
        if self.max_view_angle is None:
            return np.zeros(self.image_shape, dtype=bool)
        cos_view = np.sum(self.normals * self.view_dirs, axis=-1)
        return self.object_mask & (cos_view < np.cos(np.radians(self.max_view_angle)))

    def _object_pixel_lights(self, channel: str, dark: float | None):
        """Per light, on object pixels only: (light index, valid, y, cos_ln, cos_hn, irradiance, reasons).

        ``reasons`` are :func:`rjfit.data.observations.exclusion_reasons` with the data set's own
        flags (clipped in any channel, too dark) added; ``valid`` is that no reason applies.

        Streams one light at a time and never forms full-frame (L, H, W) geometry, so memory
        grows with the object's pixels, not with the frame.
        """
        if channel not in CHANNELS:
            raise ValueError(f"channel must be one of {CHANNELS}, got {channel!r}")
        rows, cols = np.nonzero(self.object_mask)
        normals, view_dirs = self.normals[rows, cols], self.view_dirs[rows, cols]
        positions = self.positions[rows, cols] if self.positions is not None else np.zeros_like(normals)
        grazing = self.rim_pixels()[rows, cols] if self.max_view_angle is not None else None
        for index, light in enumerate(self.lights):
            cos_ln, cos_hn, irradiance = geometry_terms(positions, normals, view_dirs, light, self.reference_intensity)
            pixels = self.images[index][rows, cols]
            y = self._channel_of(pixels, channel)
            visible = self.visibility[index][rows, cols] if self.visibility is not None else None
            reasons = exclusion_reasons(y, cos_ln, visible, dark=dark, grazing=grazing)
            if self.saturation is not None:
                # A pixel is saturated when any of its channels is clipped.
                reasons["saturated"] |= (pixels >= self.saturation).any(axis=-1)
            if self.saturated is not None:
                reasons["saturated"] |= self.saturated[index][rows, cols]
            if self.too_dark is not None:
                reasons["too_dark"] |= self.too_dark[index][rows, cols]
            valid = ~np.logical_or.reduce(list(reasons.values()))
            yield index, valid, y, cos_ln, cos_hn, irradiance, reasons

    def exclusion_counts(self, channel: str = "mean") -> dict:
        """Per object pixel, how many lights' observations each stated rule leaves out, and how many are valid.

        Each left-out observation counts under the first rule that applies, in the order of the
        returned dict, so on the object ``valid + unlit + grazing_view + shadowed + saturated +
        too_dark + not_finite`` is the number of lights.

        Returns
        -------
        dict of str -> ndarray of int, shape (H, W)
            ``valid`` (the paper's valid images per pixel, Fig. 8); ``unlit`` (the light is
            behind the surface or grazes it: ``<l.n> <=``
            :data:`rjfit.data.observations.MIN_COS`); ``grazing_view`` (the pixel is seen more
            than ``max_view_angle`` from its normal); ``shadowed`` (a shadow ray is blocked);
            ``saturated`` (clipped in some channel); ``too_dark`` (at or below the declared dark
            threshold in every channel); ``not_finite`` (the channel's value is NaN or Inf).
            Zero off the object.
        """
        counts = {name: np.zeros(self.image_shape, dtype=np.int64) for name in ("valid", *EXCLUSION_RULES)}
        rows, cols = np.nonzero(self.object_mask)
        for _, valid, *_, reasons in self._object_pixel_lights(channel, None):
            counts["valid"][rows, cols] += valid
            left = ~valid
            for name, flags in reasons.items():     # the first rule that applies takes the observation
                counts[name][rows, cols] += left & flags
                left &= ~flags
        return counts

    def valid_mask(self, channel: str = "mean", dark: float | None = None) -> np.ndarray:
        """Valid observations (L, H, W): on the object, lit, not shadowed, not saturated, not too dark.

        Parameters
        ----------
        channel : str
            The channel whose values must be finite (and above ``dark``); see
            :meth:`channel_values`. Saturation is checked on every channel.
        dark : float, optional
            Values at or below it are left out.

        Returns
        -------
        ndarray of bool, shape (L, H, W)

        Raises
        ------
        ValueError
            If ``channel`` is not one of :data:`CHANNELS`.
        """
        valid = np.zeros((self.n_lights,) + self.image_shape, dtype=bool)
        rows, cols = np.nonzero(self.object_mask)
        for index, valid_on_object, *_ in self._object_pixel_lights(channel, dark):
            valid[index, rows, cols] = valid_on_object
        return valid

    def observations(self, channel: str = "mean", dark: float | None = None, tangents: bool = False) -> Observations:
        """The valid observations of one channel (see :meth:`valid_mask`), or of R, G and B jointly.

        Parameters
        ----------
        channel, dark
            As in :meth:`valid_mask`; ``channel="rgb"`` (:data:`~rjfit.data.formats.COLOUR`):
            each of R, G and B's valid observations, stacked with their channel index
            (:func:`~rjfit.data.observations.stack_channels`), for a joint colour fit.
        tangents : bool
            Also build :attr:`Observations.tangent <rjfit.data.observations.Observations>` (the
            light's and half vector's tangent-frame components, for ``--normals sample``).

        Returns
        -------
        Observations

        Raises
        ------
        ValueError
            If ``channel`` is not one of :data:`CHANNELS`.
        DatasetError
            If no observation is valid.
        """
        if channel == COLOUR:
            return stack_channels([self.observations(name, dark, tangents) for name in COLOUR_CHANNELS])
        rows, cols = np.nonzero(self.object_mask)
        flat_pixel = rows.astype(np.int64) * self.image_shape[1] + cols
        parts = {"pixel": [], "light": [], "y": [], "cos_ln": [], "cos_hn": [], "irradiance": [], "cos_lh": []}
        view_dirs = self.view_dirs[rows, cols]
        positions = self.positions[rows, cols] if self.positions is not None else np.zeros_like(view_dirs)
        if tangents:
            parts["tangent"] = []
            normals = self.normals[rows, cols]
        for index, valid, y, cos_ln, cos_hn, irradiance, _ in self._object_pixel_lights(channel, dark):
            parts["cos_lh"].append(cos_light_half(positions, view_dirs, self.lights[index])[valid])
            if tangents:
                parts["tangent"].append(light_tangent_terms(positions[valid], normals[valid], view_dirs[valid],
                                                            self.lights[index]))
            parts["pixel"].append(flat_pixel[valid])
            parts["light"].append(np.full(int(valid.sum()), index, dtype=np.int32))
            for name, values in (("y", y), ("cos_ln", cos_ln), ("cos_hn", cos_hn), ("irradiance", irradiance)):
                parts[name].append(np.asarray(values, dtype=np.float64)[valid])
        gathered = {name: np.concatenate(chunks) for name, chunks in parts.items()}
        _require(gathered["y"].size > 0, f"{self.path}: no valid observation (check the object mask, the lights and "
                                         f"the saturation level)")
        return Observations(image_shape=self.image_shape, n_lights=self.n_lights, object_mask=self.object_mask,
                            **gathered)


def _require(condition, message):
    if not condition:
        raise DatasetError(message)


#: The measures of a validation result that messages quote; a missing or null one reads as NaN.
_VALIDATION_MEASURES = ("median_rel_err", "p99_rel_err", "unexplained_fraction")


def read_validation_result(path) -> dict:
    """The cross-check result in ``path`` (a ``validation.json`` that ``rjfit validate`` wrote),
    checked: a JSON object with ``passed`` (true or false) and ``dataset_sha256`` (a string).

    The measures ``median_rel_err``, ``p99_rel_err`` and ``unexplained_fraction`` come back as
    floats, NaN where the file has none or ``null`` (``write_json_atomic`` writes NaN as
    ``null``), so messages can always format them.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    DatasetError
        If it is not JSON, or not a validation result (e.g. a fit's ``summary.json``); the
        message names the file and says which file to pass instead.
    """
    path = Path(path)
    result = read_json(path)
    fix = ("pass the validation.json that `rjfit validate DATASET --out DIR` wrote (DIR/validation.json), or "
           "run `rjfit validate` again")
    if not isinstance(result, dict):
        raise DatasetError(f"{path}: not a validation result written by `rjfit validate` (a JSON "
                           f"{type(result).__name__}, not an object); {fix}")
    problems = []
    if not isinstance(result.get("passed"), bool):
        problems.append(f"'passed' is {result['passed']!r}, not true or false" if "passed" in result
                        else "no 'passed' entry")
    if not isinstance(result.get("dataset_sha256"), str):
        problems.append(f"'dataset_sha256' is {result['dataset_sha256']!r}, not a string"
                        if "dataset_sha256" in result else "no 'dataset_sha256' entry")
    if problems:
        raise DatasetError(f"{path}: not a validation result written by `rjfit validate` ({'; '.join(problems)}); "
                           f"{fix}")
    measures = {}
    for key in _VALIDATION_MEASURES:
        value = result.get(key)
        measures[key] = float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else np.nan
    return {**result, **measures}


def _read_channels(path, names, shape, role, description_path):
    """The channels ``names`` of the EXR file ``path`` that a data set needs, each (H, W) = ``shape``.

    One check for every EXR file of the rjfit layout: the file exists, has the channels and
    each has the images' size; ``role`` says what the file is, for messages.

    Raises
    ------
    DatasetFileNotFoundError
        If the file is missing.
    DatasetError
        If a channel is missing or has another size.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetFileNotFoundError(f"{path}: no such file; {description_path} names it as {role}")
    channels = read_exr(path)
    missing = [name for name in names if name not in channels]
    _require(not missing, f"{path}: needs channel{'s' if len(names) > 1 else ''} {' '.join(names)} ({role}); missing "
                          f"{' '.join(missing)} (the file has {' '.join(sorted(channels)) or 'no channel'})")
    height, width = shape
    for name in names:
        size = channels[name].shape
        _require(size == (height, width),
                 f"{path}: channel {name} is {size[1]} x {size[0]} (width x height), but {description_path} says "
                 f"the images are {width} x {height} (resolution); every file of a data set must have one size")
    return [channels[name] for name in names]


def load_rjfit_layout(path) -> Dataset:
    """Load a data set in the rjfit layout (see the module docstring): ``dataset.json`` and the files it names.

    Parameters
    ----------
    path : path-like
        The data set folder.

    Returns
    -------
    Dataset

    Raises
    ------
    DatasetFileNotFoundError
        (a ``DatasetError`` and a ``FileNotFoundError``) if ``dataset.json`` or a file it names is missing.
    DatasetError
        (a ``ValueError``) if ``dataset.json`` is not valid JSON or misses or mistypes an entry
        (see :func:`rjfit.data.descriptions.check_dataset_description`), a file holds NaN/Inf,
        lacks a channel, sizes disagree, a truth label indexes no material, or the geometry is
        unusable (empty mask, normals not unit length, every light behind the object).
    """
    path = Path(path)
    description_path = path / "dataset.json"
    if not description_path.is_file():
        raise DatasetFileNotFoundError(f"{description_path}: no such file; a data set in the rjfit layout is described "
                                       f"by it")
    meta = check_dataset_description(read_json(description_path), description_path)
    lights = [Light.from_json(entry) for entry in meta["lights"]]
    height, width = (int(n) for n in meta["resolution"])
    shape = (height, width)
    for index, part in enumerate(meta.get("meshes") or []):
        mesh_file = path / part["file"]
        if not mesh_file.is_file():
            raise DatasetFileNotFoundError(f"{mesh_file}: no such file; {description_path} names it as "
                                           f"meshes[{index}].file")
    images = []
    for index, name in enumerate(meta["images"]):
        image = np.stack(_read_channels(path / name, "RGB", shape, f"the image of light {index} (images[{index}])",
                                        description_path), axis=-1)
        check_radiance(image, path / name, radiance_floor(meta.get("noise_variance")))
        images.append(image)
    geometry_file = path / meta["geometry"]
    geometry_names = [f"{prefix}.{axis}" for prefix in "PNV" for axis in "XYZ"] + ["mask"]
    geometry = dict(zip(geometry_names, _read_channels(geometry_file, geometry_names, shape, "the geometry",
                                                       description_path)))
    stack3 = lambda prefix: np.stack([geometry[f"{prefix}.{axis}"] for axis in "XYZ"], axis=-1).astype(np.float64)
    object_mask = geometry["mask"] > 0.5
    visibility = None
    if meta.get("visibility"):
        visibility_file = path / meta["visibility"]
        visibility = np.stack(_read_channels(visibility_file, [f"light_{i:03d}" for i in range(len(lights))], shape,
                                             "the shadow-ray visibility (one channel per light)",
                                             description_path)) > 0.5
    truth_labels, truth_params = _read_truth(path, meta, shape, description_path)
    dataset = Dataset(path=path, meta=meta, images=np.stack(images), normals=stack3("N"),
                      view_dirs=stack3("V"), positions=stack3("P"), visibility=visibility, object_mask=object_mask,
                      lights=lights, truth_labels=truth_labels, truth_params=truth_params,
                      saturation=meta.get("saturation"), too_dark=dark_flags(images, meta.get("dark")))
    check_mask(object_mask, f"{geometry_file} (channel mask)")
    check_unit_normals(dataset.normals, object_mask, f"{geometry_file} (channels N.X N.Y N.Z)")
    check_lights_face_object(lights, dataset.normals, dataset.positions, dataset.view_dirs, object_mask,
                             lambda i: str(description_path) if i is None else f"{description_path} lights[{i}] "
                             f"({lights[i].kind}, {lights[i].position or lights[i].direction})")
    return dataset


def _read_truth(path, meta, shape, description_path):
    """``(truth labels, truth parameters per material)`` named by ``meta``; ``(None, None)`` without them."""
    if not meta.get("truth_labels"):
        return None, None
    labels_file = path / meta["truth_labels"]
    (labels,) = _read_channels(labels_file, ["label"], shape, "the truth labels", description_path)
    check_finite(labels, labels_file, "labels")
    truth_labels = np.rint(labels).astype(np.int32)
    n_materials = len(meta["materials"])
    outside = (truth_labels < -1) | (truth_labels >= n_materials)
    if outside.any():
        rows, cols = np.nonzero(outside)
        raise DatasetError(f"{labels_file}: {int(outside.sum())} labels are outside [-1, {n_materials - 1}] "
                           f"(first {truth_labels[rows[0], cols[0]]} at row {rows[0]}, column {cols[0]}); a label "
                           f"is -1 off the object or an index into the {n_materials} entries of 'materials' in "
                           f"{description_path}")
    truth_params = [{key: float(material[key]) for key in ("I0", "kd", "gamma", "sigma2")}
                    for material in meta["materials"]]
    return truth_labels, truth_params
