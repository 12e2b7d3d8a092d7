"""Ambient or stray light: a constant environment radiance around the object.

    mu += a * I0 * ( kd + (1 - kd) * A_g(theta_v) )

``a`` is the environment's radiance relative to the reference intensity (Mitsuba: a
``constant`` emitter of radiance a x reference_intensity). For a white constant environment
the reflected radiance is the BRDF's directional albedo: kd for the Lambert part, and for the
normalised Blinn lobe ``A_g(theta_v) = int N(g) <h.n>^g <l.n> dl`` over the hemisphere, which
depends on gamma and the view angle (Giesen's normalisation makes it ~1 at normal view). It is
tabulated once by quadrature over the half vector (Gauss-Legendre in u = cos^(g+1) theta_h,
uniform in phi) and interpolated; exact for a convex object, where nothing occludes the sky.

- physics: the lobe's directional albedo :func:`lobe_albedo_quadrature`, its table
  (:func:`albedo_table`, shipped as ``ambient_albedo.npy`` and checked against
  :func:`albedo_table_quadrature` by the tests; :data:`ALBEDO_LOG_GAMMA`, :data:`ALBEDO_COS_V`) and the table's
  bilinear interpolation (:func:`gamma_weights`, :func:`cos_v_weights`, :func:`albedo_rows`,
  :func:`lobe_albedo`);
- criticism: :class:`Ambient` (the term added to the mean);
- fit: :class:`AmbientLight`, ``A += a`` (C += pi a) and a lobe term ``a alb(gamma, v) / N(gamma)``
  (the compiled passes of :mod:`rjfit.sampler.passes.lobe` interpolate the table);
- Mitsuba: a ``constant`` emitter.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rjfit.effects.base import Columns, Effect, FitForm, Param, take
from rjfit.model.blinn import blinn_normalisation
from rjfit.model.priors import LogNormal
from rjfit.render.scene_change import MitsubaChange

__all__ = ["Ambient", "AmbientLight", "lobe_albedo_quadrature", "albedo_table", "albedo_table_quadrature",
           "gamma_weights", "cos_v_weights", "albedo_rows", "lobe_albedo", "ALBEDO_LOG_GAMMA", "ALBEDO_COS_V",
           "ALBEDO_TABLE", "ALBEDO_TABLE_FILE"]

#: the table's rows: log gamma from log 0.05 to log 5000; its columns: cos theta_v from 0 to 1
ALBEDO_LOG_GAMMA = np.linspace(np.log(0.05), np.log(5000.0), 48)
ALBEDO_COS_V = np.linspace(0.0, 1.0, 41)
#: the table of :func:`albedo_table_quadrature` as shipped with the package (a constant of the model: computing it
#: takes 0.3 s, which every process that fits or criticises ambient light would pay)
ALBEDO_TABLE_FILE = Path(__file__).with_name("ambient_albedo.npy")


def lobe_albedo_quadrature(gamma, cos_v, n_u=64, n_phi=96):
    """``A_g(theta_v) = int N(g) <h.n>^g <l.n> dl`` at one gamma for an array of cos theta_v, by
    quadrature over the half vector (Gauss-Legendre in u = cos^(g+1) theta_h, uniform in phi)."""
    cos_v = np.atleast_1d(np.asarray(cos_v, dtype=float))
    nodes, weights = np.polynomial.legendre.leggauss(n_u)
    u = 0.5 * (nodes + 1.0)
    wu = 0.5 * weights
    phi = (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi)
    cos_h = u ** (1.0 / (gamma + 1.0))
    sin_h = np.sqrt(np.maximum(1.0 - cos_h ** 2, 0.0))
    sin_v = np.sqrt(np.maximum(1.0 - cos_v ** 2, 0.0))[:, None, None]
    cv = cos_v[:, None, None]
    v_dot_h = sin_v * sin_h[None, :, None] * np.cos(phi)[None, None] + cv * cos_h[None, :, None]
    cos_i = 2.0 * v_dot_h * cos_h[None, :, None] - cv
    integrand = np.where((v_dot_h > 0) & (cos_i > 0), cos_i * 4.0 * v_dot_h, 0.0)
    total = np.einsum("u,vup->v", wu, integrand) * (2.0 * np.pi / n_phi)
    return blinn_normalisation(gamma) / (gamma + 1.0) * total


def albedo_table_quadrature() -> np.ndarray:
    """``A_g(theta_v)`` on the grid (:data:`ALBEDO_LOG_GAMMA` x :data:`ALBEDO_COS_V`), by quadrature (0.3 s).

    What :data:`ALBEDO_TABLE_FILE` holds; write it again with ``np.save`` where the grid or the quadrature changes.
    """
    return np.stack([lobe_albedo_quadrature(float(np.exp(lg)), ALBEDO_COS_V, n_u=48, n_phi=64)
                     for lg in ALBEDO_LOG_GAMMA])


def _read_table(path: Path) -> np.ndarray:
    table = np.load(path)
    if table.shape != (ALBEDO_LOG_GAMMA.size, ALBEDO_COS_V.size):
        raise ValueError(f"{path}: the ambient albedo table has shape {table.shape}, not "
                         f"{(ALBEDO_LOG_GAMMA.size, ALBEDO_COS_V.size)}; write it again from albedo_table_quadrature()")
    table.setflags(write=False)
    return table


#: the shipped table, read once at import (read-only)
ALBEDO_TABLE = _read_table(ALBEDO_TABLE_FILE)


def albedo_table() -> np.ndarray:
    """``A_g(theta_v)`` on the grid (:data:`ALBEDO_LOG_GAMMA` x :data:`ALBEDO_COS_V`): :data:`ALBEDO_TABLE`."""
    return ALBEDO_TABLE


def gamma_weights(gamma):
    """The table row ``i`` below each gamma and the weight ``fx`` of row ``i + 1``.

    Linear in log gamma, clipped to the table."""
    grid = ALBEDO_LOG_GAMMA
    x = (np.clip(np.log(np.asarray(gamma, dtype=float)), grid[0], grid[-1]) - grid[0]) / (grid[1] - grid[0])
    i = np.minimum(x.astype(int), grid.size - 2)
    return i, x - i


def cos_v_weights(cos_v):
    """The table column ``j`` below each cos theta_v and the weight ``fy`` of column ``j + 1``."""
    y = np.clip(np.asarray(cos_v, dtype=float), 0.0, 1.0) / (ALBEDO_COS_V[1] - ALBEDO_COS_V[0])
    j = np.minimum(y.astype(int), ALBEDO_COS_V.size - 2)
    return j, y - j


def albedo_rows(gammas):
    """The table interpolated at each of ``gammas`` (linear in log gamma): (len(gammas), n_cos_v)."""
    table = albedo_table()
    i, fx = gamma_weights(gammas)
    return (1 - fx[:, None]) * table[i] + fx[:, None] * table[i + 1]


def lobe_albedo(gamma, cos_v):
    """``A_g(theta_v)``, bilinear in (log gamma, cos theta_v) from the table (vectorised)."""
    table = albedo_table()
    gamma, cos_v = np.broadcast_arrays(np.asarray(gamma, dtype=float), np.asarray(cos_v, dtype=float))
    i, fx = gamma_weights(gamma)
    j, fy = cos_v_weights(cos_v)
    return ((1 - fx) * (1 - fy) * table[i, j] + fx * (1 - fy) * table[i + 1, j]
            + (1 - fx) * fy * table[i, j + 1] + fx * fy * table[i + 1, j + 1])


class Ambient(Effect):
    name = "ambient"
    kind = "ambient or stray light"
    stage = "ambient"
    description = "constant environment radiance a (relative to the reference intensity) x the BRDF's albedo"

    def params(self, ctx):
        return [Param("ambient", LogNormal(loc=float(np.log(0.01)), scale=2.5), init=0.01, null=0.0)]

    def prepare(self, ctx):
        # Bilinear interpolation is separable: the view angle's column and weight are fixed per
        # observation, so a refit's evaluation interpolates in gamma once per region (a row of
        # the table) and gathers from those rows (as lobe_albedo, 15x faster on the ball)
        j, fy = cos_v_weights(ctx.cos_vn)
        return ctx.region * ALBEDO_COS_V.size + j, fy

    def apply(self, terms, theta, features, ctx):
        kd = terms["kd"]
        index, fy = features
        rows = albedo_rows(terms["gamma_region"]).ravel()
        albedo = (1.0 - fy) * rows[index] + fy * rows[index + 1]
        terms["mu"] = terms["mu"] + theta[0] * terms["I0"] * (kd + (1.0 - kd) * albedo)

    def mitsuba_change(self, theta, ctx):
        radiance = float(theta[0]) * ctx.reference_intensity
        environment = {"type": "constant", "radiance": {"type": "rgb", "value": [radiance] * 3}}
        return MitsubaChange(extra={"ambient": environment},
                             stochastic=True,
                             notes=["exact for a convex object: nothing occludes the environment"])

    def fit_form(self, ctx):
        """``A += a`` and the lobe's ambient term (:class:`AmbientLight`)."""
        column, weight = cos_v_weights(ctx.cos_vn)
        grid = np.array([ALBEDO_LOG_GAMMA[0], ALBEDO_LOG_GAMMA[-1], ALBEDO_LOG_GAMMA[1] - ALBEDO_LOG_GAMMA[0]])
        return AmbientLight(params=self.fit_params(ctx), column=column.astype(np.int32), weight=weight,
                            table=albedo_table(), grid=grid)


@dataclass(frozen=True, eq=False)
class AmbientLight(FitForm):
    """Ambient light in the fit, of radiance a: ``a I0 (kd + (1 - kd) alb(gamma, v))`` added to the mean.

    ``column`` and ``weight`` place each observation's view angle in the albedo table
    (:func:`cos_v_weights`); ``table`` and ``grid`` are the table and its log-gamma grid
    (lowest, highest, step).
    """

    params: tuple
    column: np.ndarray
    weight: np.ndarray
    table: np.ndarray
    grid: np.ndarray
    name: str = "ambient"
    stage: str = "ambient"

    def apply(self, columns: Columns, theta) -> None:
        columns.C = columns.C + np.pi * theta[0]
        columns.ambient = float(theta[0])
        columns.ambient_terms = (self.column, self.weight, self.table, self.grid)

    def in_order(self, order):
        return take(self, order, "column", "weight")
