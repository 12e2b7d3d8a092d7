"""Pure-numpy synthetic image stacks for sampler tests (no Mitsuba).

An analytic unit sphere seen by an orthographic camera looking along -z, lit by point
lights placed asymmetrically in front of it, its surface split into four quadrant regions
with the paper's Table 2 truth (Lenoch et al. 2016). The closed form of eq. 2
(:func:`rjfit.model.blinn.radiance`) makes the images, so a fit of these stacks tests the
sampler alone; the Mitsuba-rendered ``paper_sphere`` data set tests the whole chain.

Region numbering follows the sampler's: region = iu * 2 + iv with iu = 1 right of the
vertical boundary and iv = 1 below the horizontal one, so 0 = upper left, 1 = lower left,
2 = upper right, 3 = lower right (the order of the paper's Table 2).
"""
from __future__ import annotations

import numpy as np

from rjfit.data.lights import tangent_frame, tangent_terms
from rjfit.data.observations import Observations, observations_from_stack
from rjfit.model.blinn import radiance

__all__ = ["PAPER_TABLE2_TRUTH", "default_light_positions", "sphere_stack"]

#: The paper's Table 2 truth, in the sampler's region order (UL, LL, UR, LR).
PAPER_TABLE2_TRUTH = (
    {"I0": 100.0, "kd": 0.5, "gamma": 5.0, "sigma2": 0.1},
    {"I0": 100.0, "kd": 0.9, "gamma": 10.0, "sigma2": 0.1},
    {"I0": 100.0, "kd": 0.6, "gamma": 5.0, "sigma2": 0.1},
    {"I0": 100.0, "kd": 0.4, "gamma": 1.0, "sigma2": 0.1},
)


def default_light_positions(n_lights: int = 10, *, distance: float = 2.2, seed: int = 1) -> np.ndarray:
    """``n_lights`` point-light positions in front of the unit sphere, placed asymmetrically.

    Directions are drawn (seeded) in the cone of polar angle 10-60 degrees around the
    camera axis +z, with azimuths jittered off a regular spacing so that no two lights are
    mirror images (the paper stresses asymmetric placement: symmetric lights make regions
    indistinguishable). Distance ``distance`` from the centre keeps the irradiance 1/r^2
    of order one.

    Parameters
    ----------
    n_lights : int
        How many lights.
    distance : float
        Distance of every light from the sphere's centre.
    seed : int
        Seed of the directions (``np.random.default_rng``).

    Returns
    -------
    ndarray, shape (n_lights, 3)
        The positions.

    Raises
    ------
    ValueError
        If ``n_lights < 1``.
    """
    if n_lights < 1:
        raise ValueError(f"n_lights must be at least 1, got {n_lights}")
    rng = np.random.default_rng(seed)
    azimuth = np.linspace(0.0, 2.0 * np.pi, n_lights, endpoint=False) + rng.uniform(0.0, 0.5, n_lights)
    polar = np.deg2rad(rng.uniform(10.0, 60.0, n_lights))
    directions = np.stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)], axis=1)
    return distance * directions


def _point_light_terms(position, normals, view):
    """``<l.n>``, ``<h.n>``, the irradiance 1 / d^2 and ``<l.h>`` of a unit point light at ``position``
    over the unit sphere (surface points = normals), seen from direction ``view``."""
    to_light = position[None, None, :] - normals
    dist2 = np.sum(to_light**2, axis=-1)
    light_dir = to_light / np.sqrt(dist2)[..., None]
    half = light_dir + view
    half /= np.linalg.norm(half, axis=-1, keepdims=True)
    return (np.sum(light_dir * normals, axis=-1), np.sum(half * normals, axis=-1), 1.0 / dist2,
            np.sum(light_dir * half, axis=-1))


def _sphere_tangents(lights, normals, view):
    """(L, H, W, 4) tangent-frame components of every light over the unit sphere (surface points = normals)."""
    frame = tangent_frame(normals)
    out = []
    for position in lights:
        to_light = position[None, None, :] - normals
        out.append(tangent_terms(to_light / np.linalg.norm(to_light, axis=-1, keepdims=True), view, *frame))
    return np.stack(out)


