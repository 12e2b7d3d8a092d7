"""The effect protocol: one effect of the library = its physics, parameters with priors, the
criticism's form (an extension of eq. 2 with a residual signature and a Mitsuba-side change)
and the fit's form (how it enters the fit's likelihood).

Stages (the order :func:`rjfit.diagnose.model.predict` and the fit apply them in)::

    lobe      specular-lobe shape       spec = (1-w) spec + w f   (a GGX lobe mixed in, first in the stage)
              specular-lobe factor      spec *= factor            (Fresnel, masking)
    direct    added direct light        direct += term            (a second lobe, first in the stage)
              direct-light factor       direct *= factor          (cast shadows)
    indirect  added light-dependent     mu = direct + indirect    (interreflection)
    light     per-light factor          mu *= s_l                 (light calibration)
    ambient   added light-independent   mu += ambient             (ambient / stray light)
    camera    response curve            y = C(mu)                 (camera response)

with ``mu = I0 E (kd/pi + (1 - kd) N(g) <h.n>^g spec) <l.n>`` in between (eq. 2). At the
effect's null value (``Param.null``) every factor is 1 and every added term 0: the plain
model is nested in each extension.

Each effect also says how it enters the FIT (issue 26): :meth:`Effect.fit_form` builds the
:class:`FitForm` the fit samples with the regions (a column factor, a data transform or a
lobe term, changing the :class:`Columns` of :mod:`rjfit.sampler.forward`), with this
library's priors and starting values and the features of the context's observations. The
fit's closed form equals :func:`rjfit.diagnose.model.predict` for the same parameters
(``tests/diagnose/test_effects_in_fit.py``).
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, replace

import numpy as np

from rjfit.render.scene_change import MitsubaChange

__all__ = ["STAGES", "Param", "Effect", "CameraResponse", "FitForm", "Columns", "take", "stage_key"]

#: the order in which effects extend eq. 2 (the module docstring describes each stage)
STAGES = ("lobe", "direct", "indirect", "light", "ambient", "camera")


def stage_key(effect) -> tuple:
    """Where an effect (or fit form) applies: its stage's place in :data:`STAGES`, then its
    ``order_in_stage`` (a lobe's distribution, -1, before the factors on it, 0, before a lobe
    added after them, 1; 0 for an object without one, such as a wrapper of an effect). Sorting by it is
    stable, so effects of one rank keep their order."""
    return STAGES.index(effect.stage), getattr(effect, "order_in_stage", 0)


@dataclass(frozen=True)
class Param:
    """One scalar parameter of an effect: its prior (with the transform; Gaussian in an
    unconstrained coordinate, :mod:`rjfit.model.priors`) and two values: ``init`` where a
    refit starts and chains start near, ``null`` where the effect vanishes (possibly a bound
    of the prior's support, approached only as a limit: an ambient term's 0, camera sRGB's
    infinite white level; None where no value of this parameter alone makes the effect vanish).

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
    """Base class of the library's effects (each module of :mod:`rjfit.effects` defines one)."""

    name: str = ""
    kind: str = ""            # the category (e.g. "camera response")
    stage: str = ""
    order_in_stage: int = 0   # within the stage (stage_key): -1 a lobe's distribution, 1 a lobe added after its factors
    description: str = ""
    needs_mitsuba: bool = False
    # Its feature is rendered by Mitsuba from the fitted regions' BRDFs (interreflection's
    # indirect light), so it depends on the segmentation: a refit renders it on the diagnosed
    # fit's MAP labels, and `rjfit refine` renders it again while a round's labels move
    renders_fitted_model: bool = False
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

    # -- the criticism's form: features and the extension of eq. 2 ---------------------
    def prepare(self, ctx):
        """Per-observation features (computed once per context; cached by the caller)."""
        return None

    def apply(self, terms: dict, theta: np.ndarray, features, ctx) -> None:
        """Extend the model in ``terms`` (in place) at constrained parameters ``theta``."""
        raise NotImplementedError

    # -- the fit's form ----------------------------------------------------------------
    def fit_params(self, ctx) -> tuple:
        """The parameters as the fit takes them: name, this library's prior, starting value."""
        return tuple(Param(p.name, p.prior, float(p.init)) for p in self.params(ctx))

    def fit_form(self, ctx) -> FitForm:
        """The :class:`FitForm` the fit samples, its features in the order of ``ctx``'s observations."""
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


