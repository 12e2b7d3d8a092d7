"""The effect protocol: one candidate missing effect = parameters with priors, features from
the geometry / Mitsuba, an extension of eq. 2, a residual signature and a Mitsuba-side change.

Stages (the order :func:`rjfit.diagnose.model.predict` applies them in)::

    lobe      specular-lobe factor      spec *= factor            (Fresnel, masking)
    direct    direct-light factor       direct *= factor          (cast shadows)
    indirect  added light-dependent     mu = direct + indirect    (interreflection)
    light     per-light factor          mu *= s_l                 (light calibration)
    ambient   added light-independent   mu += ambient             (ambient / stray light)
    camera    response curve            y = C(mu)                 (camera response)

with ``mu = I0 E (kd/pi + (1 - kd) N(g) <h.n>^g spec) <l.n>`` in between (eq. 2). At the
effect's null value (``Param.null``) every factor is 1 and every added term 0: the plain
model is nested in each extension.

Each effect also says how it enters the FIT (issue 26): :meth:`Effect.sampler_effect` builds
the :class:`rjfit.sampler.forward.Effect` the fit samples with the regions, with this
library's priors and starting values and the features of the context's observations (see
:mod:`rjfit.sampler.effects`). The fit's closed form equals :func:`rjfit.diagnose.model.predict`
for the same parameters (``tests/diagnose/test_effects_in_fit.py``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rjfit.model.effects import STAGES
from rjfit.render.scene_change import MitsubaChange
from rjfit.sampler.forward import EffectParam

__all__ = ["Param", "Effect", "STAGES"]


@dataclass(frozen=True)
class Param:
    """One scalar parameter of an effect: its prior (with the transform) and two values:
    ``init`` where a refit starts, ``null`` where the effect vanishes (possibly a bound of the
    prior's support, approached only as a limit: an ambient term's 0, camera sRGB's infinite
    white level; None where no value of this parameter alone makes the effect vanish).

    ``physical_ends`` lists the bounds of the prior's support that are physical states, not
    artefacts of the transform: a weight's w = 1 (full occlusion, full masking). A MAP pulled
    towards such an end lies many prior sd out on the logit scale (w = 0.999 is 3.5 sd of a
    LogitNormal(0, 2)) yet is a physical value, so it is not a prior-data conflict."""

    name: str
    prior: object
    init: float
    null: float | None = None
    physical_ends: tuple = ()


class Effect:
    """Base class of the candidate effects (each module under ``effects/`` defines one)."""

    name: str = ""
    kind: str = ""            # the category (e.g. "camera response")
    stage: str = ""
    description: str = ""
    needs_mitsuba: bool = False
    # apply() changes an observation's terms through its own region's parameters and the
    # effect's only, so the refit's objective has no cross terms between two regions'
    # parameters and its Hessian skips them (rjfit.diagnose.hessian); False for an effect that
    # couples regions (say, light one region sends to another at its fitted albedo)
    region_local: bool = True
    # An effect whose parameters act only through one value per light, ``u = B theta`` with
    # ``B = light_basis(ctx)`` (L, k) and an observation of light l depending on u[l] alone
    # (its priors Normal, so theta = z): the refit's Hessian is then taken over the L
    # light values, whose pairs never meet (rjfit.diagnose.hessian), and mapped back by B.
    # Such an effect defines ``light_basis`` and ``apply_light_values(terms, u, ctx)``.
    light_basis = None

    # -- parameters --------------------------------------------------------------------
    def params(self, ctx) -> list:
        raise NotImplementedError

    def param_names(self, ctx) -> list:
        return [p.name for p in self.params(ctx)]

    def available(self, ctx) -> tuple[bool, str]:
        """Whether the effect can be tried on this context, and why not."""
        if self.needs_mitsuba and not ctx.has_mesh:
            return False, "needs the scene's mesh for Mitsuba features; the data set has none"
        return True, ""

    # -- features and the extension ----------------------------------------------------
    def prepare(self, ctx):
        """Per-observation features (computed once per context; cached by the caller)."""
        return None

    def apply(self, terms: dict, theta: np.ndarray, features, ctx) -> None:
        """Extend the model in ``terms`` (in place) at constrained parameters ``theta``."""
        raise NotImplementedError

    # -- inside the fit ----------------------------------------------------------------
    def fit_params(self, ctx) -> tuple:
        """The parameters as the fit takes them: name, this library's prior, starting value."""
        return tuple(EffectParam(p.name, p.prior, float(p.init)) for p in self.params(ctx))

    def sampler_effect(self, ctx):
        """The :class:`rjfit.sampler.forward.Effect` the fit samples, its features in the order of ``ctx``'s observations."""
        raise NotImplementedError

    # -- signature ---------------------------------------------------------------------
    def signature(self, ctx, residuals, sigma2, template_columns):
        """What the residuals look like if this effect is missing, and how much they do.

        ``template_columns`` (N, k) are the derivatives of the predicted values with
        respect to the effect's unconstrained parameters at their ``init`` values, taken
        at the current fit (computed from the effect's features: geometry and Mitsuba).
        The score is the share of the standardised residuals' sum of squares that a least
        squares combination of the columns explains (0..1); the map is that combination per
        pixel (mean over lights), in units of the noise standard deviation.
        """
        columns = np.asarray(template_columns, dtype=float)
        r = np.asarray(residuals, dtype=float) / np.sqrt(sigma2)
        finite = np.all(np.isfinite(columns), axis=1)
        if not finite.any() or not np.any(columns[finite]):
            return 0.0, ctx.per_pixel_mean(np.zeros_like(r))
        coef, *_ = np.linalg.lstsq(columns[finite], r[finite], rcond=None)
        fitted = np.zeros_like(r)
        fitted[finite] = columns[finite] @ coef
        score = float(np.sum(fitted ** 2) / max(np.sum(r ** 2), 1e-300))
        return score, ctx.per_pixel_mean(fitted)

    # -- Mitsuba side ------------------------------------------------------------------
    def mitsuba_change(self, theta, ctx) -> MitsubaChange:
        raise NotImplementedError

    def __repr__(self):
        return f"<effect {self.name}>"
