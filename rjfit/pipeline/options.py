"""Every option of a fit, declared once: :class:`FitOptions`.

A field holds its default, its check and, for options the command line offers, its flag and
help text (:func:`cli_option`): ``rjfit fit`` builds its click options from these fields, the
Python API (:func:`rjfit.pipeline.fit.fit`, :func:`~rjfit.pipeline.fit.fit_datasets`) takes
the same names as keyword arguments, and the summary records the options it ran with. Adding
an option is one field here, plus the code that uses it.

One rule for "not given": a field is None until it is given, for every field. What a fit was
not given is filled once, by :func:`rjfit.pipeline.resolve.resolve_options` (the preset, the
data's kind, the plain default: ``metadata["default"]`` of each field), which records where each
value came from (``sources``). Each region model's ``RegionFit.reads``
(:mod:`rjfit.pipeline.regions`) and :data:`CHOICE_OPTIONS` say which options each region model, noise
model and sampler reads: a given option that the fit's models do not read is refused there. This module
names the region models (:data:`REGION_MODELS`, ``--regions``' choices) but may not import them
(they build their settings from these options).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from pathlib import Path

from rjfit.data.formats import CHANNELS, COLOUR
from rjfit.data.noise import DEFAULT_FLOOR, NOISE_MODELS
from rjfit.data.observations import RIM_COS
from rjfit.effects import EFFECTS, effects_help
from rjfit.sampler.priors import PRESETS

__all__ = ["FitOptions", "CliSpec", "cli_option", "EACH_CHANNEL", "FIT_CHANNELS", "REGION_MODELS", "NOISE_OPTIONS",
           "SAMPLER_OPTIONS", "CHOICE_OPTIONS", "EFFECT_OPTIONS", "GIVEN"]

EACH_CHANNEL = ("R", "G", "B")                 # what ``channel="each"`` fits, one fit per channel
FIT_CHANNELS = CHANNELS + ("each", COLOUR)
GIVEN = "given"                                # a value's source (FitOptions.sources) when the user gave it

#: The region models' ``--regions`` names, in the order of :data:`rjfit.pipeline.regions.REGION_FITS` (a test
#: checks they agree); the options each reads are its ``RegionFit.reads``.
REGION_MODELS = ("changepoints", "materials", "fixed")
#: The options each noise model reads beyond ``noise`` itself (``--noise``); models not named read none.
NOISE_OPTIONS = {"shot": frozenset({"noise_floor"}), "relative": frozenset({"noise_floor"})}
#: The options read only by some samplers (``--sampler``).
SAMPLER_OPTIONS = {"adaptive": frozenset({"gamma_moves"})}
#: The fields whose choice decides whether an option is read: (field, {choice: the options read only under it}).
CHOICE_OPTIONS = (("noise", NOISE_OPTIONS), ("sampler", SAMPLER_OPTIONS))
#: The options read only when effects are sampled (``--effects`` or ``--effects-from``).
EFFECT_OPTIONS = frozenset({"effect_every"})

@dataclass(frozen=True)
class CliSpec:
    """How a :class:`FitOptions` field appears on the command line.

    ``kind`` is one of 'int', 'float', 'choice', 'flag', 'text', 'path' (a file), 'dir' (a
    folder), 'power' (a number in (0, 1] or 'auto'); ``low`` is the smallest integer an 'int' takes.
    """

    flag: str
    help: str
    kind: str
    choices: tuple = ()
    low: int | None = None
    show_default: bool = True


def option(default):
    """A dataclass field that is None until given, with the value it takes when nothing else sets it."""
    return field(default=None, metadata={"default": default})


def cli_option(default, flag: str, help: str, kind: str, **spec):
    """:func:`option` with its command-line flag and help (``metadata["cli"]``)."""
    return field(default=None, metadata={"default": default,
                                         "cli": CliSpec(flag=flag, help=help, kind=kind, **spec)})


def _effect_names(value) -> tuple:
    """``effects`` as a tuple of library names: from 'a,b' (the command line) or a sequence."""
    names = [n.strip() for n in value.split(",")] if isinstance(value, str) else [str(n) for n in value]
    names = tuple(dict.fromkeys(n for n in names if n))
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown effect(s) {', '.join(unknown)} (--effects): choose from {', '.join(sorted(EFFECTS))}")
    return names


POWER_RULES = ("auto", "area")
#: ``--normals``: the given normals as they are, or each pixel's sampled (rjfit.sampler.normals)
NORMALS_CHOICES = ("fixed", "sample")
#: degrees: the rim's edge, arccos(RIM_COS) = 72.5 (rjfit.data.observations.RIM_COS)
RIM_VIEW_ANGLE = round(math.degrees(math.acos(RIM_COS)), 2)
#: The prior odds of each further material, with and without the preset: 1:100, so that one takes half the
#: posterior only with a decisive Bayes factor (Jeffreys). At 1:1 (plain, until 2026-11-27) materials of one
#: pixel whose own parameters fit its noise held 15 to 21 % of two of four rendered layouts' posteriors; at 1:20
#: (the preset) those of outlier pixels held 2 to 23 % of the one-material stacks' (docs/results/materials.md,
#: docs/results/measured-data.md).
FURTHER_MATERIAL_ODDS = 0.01
#: The Potts prior's factor per material without the preset (the preset's rule: rjfit.pipeline.resolve).
PLAIN_POTTS_RHO = FURTHER_MATERIAL_ODDS


def _likelihood_power_value(value):
    if value in POWER_RULES:
        return value
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"likelihood power (--likelihood-power) must be a number in (0, 1], 'auto' or 'area', got "
                         f"{value!r}") from None
    if not 0.0 < number <= 1.0:
        raise ValueError(f"likelihood power (--likelihood-power) must lie in (0, 1], got {number}")
    return number


def _auto_or_at_least_zero(what: str):
    """The converter of an option that is 'auto' or a number >= 0 (``what`` names it in the refusal)."""
    def convert(value):
        if value == "auto":
            return value
        try:
            number = float(value)
        except (TypeError, ValueError):
            number = math.nan
        if not (math.isfinite(number) and number >= 0):
            raise ValueError(f"{what} must be a number >= 0 or 'auto', got {value!r}")
        return number
    return convert


@dataclass(frozen=True)
class FitOptions:
    """The options of one fit (or of each fit of a batch). Each given option is checked when it is built.

    A field is None where it was not given; :func:`rjfit.pipeline.resolve.resolve_options` fills
    every field and records each one's source in ``sources`` (empty: not resolved yet).

    Raises
    ------
    ValueError
        If a given option is out of range, naming its command-line flag: ``burn_in`` not in [0, 1),
        ``n_chains < 1``, ``iterations < 10``, an unknown ``prior``, ``noise``, ``channel``,
        ``sampler``, ``split_map`` or ``cp_prior``, a ``likelihood_power`` that is neither
        'auto' nor in (0, 1], ``anneal`` not in [0, 1], ``noise_floor`` not positive,
        ``max_u`` / ``max_v`` negative, an effect the library does not know,
        ``effect_every`` below 1, or a ``labels`` map without ``regions='fixed'``.
    """

    n_chains: int = cli_option(4, "--chains", "Chains from dispersed starts.", "int", low=1)
    iterations: int = cli_option(4000, "--iterations", "Iterations per chain (default 4000; --preset measured: 500).",
                                 "int", low=10, show_default=False)
    burn_in: float | None = cli_option(
        None, "--burn-in", "Discarded fraction (default: 0.5 for rendered data, 0.2 for measured, as in the paper).",
        "float", show_default=False)
    regions: str = cli_option(
        "changepoints", "--regions",
        "Region model: the paper's change points (changepoints), free-form materials (materials): a material "
        "label per pixel under a Potts prior, K materials unknown, one BRDF per material shared by all its pixels, "
        "connected or not; or your own label map held fixed (fixed, with --labels). Default: changepoints for "
        "rendered data, materials for measured data.", "choice", choices=REGION_MODELS, show_default=False)
    labels: Path | None = cli_option(
        None, "--labels",
        "Label map of --regions fixed: an integer label per pixel of the images (.npy, .exr or a one-channel image; "
        "negative: no label); each label's BRDF posterior is sampled, nothing else.", "path", show_default=False)
    max_materials: int = cli_option(8, "--max-materials",
                                    "Most materials (--regions materials); the summary warns when the posterior "
                                    "puts mass on it.", "int", low=1)
    potts_beta: float = cli_option(3.0, "--potts-beta",
                                   "Potts prior strength per pair of neighbouring pixels of different materials "
                                   "(--regions materials); keep it above log(1 + sqrt(--max-materials)), the "
                                   "critical coupling (docs/options.md).", "float")
    potts_rho: float = cli_option(
        PLAIN_POTTS_RHO, "--potts-rho",
        "Prior factor per material (--regions materials): pi(S) ~ rho^K exp(-beta B). Default 0.01 (prior odds 1:100 "
        "per further material); --preset measured sets beta and rho by a rule on the mask unless --potts-rho is "
        "given (docs/options.md).", "float", show_default=False)
    edge_power: float | str = cli_option(
        0.0, "--edge-power",
        "Power of the edge term in the target (--regions materials, no effects; with --channel rgb summed over the "
        "channels): a boundary between "
        "two materials earns where the data's differences across it step as the materials do, and costs where "
        "no step fits them better. A number >= 0, or 'auto' "
        "(the coarsening rule on those differences). Default 0 (none); --preset measured sets auto where it "
        "applies (docs/options.md).", "power", show_default=False)
    edge_gain_sd: float | str = cli_option(
        0.0, "--edge-gain-sd",
        "The edge term's local gain (with --edge-power): the sd of a factor on the shading that a pair's two ends "
        "share and that scales the step across them, integrated out of each pair, so that a boundary earns by the "
        "step's shape and size beyond that factor. A number >= 0, or 'auto' (measured on the data). Default 0 "
        "(none); --preset measured sets auto with the edge term in one channel (docs/options.md).", "power",
        show_default=False)
    edge_noise: str = cli_option(
        "constant", "--edge-noise",
        "The noise of the edge term's differences (with --edge-power): constant (one scale for every pair) or "
        "measured (each pair's variance growing with how much the shading changes and the geometry turns across "
        "it, measured on the data). Default constant; --preset measured sets measured with the edge term "
        "(docs/options.md).", "choice", choices=("constant", "measured"), show_default=False)
    preset: str = cli_option(
        "none", "--preset",
        "Defaults for a kind of data: none (the options as given); measured: --noise normals, --likelihood-power "
        "auto, no annealed warm-up, --max-view-angle 72.5, --gamma-moves 8, --iterations 500, the Potts rule on the "
        "mask (--regions materials), the edge term (auto) where it applies, with its measured noise and, in one "
        "channel, its local gain (auto), and calibration (small mask parts left out; an unknown camera response and "
        "per-light gains estimated and applied), each where not given "
        "(docs/options.md). Default: none for rendered data, measured for measured data.", "choice", choices=("none", "measured"), show_default=False)
    calibrate: bool = option(False)
    # half the material model's cluster seeds drawn per material (first under --preset measured, now every
    # material fit's: one-pixel leftovers die within tens of iterations; docs/results/materials.md)
    cluster_material_seed: float = option(0.5)
    # the material model's segment moves per iteration (data-driven regions moved or born whole;
    # rjfit/sampler/moves/segment_move.py); 0 for the comparison in docs/results/measured-data.md
    segment_moves: int = option(2)
    # the material model's component moves per iteration (a connected piece of a material moved whole;
    # rjfit/sampler/regions/materials/component_move.py): not in the default, since the target prefers shading
    # parts of psm-cat that these moves propose and the others do not (docs/results/2026-11-28-local-gain.md)
    component_moves: int = option(0)
    # the material model's scatter moves per iteration (a whole material dissolved into the others pixel by pixel,
    # and its reverse; rjfit/sampler/regions/materials/scatter_move.py): not in the default, since as many of
    # psm-horse's chains keep a second material with them (docs/results/2026-12-03-scatter-moves.md)
    scatter_moves: int = option(0)
    # the material model's spatial splits per iteration (a material split into the halves of its pixels' positions,
    # and their reverse; rjfit/sampler/regions/materials/merge_split.py): 0 under --preset measured, where psm-cat's
    # chains kept more small materials with them (docs/results/2026-12-01-spatial-splits.md)
    spatial_split_moves: int = option(1)
    max_u: int = cli_option(3, "--max-u", "Most u change-point vectors (--regions changepoints).", "int", low=0)
    max_v: int = cli_option(3, "--max-v", "Most v change-point vectors (--regions changepoints).", "int", low=0)
    sampler: str = cli_option("adaptive", "--sampler",
                              "Within-model moves: adaptive blocks (default) or the paper's component-wise MH.",
                              "choice", choices=("adaptive", "paper"))
    gamma_moves: int = cli_option(
        2, "--gamma-moves",
        "Gamma moves per region and iteration of the adaptive sampler (each proposes log gamma and redraws kd and I0 "
        "given it). Default 2; --preset measured: 8.", "int", low=1, show_default=False)
    prior: str = cli_option("default", "--prior", "Prior preset (paper: Table 1 synthetic, Table 3 real).",
                            "choice", choices=PRESETS)
    split_map: str = cli_option(
        "conditional", "--split-map",
        "Parameters of regions born by a split (--regions changepoints): drawn from a data-driven proposal "
        "(conditional), or a bijective map: mean (|det| 2) or the paper's eq. 10 (|det| 3), Jacobian included.",
        "choice", choices=("conditional", "mean", "paper"))
    cp_prior: str = cli_option("smooth", "--cp-prior",
                               "Change-point prior (--regions changepoints): random walk along the vector (smooth) "
                               "or independent uniform per row.", "choice", choices=("smooth", "paper"))
    drop_jacobian: bool = cli_option(False, "--drop-jacobian",
                                     "Reproduce the paper's acceptance ratio without the split/merge Jacobian "
                                     "(--regions changepoints; wrong; for study).", "flag")
    jump_prob: float = option(0.2)
    channel: str = cli_option(
        "mean", "--channel",
        "Colour channel fitted (luminance: CIE Y, sRGB primaries); each: R, G and B fitted separately, into "
        "OUT/R, OUT/G and OUT/B (OUT/NAME/R, ... for several data sets); rgb: R, G and B fitted jointly (one "
        "segmentation, one lobe exponent per material, per-channel amplitudes and noise; --regions materials).",
        "choice", choices=FIT_CHANNELS)
    likelihood_power: float | str = cli_option(
        1.0, "--likelihood-power",
        "zeta in (0, 1] of the coarsened posterior (likelihood ** zeta, Miller and Dunson 2019): each observation "
        "counts as zeta observations, so a misfit shared by neighbouring pixels does not split a material. 'auto': "
        "from the lag-1 spatial correlation of per-pixel-fit residuals; 'area': from their autocorrelation summed "
        "over lags (docs/options.md). Default 1 (the plain posterior); --preset measured: auto.", "power",
        show_default=False)
    noise: str = cli_option(
        "constant", "--noise",
        "Noise model y_i ~ N(mu_i, sigma_r^2 s_i^2), s_i known per observation: constant (s_i = 1, the paper's); "
        "shot (variance grows with the signal); relative (sd grows with the signal); normals (the measured normals' "
        "error as noise); footprint (normals plus a pixel's footprint). Default constant; --preset measured: "
        "normals. What each assumes and when to use it: docs/options.md.", "choice", choices=NOISE_MODELS,
        show_default=False)
    normals: str = cli_option(
        "fixed", "--normals",
        "fixed: the given normals are used as they are (their error as noise under --noise normals); sample: each "
        "pixel's normal is an unknown with a Gaussian prior around the given one at the estimated normal-error scale, "
        "sampled with the regions (one channel, no effects), its posterior shift and sd written to maps.exr; under "
        "--noise normals the noise inflation is kept (docs/options.md).", "choice",
        choices=NORMALS_CHOICES)
    normal_sd: float | None = cli_option(
        None, "--normal-sd",
        "Degrees: the sd of the sampled normals' prior per tangent direction (--normals sample); default the "
        "normal-error estimate of 5 x 5 tile fits, floored at 0.25.", "float", show_default=False)
    max_view_angle: float | None = cli_option(
        None, "--max-view-angle",
        "Degrees: observations of pixels seen further than this from their normal (the rim) are left out; their "
        "labels follow their neighbours'. Default 90 (every view kept); --preset measured sets 72.5 (give 90 to "
        "keep every view under it; docs/options.md).", "float", show_default=False)
    light_field: int = cli_option(
        0, "--light-field",
        "Degree of each light's gain field: with the per-light gains of a data set whose response is unknown, each "
        "light's gain is the exponential of a polynomial of this degree over the image (a light that lights the "
        "object unevenly), estimated and divided out of its images. 0: one gain per light. Default 0; --preset "
        "measured sets 2 (docs/options.md).", "int", low=0, show_default=False)
    noise_floor: float = cli_option(
        DEFAULT_FLOOR, "--noise-floor",
        "c / ybar of the shot and relative noise models (--noise shot or relative): the floor (read noise) added to "
        "the signal, as a fraction of the mean observed value.", "float")
    effects: tuple = cli_option(
        (), "--effects",
        "Effects sampled jointly with the segmentation and the region BRDFs, comma-separated names, each with the "
        "library's priors (docs/sampler.md). Interreflection needs --effects-from. Either region model; a single "
        "channel (not --channel rgb). The effects: " + effects_help(),
        "text", show_default=False)
    effects_from: Path | None = cli_option(
        None, "--effects-from",
        "A diagnosis folder (rjfit diagnose --out): the effects it named are sampled too; interreflection's Mitsuba "
        "feature is rendered on the diagnosed fit's MAP segmentation at the diagnosis' final-model materials.", "dir",
        show_default=False)
    effect_every: int = cli_option(1, "--effect-every",
                                   "Iterations between the effects' moves (one move per effect; with --effects).",
                                   "int", low=1)
    anneal: float = option(0.5)
    cp_thin: int = option(10)
    seed: int = cli_option(0, "--seed", "Seed of every random draw.", "int", low=0)
    checkpoint_every: int = cli_option(
        2000, "--checkpoint-every",
        "Iterations between a chain's checkpoints (OUT/checkpoints): a fit stopped by Ctrl-C, a crash or SIGKILL and "
        "run again with the same command resumes there and gives the samples of an uninterrupted run.", "int", low=1)
    threads: int | None = cli_option(
        None, "--threads",
        "Threads per chain for its large passes over the observations (default: the cores left to each chain that "
        "runs at once, e.g. 2 for one chain on 2 cores, 1 for 4 chains; 1 on Dask). The samples are the same for any "
        "number.", "int", low=1, show_default=False)
    processes: int | None = option(None)
    figures: bool = option(True)
    progress: bool = option(True)
    # (name, source) of every field once resolved (rjfit.pipeline.resolve.resolve_options): 'given', 'preset',
    # 'data' (the data's kind or its declared calibration need) or 'default'; () until then
    sources: tuple = ()

    def __post_init__(self):
        self._check_counts()
        for name, what in (("preset", "preset"), ("regions", "region model"), ("prior", "prior"), ("noise", "noise model"),
                           ("channel", "channel"), ("normals", "normals"),
                           ("sampler", "sampler"), ("split_map", "split map"), ("cp_prior", "change-point prior"),
                           ("edge_noise", "edge noise")):
            spec = self.cli(name)
            if getattr(self, name) is not None and getattr(self, name) not in spec.choices:
                raise ValueError(f"unknown {what} {getattr(self, name)!r} ({spec.flag}): choose one of "
                                 f"{', '.join(spec.choices)}")
        self._convert("likelihood_power", _likelihood_power_value)
        self._convert("edge_power", _auto_or_at_least_zero("edge power (--edge-power)"))
        self._convert("edge_gain_sd", _auto_or_at_least_zero("the edge term's gain sd (--edge-gain-sd)"))
        self._convert("effects", _effect_names)
        self._convert("effects_from", Path)
        self._convert("labels", Path)
        self._check_ranges()

    def _convert(self, name, convert):
        if getattr(self, name) is not None:
            object.__setattr__(self, name, convert(getattr(self, name)))

    def _check_counts(self):
        if self.burn_in is not None and not 0.0 <= self.burn_in < 1.0:
            raise ValueError(f"burn_in (--burn-in) is a fraction in [0, 1), got {self.burn_in}")
        if (self.n_chains is not None and self.n_chains < 1) or (self.iterations is not None and self.iterations < 10):
            raise ValueError(f"need n_chains >= 1 (--chains) and iterations >= 10 (--iterations), got "
                             f"{self.n_chains}, {self.iterations}")
        if self.effect_every is not None and self.effect_every < 1:
            raise ValueError(f"effect_every (--effect-every) must be >= 1, got {self.effect_every}")
        if self.max_materials is not None and not 1 <= self.max_materials <= 127:
            raise ValueError(f"--max-materials must lie in 1 .. 127, got {self.max_materials}")
        if (self.max_u is not None and self.max_u < 0) or (self.max_v is not None and self.max_v < 0):
            raise ValueError(f"max_u and max_v (--max-u, --max-v) must be >= 0, got {self.max_u}, {self.max_v}")

    def _check_ranges(self):
        if self.normal_sd is not None and not (math.isfinite(self.normal_sd) and 0.0 < self.normal_sd < 45.0):
            raise ValueError(f"--normal-sd is in degrees, in (0, 45), got {self.normal_sd}")
        if self.anneal is not None and not 0.0 <= self.anneal <= 1.0:
            raise ValueError(f"anneal is the fraction of the burn-in run tempered, in [0, 1], got {self.anneal}")
        if self.max_view_angle is not None and not (math.isfinite(self.max_view_angle)
                                                    and 0.0 < self.max_view_angle <= 90.0):
            raise ValueError(f"--max-view-angle is in degrees, in (0, 90], got {self.max_view_angle}")
        if self.light_field is not None and not 0 <= self.light_field <= 4:
            raise ValueError(f"--light-field is a polynomial's degree, 0 (one gain per light) to 4, got "
                             f"{self.light_field}")
        if self.noise_floor is not None and not (math.isfinite(self.noise_floor) and self.noise_floor > 0):
            raise ValueError(f"noise floor (--noise-floor) must be a positive number, got {self.noise_floor}")
        if self.potts_beta is not None and not (math.isfinite(self.potts_beta) and self.potts_beta >= 0):
            raise ValueError(f"Potts strength (--potts-beta) must be a number >= 0, got {self.potts_beta}")
        if self.potts_rho is not None and not self.potts_rho > 0:
            raise ValueError(f"Potts factor per material (--potts-rho) must be > 0, got {self.potts_rho}")

    @property
    def resolved(self) -> bool:
        """Whether every field is filled (:func:`rjfit.pipeline.resolve.resolve_options`)."""
        return bool(self.sources)

    def source(self, name: str) -> str | None:
        """Where field ``name``'s value came from once resolved ('given', 'preset', 'data', 'default'), else None."""
        return dict(self.sources).get(name)

    def given(self) -> dict:
        """The options given (not None before resolution; those whose source is 'given' after it)."""
        if self.resolved:
            return {name: getattr(self, name) for name, source in self.sources if source == GIVEN}
        return {f.name: getattr(self, f.name) for f in fields(self)
                if f.name != "sources" and getattr(self, f.name) is not None}

    @classmethod
    def default(cls, name: str):
        """The value field ``name`` takes when neither it is given nor a preset or the data sets it."""
        return next(f.metadata["default"] for f in fields(cls) if f.name == name)

    @classmethod
    def cli(cls, name: str) -> CliSpec | None:
        """The command-line spec of field ``name`` (None for options the command line does not offer)."""
        return next(f.metadata.get("cli") for f in fields(cls) if f.name == name)

    @classmethod
    def cli_fields(cls):
        """``(name, default, CliSpec)`` of every option the command line offers, in declaration order."""
        return [(f.name, f.metadata["default"], f.metadata["cli"]) for f in fields(cls) if "cli" in f.metadata]

    @classmethod
    def split(cls, keywords: dict) -> tuple[dict, dict]:
        """``keywords`` split into (those that are fit options, the rest)."""
        names = {f.name for f in fields(cls)}
        return ({k: v for k, v in keywords.items() if k in names},
                {k: v for k, v in keywords.items() if k not in names})

    @classmethod
    def build(cls, options: "FitOptions | None" = None, **changes) -> "FitOptions":
        """``options`` (default: none given) with ``changes``; what the Python API's keyword arguments make."""
        options = options if options is not None else cls()
        return options.replace(**changes) if changes else options

    def replace(self, **changes) -> "FitOptions":
        """The options given, with ``changes`` (checked like the original): not resolved, so that what was
        not given is filled again (a preset given later still sets it)."""
        return FitOptions(**{**self.given(), **changes})

    def to_json(self) -> dict:
        """Every option as JSON values, and ``sources`` ({name: source}) where resolved (``summary.json``
        "fit_options": what `rjfit refine` fits again with)."""
        record = {}
        for f in fields(self):
            value = getattr(self, f.name)
            record[f.name] = (str(value) if isinstance(value, Path) else dict(value) if f.name == "sources"
                              else list(value) if isinstance(value, tuple) else value)
        return record

    @classmethod
    def from_json(cls, record: dict, region_reads: dict | None = None) -> "FitOptions":
        """The options given to the fit :meth:`to_json` recorded (names it does not know are ignored: a newer
        rjfit's). A record without sources (an rjfit before 2026-11-28) gives its region model, its preset and
        every value that differs from its plain default and that its models read: its noise model's
        (:data:`NOISE_OPTIONS`) and, with ``region_reads`` ({model name: the options it reads}, each
        ``RegionFit.reads``, which this module cannot import), its region model's.

        Raises
        ------
        ValueError
            If a recorded option is out of range (as the constructor).
        """
        names = {f.name for f in fields(cls)} - {"sources"}
        known = {k: (tuple(v) if isinstance(v, list) else v) for k, v in record.items() if k in names}
        sources = record.get("sources")
        if isinstance(sources, dict) and sources:       # resolved: what was given
            return cls(**{k: v for k, v in known.items() if sources.get(k) == GIVEN})
        if isinstance(sources, dict):                   # not resolved: every value was given
            return cls(**{k: v for k, v in known.items() if v is not None})
        return cls(**{k: v for k, v in known.items()
                      if k in ("regions", "preset") or (v is not None and v != cls.default(k)
                                                        and _read_by(k, known, region_reads or {}))})


def _read_by(name: str, values: dict, region_reads: dict) -> bool:
    """Whether the region model, noise model and sampler of ``values`` read option ``name`` (``region_reads``: the
    options each region model reads; :data:`CHOICE_OPTIONS`)."""
    regions = values.get("regions") or FitOptions.default("regions")
    modelled = set().union(*region_reads.values())
    if name in modelled and name not in region_reads.get(regions, ()):
        return False
    for field_name, table in CHOICE_OPTIONS:
        chosen = values.get(field_name) or FitOptions.default(field_name)
        if name in set().union(*table.values()) and name not in table.get(chosen, ()):
            return False
    return True