def sphere_stack(size: int | tuple[int, int] = 64, *, n_lights: int = 10, light_positions=None,
                 truth=PAPER_TABLE2_TRUTH, seed: int = 0, extent: float = 1.1,
                 min_cos: float = 1e-3, tangents: bool = False):
    """Render a noisy synthetic stack of the four-region sphere with the closed form.

    Parameters
    ----------
    size : int or (int, int)
        Image ``(height, width)``; an int gives a square image.
    n_lights : int
        Number of point lights when ``light_positions`` is not given.
    light_positions : array_like, shape (L, 3), optional
        Light positions (unit relative intensity each).
    truth : sequence of 4 dicts
        Per region ``I0, kd, gamma, sigma2`` in region order UL, LL, UR, LR.
    seed : int
        Seed of the Gaussian noise (``np.random.default_rng``).
    extent : float
        Half-width of the orthographic view in sphere radii.
    min_cos : float
        Observations with ``<l.n> <= min_cos`` are left out.
    tangents : bool
        Also record :attr:`Observations.tangent` (for a fit that samples the normals).

    Returns
    -------
    observations : Observations
    truth_labels : ndarray of int, shape (H, W)
        Region per pixel, -1 off the object.
    truth_params : list of dict
        ``truth`` as a list of plain dicts.

    Raises
    ------
    ValueError
        If the image is smaller than 2 x 2, ``truth`` does not have 4 entries,
        ``light_positions`` is not of shape (L, 3), ``n_lights < 1`` (when
        ``light_positions`` is not given), or no observation is valid (every light behind
        the sphere; from :func:`rjfit.data.observations.observations_from_stack`).
    """
    height, width = (size, size) if np.isscalar(size) else tuple(int(s) for s in size)
    if height < 2 or width < 2:
        raise ValueError(f"image size must be at least 2 x 2, got {height} x {width}")
    if len(truth) != 4:
        raise ValueError(f"truth must give 4 regions (UL, LL, UR, LR), got {len(truth)}")
    lights = default_light_positions(n_lights) if light_positions is None else np.asarray(light_positions, float)
    if lights.ndim != 2 or lights.shape[1] != 3:
        raise ValueError(f"light_positions must have shape (L, 3), got {lights.shape}")
    rng = np.random.default_rng(seed)

    x = -extent + (np.arange(width) + 0.5) * (2.0 * extent / width)
    y = extent - (np.arange(height) + 0.5) * (2.0 * extent / height)
    xx, yy = np.meshgrid(x, y)
    rho2 = xx**2 + yy**2
    object_mask = rho2 < 1.0
    zz = np.sqrt(np.clip(1.0 - rho2, 0.0, None))
    normals = np.stack([xx, yy, zz], axis=-1)          # unit sphere: n = p
    view = np.array([0.0, 0.0, 1.0])                   # towards the camera

    labels = np.where(xx > 0, 2, 0) + np.where(yy < 0, 1, 0)
    labels = np.where(object_mask, labels, -1)
    params = {key: np.array([region[key] for region in truth], dtype=float) for key in ("I0", "kd", "gamma", "sigma2")}
    region = np.where(object_mask, labels, 0)

    images, cos_ln_all, cos_hn_all, irr_all, cos_lh_all = [], [], [], [], []
    for position in lights:
        cos_ln, cos_hn, irradiance, cos_lh = _point_light_terms(position, normals, view)
        mu = radiance(params["I0"][region], params["kd"][region], params["gamma"][region],
                      cos_ln, cos_hn, irradiance)
        noise = rng.normal(0.0, 1.0, size=mu.shape) * np.sqrt(params["sigma2"][region])
        images.append(mu + noise)
        cos_ln_all.append(cos_ln)
        cos_hn_all.append(cos_hn)
        irr_all.append(irradiance)
        cos_lh_all.append(cos_lh)
    valid = object_mask[None] & (np.stack(cos_ln_all) > min_cos)
    obs: Observations = observations_from_stack(np.stack(images), np.stack(cos_ln_all), np.stack(cos_hn_all),
                                                np.stack(irr_all), valid, object_mask, cos_lh=np.stack(cos_lh_all),
                                                tangent=_sphere_tangents(lights, normals, view) if tangents else None)
    return obs, labels.astype(int), [dict(region) for region in truth]