class CameraResponse(Effect):
    """An effect of the kind "camera response": a curve ``y = curve(mu, theta, white_level)`` on the
    mean, applied last, and the same curve on the path-traced images (its Mitsuba side).

    The noise is a sensor's: added to the linear radiance, before the curve (``y = f(mu + e)``),
    so the stored values' noise follows the curve's slope. The fit and the criticism alike
    write the likelihood on the linear scale, ``f^-1(y) ~ N(mu, sigma^2 s^2)``, times the
    inverse's slope ``|(f^-1)'(y)|`` (the density of ``y``). Subclasses define :meth:`params`,
    :meth:`curve`, :meth:`inverse` with :meth:`inverse_log_slope` (from the functions of the
    effect's module, which its fit form uses too) and :meth:`fit_form`."""

    kind = "camera response"
    stage = "camera"

    def curve(self, mu, theta, white_level):
        raise NotImplementedError

    def inverse(self, values, theta, white_level):
        """``f^-1(values)``: stored values on the linear scale."""
        raise NotImplementedError

    def inverse_log_slope(self, values, theta, white_level):
        """``log (f^-1)'(values)`` per value (the log-Jacobian of the linearisation)."""
        raise NotImplementedError

    def prepare(self, ctx):
        return ctx.white_level

    def apply(self, terms, theta, features, ctx):
        terms["mu"] = self.curve(terms["mu"], theta, features)

    def mitsuba_change(self, theta, ctx):
        white = ctx.white_level
        return MitsubaChange(post_process=lambda images: self.curve(images, theta, white))


class FitForm(ABC):
    """An effect as the fit samples it: parameters -> transformed columns.

    A fit form changes the :class:`Columns` (float64, in the problem's order) in place at
    its constrained parameters (:meth:`apply`), in the order of its ``stage``
    (:data:`STAGES`, the criticism's order). A per-observation feature the problem does not
    hold (a visibility, a view angle) the form keeps itself, in the order of the
    observations it was built from; :meth:`in_order` returns it in the problem's order.
    Subclasses are frozen dataclasses (a chain's checkpoint digests them).

    Attributes
    ----------
    name : str
        The effect's name (as the library names it).
    stage : str
        One of :data:`STAGES`.
    params : tuple of Param
    """

    name: str
    stage: str
    params: tuple
    order_in_stage = 0        # as Effect.order_in_stage (a class attribute, not a dataclass field)

    @property
    def n_params(self) -> int:
        return len(self.params)

    @abstractmethod
    def apply(self, columns: Columns, theta) -> None:
        """Change ``columns`` in place at constrained parameters ``theta``."""

    def in_order(self, order) -> FitForm:
        """This form with its per-observation features taken at ``order`` (default: no feature, itself)."""
        return self


def take(form: FitForm, order, *fields: str) -> FitForm:
    """``form`` with each of its per-observation ``fields`` taken at ``order`` (a :meth:`FitForm.in_order`)."""
    return replace(form, **{name: np.asarray(getattr(form, name))[order] for name in fields})


@dataclass
class Columns:
    """The columns while effects are applied (float64, the problem's order, before the noise scales).

    The model is ``f(offset + a A + b B(gamma))`` on the data's scale with ``A = C / pi`` and
    ``B`` as in :mod:`rjfit.sampler.forward`; ``y`` holds ``f^-1`` of the data once the camera
    stage ran (the raw data before), ``log_jacobian`` the sum of ``log |(f^-1)'(y_i)|``,
    ``light`` the light of each observation (for per-light effects), ``curve`` the response
    ``f`` (None: linear).
    """

    y: np.ndarray
    C: np.ndarray
    CB: np.ndarray
    light: np.ndarray
    offset: np.ndarray | None = None
    mask_w: float = 0.0
    tan: tuple | None = None            # (tan v, tan l) of masking and of the GGX lobes
    ggx_w: float = 0.0                  # weight of the GGX lobe mixed into the Blinn lobe (0: none)
    second_lobe: np.ndarray | None = None   # a second lobe's C v f_GGX(alpha2) per observation (direct light)
    ambient: float | None = None        # ambient radiance a of the ambient stage
    ambient_terms: tuple | None = None  # (column j, weight fy, table, grid) of the albedo interpolation
    log_jacobian: float = 0.0
    curve: object = None

    def scale(self, factor) -> None:
        """Multiply the direct and indirect light (``C``, ``CB``, a second lobe and the offset) by per-observation
        ``factor``."""
        self.C = self.C * factor
        self.CB = self.CB * factor
        if self.second_lobe is not None:
            self.second_lobe = self.second_lobe * factor
        if self.offset is not None:
            self.offset = self.offset * factor

    def add_offset(self, values) -> None:
        """Add known light (on the linear scale, before the light stage) to every observation's mean."""
        self.offset = values if self.offset is None else self.offset + values

    def data_scale(self, mean):
        """``f(offset + mean)``: a mean on the linearised scale (before noise scales) on the data's scale."""
        mean = mean if self.offset is None else mean + self.offset
        return mean if self.curve is None else self.curve(mean)
