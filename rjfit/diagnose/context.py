"""The fixed-segmentation context a criticism refit works on.

A :class:`Context` holds one data set's valid observations (flat arrays, as
:class:`rjfit.data.observations.Observations`), the region index of each observation under a
FIXED segmentation (the fit's MAP labels, or the truth labels in tests), the per-observation
geometry the effects need (``<v.n>``, ``<h.v>``) and a cache of effect features (Mitsuba
visibility, indirect radiance, ...). Criticism never touches the sampler: the segmentation is
held fixed, which is what makes a refit per candidate effect cheap.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from rjfit.data.noise import DEFAULT_FLOOR, describe_noise, noise_scale
from rjfit.data.observations import observations_from_stack

__all__ = ["Context", "build_context", "declared_dark"]


@dataclass
class Context:
    dataset: object                 # rjfit.data.dataset.Dataset
    labels: np.ndarray              # (H, W) region index, -1 off the object / unused
    n_regions: int
    region: np.ndarray              # (N,) region of each observation
    light: np.ndarray               # (N,) light (image) index
    pixel: np.ndarray               # (N,) flat pixel index
    y: np.ndarray
    cos_ln: np.ndarray
    cos_hn: np.ndarray
    irradiance: np.ndarray
    cos_vn: np.ndarray
    cos_hv: np.ndarray
    valid: np.ndarray               # (L, H, W) which observations are in
    channel: str = "mean"
    seed: int = 0                   # the diagnosis' seed: Monte Carlo features (indirect light) draw from it
    likelihood_power: float = 1.0   # zeta of a coarsened fit: refits weigh the log-likelihood by it
    noise_scale: np.ndarray | None = None   # (N,) known noise scales s_i of the fit's noise model (None: all 1)
    noise: dict = field(default_factory=lambda: describe_noise("constant", DEFAULT_FLOOR))
    # the data set's declared dark threshold in its values' units (None: none): every kept
    # observation is above it, so the refits' likelihood is truncated there (RefitObjective)
    dark: float | None = None
    features: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    @property
    def n_obs(self) -> int:
        return int(self.y.size)

    @property
    def n_lights(self) -> int:
        return int(self.valid.shape[0])

    @property
    def image_shape(self):
        return tuple(self.labels.shape)

    @property
    def dataset_dir(self) -> Path:
        return Path(self.dataset.path)

    @property
    def has_mesh(self) -> bool:
        """Whether the data set's scene can be rebuilt in Mitsuba: its meta names mesh files that
        exist (a rendered data set, or a measured mesh stack; see
        :func:`rjfit.render.render.scene_from_dataset_meta`)."""
        meshes = self.dataset.meta.get("meshes")
        return bool(meshes) and self.dataset.positions is not None \
            and all((self.dataset_dir / entry["file"]).is_file() for entry in meshes)

    @property
    def reference_intensity(self) -> float:
        return self.dataset.reference_intensity

    @property
    def white_level(self) -> float:
        """The largest valid value: the white level camera-response effects are relative to."""
        return float(np.max(self.y))

    def dense(self, values, fill=np.nan):
        """Scatter per-observation values into an (L, H, W) stack."""
        out = np.full(self.valid.shape, fill, dtype=float)
        height, width = self.image_shape
        out[self.light, self.pixel // width, self.pixel % width] = values
        return out

    def per_pixel_mean(self, values):
        """Mean over lights of per-observation values, as an (H, W) map (NaN where none)."""
        size = self.labels.size
        total = np.bincount(self.pixel, weights=values, minlength=size)
        count = np.bincount(self.pixel, minlength=size)
        with np.errstate(invalid="ignore", divide="ignore"):
            return (total / count).reshape(self.image_shape)

    def standardise(self, values):
        """Per-observation values (along the first axis) divided by the noise model's known scales
        s_i: residuals in the units in which the noise is homoscedastic (unchanged for 'constant')."""
        if self.noise_scale is None:
            return values
        values = np.asarray(values, dtype=float)
        return values / self.noise_scale.reshape((-1,) + (1,) * (values.ndim - 1))

    def feature(self, key, compute):
        """A cached feature: ``compute()`` runs once per context and key."""
        if key not in self.features:
            self.features[key] = compute()
        return self.features[key]


def _light_directions(dataset):
    """Unit directions towards each light, (L, H, W, 3)."""
    positions = dataset.positions if dataset.positions is not None else np.zeros_like(dataset.normals)
    out = []
    for light in dataset.lights:
        if light.kind == "point":
            to_light = np.asarray(light.position, dtype=float) - positions
        else:
            to_light = np.broadcast_to(np.asarray(light.direction, dtype=float), positions.shape)
        norm = np.linalg.norm(to_light, axis=-1, keepdims=True)
        out.append(to_light / np.where(norm > 0, norm, 1.0))
    return np.stack(out)


def build_context(dataset, labels, *, channel="mean", valid=None, seed=0, likelihood_power=1.0, noise="constant",
                  noise_floor=DEFAULT_FLOOR, normals=None) -> Context:
    """Gather a data set's valid observations under a fixed segmentation.

    Parameters
    ----------
    dataset : Dataset or path
    labels : ndarray (H, W)
        Region index per pixel, negative off the object. Regions are renumbered 0..R-1 in
        order of their label; pixels on the object mask with a negative label are left out.
    valid : ndarray (L, H, W), optional
        Which observations to use (default: ``dataset.valid_mask(channel)``).
    likelihood_power : float in (0, 1]
        The power zeta of a coarsened fit (:mod:`rjfit.data.coarsen`): every refit on the context
        raises the likelihood to it, so its evidence and Bayes factors weigh the data as the
        fit did (1: the plain likelihood).
    noise : {'constant', 'shot', 'relative', 'normals'}
        The fit's noise model (:mod:`rjfit.data.noise`): refits then weigh observation i by its
        known scale s_i, ``y_i ~ N(mu_i, sigma_r^2 s_i^2)``, as the sampler did.
    noise_floor : float
        Its floor (``rjfit fit --noise-floor``).
    normals : ndarray (H, W, 3), optional
        Unit normals the refits use instead of the data set's: a fit's posterior mean normals
        (``rjfit fit --normals sample``). The valid observations and the noise model's scales stay
        those of the data set's normals, as that fit kept and weighed them; ``ctx.dataset`` carries
        these normals.

    Raises
    ------
    ValueError
        If ``labels`` do not have the images' shape, ``likelihood_power`` is not in (0, 1], or
        the noise model is unknown or its floor not positive (:func:`rjfit.data.noise.noise_scale`).
    """
    zeta = float(likelihood_power)
    if not 0.0 < zeta <= 1.0:
        raise ValueError(f"likelihood_power is {likelihood_power!r}; it must be in (0, 1] (1: the plain likelihood)")
    if not hasattr(dataset, "images"):
        from rjfit.render.datasets import load_dataset

        dataset = load_dataset(dataset)
    labels = np.asarray(labels)
    if labels.shape != dataset.image_shape:
        raise ValueError(f"labels are {labels.shape}, the data set's images are {dataset.image_shape}")
    cos_ln, cos_hn, irradiance = dataset.geometry()
    if valid is None:
        valid = dataset.valid_mask(channel)
    valid = np.asarray(valid, dtype=bool) & (labels >= 0)[None] & dataset.object_mask[None]
    used = np.unique(labels[valid.any(axis=0)])
    remap = np.full(int(max(labels.max(), 0)) + 1, -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    region_map = np.where(labels >= 0, remap[np.maximum(labels, 0)], -1)
    obs = observations_from_stack(dataset.channel_values(channel), cos_ln, cos_hn, irradiance, valid,
                                  dataset.object_mask)
    light_dirs = _light_directions(dataset)
    height, width = dataset.image_shape
    rows, cols = obs.pixel // width, obs.pixel % width
    v = dataset.view_dirs[rows, cols]
    n = dataset.normals[rows, cols]
    l = light_dirs[obs.light, rows, cols]
    h = l + v
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    # <l.h> per observation: the normals' error noise model needs it (the fit's observations carry it)
    obs = replace(obs, cos_lh=np.sum(l * h, axis=-1))
    scale = noise_scale(obs, noise, noise_floor)
    if normals is not None:
        dataset, obs, n = _at_normals(dataset, obs, valid, normals)
    dark = declared_dark(dataset)
    described = describe_noise(noise, noise_floor, scale)
    if dark is not None:        # diagnosis.json's record of the likelihood says so
        described["truncated_at_dark"] = dark
    return Context(dataset=dataset, labels=region_map.astype(np.int64), n_regions=int(used.size),
                   region=region_map[rows, cols].astype(np.int64), light=obs.light.astype(np.int64),
                   pixel=obs.pixel, y=obs.y, cos_ln=obs.cos_ln, cos_hn=obs.cos_hn, irradiance=obs.irradiance,
                   cos_vn=np.clip(np.sum(v * n, axis=-1), 1e-6, 1.0), cos_hv=np.clip(np.sum(h * v, axis=-1), 0.0, 1.0),
                   valid=valid, channel=channel, seed=int(seed), likelihood_power=zeta, noise_scale=scale,
                   noise=described, dark=dark)


def _at_normals(dataset, obs, valid, normals):
    """``(dataset, obs, n)`` at the unit ``normals`` (H, W, 3): the data set carrying them, the observations'
    ``<l.n>`` and ``<h.n>`` at them and each observation's normal; the same observations (``valid``)."""
    normals = np.asarray(normals, dtype=float)
    if normals.shape != dataset.normals.shape:
        raise ValueError(f"normals are {normals.shape}, the data set's are {dataset.normals.shape}")
    dataset = replace(dataset, normals=normals)
    cos_ln, cos_hn, _ = dataset.geometry()
    width = dataset.image_shape[1]
    return (dataset, replace(obs, cos_ln=cos_ln[valid], cos_hn=cos_hn[valid]),
            normals[obs.pixel // width, obs.pixel % width])


def declared_dark(dataset) -> float | None:
    """The dark threshold a data set declares in its values' units (``dark`` of ``dataset.json``),
    below which no observation was kept; None where it declares none or one on raw codes (a
    photometric-stereo folder's ``raw_threshold``, before its per-light intensities are divided
    out, so no one value in the data's units)."""
    dark = (getattr(dataset, "meta", None) or {}).get("dark")
    return float(dark) if isinstance(dark, (int, float)) and not isinstance(dark, bool) else None
