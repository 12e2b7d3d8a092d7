"""Every option of a fit, declared once: :class:`FitOptions`.

A field holds its default, its check and, for options the command line offers, its flag and
help text (:func:`cli_option`): ``rjfit fit`` builds its click options from these fields, the
Python API (:func:`rjfit.pipeline.fit.fit`, :func:`~rjfit.pipeline.fit.fit_datasets`) takes
the same names as keyword arguments, and the summary records the options it ran with. Adding
an option is one field here, plus the code that uses it.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field, fields
from pathlib import Path

from rjfit.data.formats import CHANNELS, COLOUR
from rjfit.data.noise import DEFAULT_FLOOR, NOISE_MODELS
from rjfit.data.observations import RIM_COS
from rjfit.diagnose.effects import EFFECTS
from rjfit.sampler.priors import PRESETS
from rjfit.pipeline.regions import REGION_FITS

__all__ = ["FitOptions", "CliSpec", "cli_option", "EACH_CHANNEL", "FIT_CHANNELS"]

EACH_CHANNEL = ("R", "G", "B")                 # what ``channel="each"`` fits, one fit per channel
FIT_CHANNELS = CHANNELS + ("each", COLOUR)


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


def cli_option(default, flag: str, help: str, kind: str, **spec):
    """A dataclass field with its command-line flag and help (``metadata["cli"]``)."""
    return field(default=default, metadata={"cli": CliSpec(flag=flag, help=help, kind=kind, **spec)})


def _effect_names(value) -> tuple:
    """``effects`` as a tuple of library names: from 'a,b' (the command line) or a sequence."""
    names = [n.strip() for n in value.split(",")] if isinstance(value, str) else [str(n) for n in value]
    names = tuple(dict.fromkeys(n for n in names if n))
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown effect(s) {', '.join(unknown)} (--effects): choose from {', '.join(sorted(EFFECTS))}")
    return names


POWER_RULES = ("auto", "area")
#: degrees: the rim's edge, arccos(RIM_COS) = 72.5 (rjfit.data.observations.RIM_COS)
RIM_VIEW_ANGLE = round(math.degrees(math.acos(RIM_COS)), 2)
#: What ``--preset measured`` sets, where an option is not given (docs/measured-data.md); the Potts beta
#: and rho follow from the data set's mask (rjfit.pipeline.fit_dataset.ghost_material_prior).
MEASURED_PRESET = {"noise": "normals", "likelihood_power": "auto", "anneal": 0.0, "calibrate": True,
                   "max_view_angle": RIM_VIEW_ANGLE, "edge_power": "auto"}
#: The value of an option whose field default is None ("not given") when no preset sets it. A given value,
#: even one equal to these, is kept under a preset (``--preset measured --noise constant`` fits constant noise).
#: The prior odds of each further material, with and without the preset: 1:100, so that one takes half the
#: posterior only with a decisive Bayes factor (Jeffreys). At 1:1 (plain, until 2026-11-27) materials of one
#: pixel whose own parameters fit its noise held 15 to 21 % of two of four rendered layouts' posteriors; at 1:20
#: (the preset) those of outlier pixels held 2 to 23 % of the one-material stacks' (docs/materials.md,
#: docs/measured-data.md).
FURTHER_MATERIAL_ODDS = 0.01
#: The Potts prior's factor per material without the preset (the preset's rule: rjfit.pipeline.fit_dataset).
PLAIN_POTTS_RHO = FURTHER_MATERIAL_ODDS
PLAIN_DEFAULTS = {"noise": "constant", "likelihood_power": 1.0, "potts_rho": PLAIN_POTTS_RHO, "max_view_angle": None,
                  "edge_power": 0.0}


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


@dataclass(frozen=True)
class FitOptions:
    """The options of one fit (or of each fit of a batch). All are checked when it is built.

    Raises
    ------
    ValueError
        If an option is out of range, naming its command-line flag: ``burn_in`` not in [0, 1),
        ``n_chains < 1``, ``iterations < 10``, an unknown ``prior``, ``noise``, ``channel``,
        ``sampler``, ``split_map`` or ``cp_prior``, a ``likelihood_power`` that is neither
        'auto' nor in (0, 1], ``anneal`` not in [0, 1], ``noise_floor`` not positive,
        ``max_u`` / ``max_v`` negative, an effect the library does not know,
        ``effect_every`` below 1, or a ``labels`` map without ``regions='fixed'``.
    """

    n_chains: int = cli_option(4, "--chains", "Chains from dispersed starts.", "int", low=1)
    iterations: int = cli_option(4000, "--iterations", "Iterations per chain.", "int", low=10)
    burn_in: float | None = cli_option(
        None, "--burn-in", "Discarded fraction (default: 0.5 for synthetic data, 0.2 for measured, as in the paper).",
        "float", show_default=False)
    regions: str = cli_option(
        "changepoints", "--regions",
        "Region model: the paper's change points (changepoints), free-form materials (materials): a material "
        "label per pixel under a Potts prior, K materials unknown, one BRDF per material shared by all its pixels, "
        "connected or not; or your own label map held fixed (fixed, with --labels).", "choice",
        choices=tuple(REGION_FITS))
    labels: Path | None = cli_option(
        None, "--labels",
        "Label map of --regions fixed: an integer label per pixel of the images (.npy, .exr or a one-channel image; "
        "negative: no label); each label's BRDF posterior is sampled, nothing else.", "path", show_default=False)
    max_materials: int = cli_option(8, "--max-materials",
                                    "Most materials (--regions materials); the summary warns when the posterior "
                                    "puts mass on it.", "int", low=1)
    potts_beta: float = cli_option(3.0, "--potts-beta",
                                   "Potts prior strength per pair of neighbouring pixels of different materials "
                                   "(--regions materials). Keep it above log(1 + sqrt(--max-materials)), the "
                                   "Potts model's critical coupling (1.34 for 8): below it the prior favours "
                                   "materials scattered pixel by pixel; 3 is the smallest of 1, 2, 3 that kept "
                                   "extra materials of one or two pixels off four rendered layouts "
                                   "(docs/materials.md).", "float")
    potts_rho: float | None = cli_option(
        None, "--potts-rho",
        "Prior factor per material (--regions materials): pi(S) ~ rho^K exp(-beta B). Default 0.01: prior odds "
        "1:100 for each further material, which then needs a decisive Bayes factor; --preset measured sets beta and "
        "rho by a rule on the mask unless --potts-rho is given (docs/measured-data.md).", "float", show_default=False)
    edge_power: float | str | None = cli_option(
        None, "--edge-power",
        "Power of the edge term in the target (--regions materials, one channel, no effects): a boundary between "
        "two materials costs what their step misfits the data's differences across it (pixels 3 px apart) beyond "
        "either material alone (docs/materials.md, 'The edge term'). A number >= 0, or 'auto' (the coarsening rule "
        "on those differences). Default 0 (none); --preset measured sets auto, and leaves it out of joint colour "
        "fits and fits with effects.", "power", show_default=False)
    preset: str = cli_option(
        "none", "--preset",
        "Defaults for a kind of data: none (the options as given); measured: for measured stacks (real normals, "
        "unknown response or intensities), sets --noise normals and --likelihood-power auto where they are left at "
        "their defaults, no annealed warm-up, the rim left out (--max-view-angle 72.5), with --regions materials the Potts beta and rho by a rule on the mask, "
        "and calibrates (mask parts under 5 px left out; an unknown camera response and per-light gains "
        "estimated before the fit and applied to the images), as measured in docs/measured-data.md.", "choice",
        choices=("none", "measured"))
    calibrate: bool = False
    # half the material model's cluster seeds drawn per material (first under --preset measured, now every
    # material fit's: one-pixel leftovers die within tens of iterations; docs/materials.md)
    cluster_material_seed: float = 0.5
    # the material model's segment moves per iteration (data-driven regions moved or born whole;
    # rjfit/sampler/moves/segment_move.py); 0 for the comparison in docs/measured-data.md
    segment_moves: int = 2
    max_u: int = cli_option(3, "--max-u", "Most u change-point vectors.", "int", low=0)
    max_v: int = cli_option(3, "--max-v", "Most v change-point vectors.", "int", low=0)
    sampler: str = cli_option("adaptive", "--sampler",
                              "Within-model moves: adaptive blocks (default) or the paper's component-wise MH.",
                              "choice", choices=("adaptive", "paper"))
    prior: str = cli_option("default", "--prior", "Prior preset (paper: Table 1 synthetic, Table 3 real).",
                            "choice", choices=PRESETS)
    split_map: str = cli_option(
        "conditional", "--split-map",
        "Parameters of regions born by a split: drawn from a data-driven proposal (conditional), or a bijective "
        "map: mean (|det| 2) or the paper's eq. 10 (|det| 3), Jacobian included.",
        "choice", choices=("conditional", "mean", "paper"))
    cp_prior: str = cli_option("smooth", "--cp-prior",
                               "Change-point prior: random walk along the vector (smooth) or independent uniform "
                               "per row.", "choice", choices=("smooth", "paper"))
    drop_jacobian: bool = cli_option(False, "--drop-jacobian",
                                     "Reproduce the paper's acceptance ratio without the split/merge Jacobian "
                                     "(wrong; for study).", "flag")
    jump_prob: float = 0.2
    channel: str = cli_option(
        "mean", "--channel",
        "Colour channel fitted (luminance: CIE Y, sRGB primaries); each: R, G and B fitted separately, into "
        "OUT/R, OUT/G and OUT/B (OUT/NAME/R, ... for several data sets); rgb: R, G and B fitted jointly (one "
        "segmentation, one lobe exponent per material, per-channel amplitudes and noise; --regions materials).", "choice", choices=FIT_CHANNELS)
    likelihood_power: float | str | None = cli_option(
        None, "--likelihood-power",
        "zeta in (0, 1] of the coarsened posterior (likelihood ** zeta, Miller and Dunson 2019): each observation "
        "counts as zeta observations, so a BRDF misfit shared by neighbouring pixels of measured data does not split "
        "a uniform material into regions. 'auto': zeta = ((1-rho)/(1+rho))^2 from the lag-1 spatial correlation rho "
        "of per-pixel-fit residuals (about 1 for white noise). 'area': zeta = 1 / (the residuals' spatial "
        "autocorrelation summed over lags within +-40 px: an effective number of independent observations; residuals "
        "of 5 x 5 pixel tile fits, standardised by the noise model's scales). 1 (the default; --preset measured: "
        "auto): the plain posterior.", "power", show_default=False)
    noise: str | None = cli_option(
        None, "--noise",
        "Noise model (default constant; --preset measured: normals) y_i ~ N(mu_i, sigma_r^2 s_i^2), s_i known per observation: constant: s_i = 1 (homoscedastic per "
        "region, the paper's); shot: s_i^2 = (m_i + c) / ybar (variance grows with the signal: photon plus read "
        "noise); relative: s_i = (m_i + c) / ybar (sd grows with the signal: a multiplicative error). m_i: the "
        "prediction of a separate Lambert + Blinn fit of each pixel; ybar: the mean observed value; c = NOISE_FLOOR * "
        "ybar. normals: s_i^2 = 1 + k g_i^2, the normals' error as noise, g_i = |d mu_i / d n| of a Lambert + Blinn "
        "fit of each 5 x 5 pixel tile, k by maximum likelihood (docs/measured-data.md). footprint: s_i^2 = 1 + k g_i^2 + "
        "t f_i^2, normals plus a pixel's footprint, f_i^2 = |grad_x y_i|^2 / 12 of the observed image (the limb of a "
        "sphere), k and t by maximum likelihood (docs/measured-data.md). Weighted least squares: the "
        "sampler is unchanged. A model the noise does not follow splits regions: keep constant unless the noise is "
        "known to grow with the signal or the normals are measured.", "choice", choices=NOISE_MODELS,
        show_default=False)
    max_view_angle: float | None = cli_option(
        None, "--max-view-angle",
        "Degrees: observations of pixels seen further than this from their normal (the rim) are left out; their "
        "labels follow their neighbours'. Default: 90 (every view kept), and --preset measured sets 72.5 (<v.n> < "
        "0.3), where measured normals' error, a pixel's footprint and pixels partly background change the radiance "
        "most (docs/measured-data.md); give 90 to keep every view under the preset.", "float", show_default=False)
    noise_floor: float = cli_option(
        DEFAULT_FLOOR, "--noise-floor",
        "c / ybar of the shot and relative noise models: the floor (read noise) added to the signal, as a fraction "
        "of the mean observed value. Unused for --noise constant.", "float")
    effects: tuple = cli_option(
        (), "--effects",
        "Effects sampled jointly with the segmentation and the region BRDFs, comma-separated names of the criticism's "
        "library (ambient, camera_gamma, camera_srgb, cast_shadows, fresnel, interreflection, light_calibration, "
        "masking), each with the library's priors; see docs/sampler.md. Interreflection needs --effects-from. Either "
        "region model; a single channel (not --channel rgb).",
        "text", show_default=False)
    effects_from: Path | None = cli_option(
        None, "--effects-from",
        "A diagnosis folder (rjfit diagnose --out): the effects it named are sampled too; interreflection's Mitsuba "
        "feature is rendered on the diagnosed fit's MAP segmentation at the diagnosis' final-model materials.", "dir",
        show_default=False)
    effect_every: int = cli_option(1, "--effect-every", "Iterations between the effects' moves (one move per effect).",
                                   "int", low=1)
    anneal: float = 0.5
    cp_thin: int = 10
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
    processes: int | None = None
    figures: bool = True
    progress: bool = True
    # the options of PLAIN_DEFAULTS that were not given, filled by the preset or the plain default: a copy
    # (replace) fills them again, so that a preset given later still sets them
    unset: tuple = ()

    def __post_init__(self):
        if self.burn_in is not None and not 0.0 <= self.burn_in < 1.0:
            raise ValueError(f"burn_in (--burn-in) is a fraction in [0, 1), got {self.burn_in}")
        if self.n_chains < 1 or self.iterations < 10:
            raise ValueError(f"need n_chains >= 1 (--chains) and iterations >= 10 (--iterations), got "
                             f"{self.n_chains}, {self.iterations}")
        self._apply_preset()
        for name, what in (("preset", "preset"), ("regions", "region model"), ("prior", "prior"), ("noise", "noise model"),
                           ("channel", "channel"),
                           ("sampler", "sampler"), ("split_map", "split map"), ("cp_prior", "change-point prior")):
            spec = self.cli(name)
            if getattr(self, name) not in spec.choices:
                raise ValueError(f"unknown {what} {getattr(self, name)!r} ({spec.flag}): choose one of "
                                 f"{', '.join(spec.choices)}")
        object.__setattr__(self, "likelihood_power", _likelihood_power_value(self.likelihood_power))
        object.__setattr__(self, "effects", _effect_names(self.effects))
        if self.effects_from is not None:
            object.__setattr__(self, "effects_from", Path(self.effects_from))
        if self.labels is not None:
            if self.regions != "fixed":
                raise ValueError("--labels is the label map of --regions fixed: give --regions fixed, or leave it out")
            object.__setattr__(self, "labels", Path(self.labels))
        if self.effect_every < 1:
            raise ValueError(f"effect_every (--effect-every) must be >= 1, got {self.effect_every}")
        if not 0.0 <= self.anneal <= 1.0:
            raise ValueError(f"anneal is the fraction of the burn-in run tempered, in [0, 1], got {self.anneal}")
        if self.max_view_angle is not None and not (math.isfinite(self.max_view_angle)
                                                    and 0.0 < self.max_view_angle <= 90.0):
            raise ValueError(f"--max-view-angle is in degrees, in (0, 90], got {self.max_view_angle}")
        if not (math.isfinite(self.noise_floor) and self.noise_floor > 0):
            raise ValueError(f"noise floor (--noise-floor) must be a positive number, got {self.noise_floor}")
        if not (math.isfinite(self.potts_beta) and self.potts_beta >= 0 and self.potts_rho > 0):
            raise ValueError(f"Potts strength (--potts-beta) must be a number >= 0 and rho > 0, got "
                             f"{self.potts_beta}, {self.potts_rho}")
        if self.channel == COLOUR and (self.effects or self.effects_from is not None):
            # the effects' features and the criticism are of one channel (a colour fit is diagnosed on its mean)
            raise ValueError("--effects and --effects-from are for single-channel fits, not yet --channel rgb: fit "
                             "one channel (--channel mean) with the effects")
        if self.channel == COLOUR and self.likelihood_power == "area":
            # its summed autocorrelation would pool a pixel's channels as one channel's observations
            raise ValueError("--likelihood-power area measures one channel: not yet with --channel rgb; use "
                             "--likelihood-power auto (what --preset measured sets) or fit one channel (--channel mean)")
        if self.channel == COLOUR and (self.regions != "materials" or self.sampler != "adaptive"):
            raise ValueError("--channel rgb (a joint colour fit) works with --regions materials and the adaptive "
                             "sampler only (the change-point model's passes see one channel): use --regions materials, "
                             "or fit one channel (--channel mean, R, G, B or each)")
        self._check_edge_power()
        if not 1 <= self.max_materials <= 127:
            raise ValueError(f"--max-materials must lie in 1 .. 127, got {self.max_materials}")
        if self.max_u < 0 or self.max_v < 0:
            raise ValueError(f"max_u and max_v (--max-u, --max-v) must be >= 0, got {self.max_u}, {self.max_v}")

    def _check_edge_power(self):
        """The edge term reads one channel's plain prediction: a preset's leaves it out elsewhere, a given one fails."""
        if self.edge_power != "auto":
            try:
                power = float(self.edge_power)
            except (TypeError, ValueError):
                power = math.nan
            if not (math.isfinite(power) and power >= 0):
                raise ValueError(f"edge power (--edge-power) must be a number >= 0 or 'auto', got {self.edge_power!r}")
            object.__setattr__(self, "edge_power", power)
        other = (self.regions != "materials" or self.channel == COLOUR or bool(self.effects)
                 or self.effects_from is not None or self.sampler != "adaptive")
        if (self.edge_power == "auto" or self.edge_power > 0) and other:
            if "edge_power" in self.unset:
                object.__setattr__(self, "edge_power", 0.0)
            else:
                raise ValueError("--edge-power works with --regions materials, one channel, no effects and the "
                                 "adaptive sampler: give --edge-power 0 or fit one channel without effects")

    def _apply_preset(self):
        """Fill the options not given: the preset's value, else the plain default (:data:`PLAIN_DEFAULTS`)."""
        measured = self.preset == "measured"
        unset = set(self.unset) | {name for name in PLAIN_DEFAULTS if getattr(self, name) is None}
        for name in PLAIN_DEFAULTS:
            if name in unset:
                value = MEASURED_PRESET.get(name, PLAIN_DEFAULTS[name]) if measured else PLAIN_DEFAULTS[name]
                object.__setattr__(self, name, value)
        for name, value in MEASURED_PRESET.items():     # options the command line does not offer
            if measured and name not in PLAIN_DEFAULTS and getattr(self, name) == FitOptions.__dataclass_fields__[
                    name].default:
                object.__setattr__(self, name, value)
        object.__setattr__(self, "unset", tuple(sorted(unset)))

    @property
    def potts_rule(self) -> bool:
        """Whether --preset measured's mask rule chooses the Potts beta and rho (no --potts-rho given)."""
        return self.preset == "measured" and self.regions == "materials" and "potts_rho" in self.unset

    @classmethod
    def cli(cls, name: str) -> CliSpec | None:
        """The command-line spec of field ``name`` (None for options the command line does not offer)."""
        return next(f.metadata.get("cli") for f in fields(cls) if f.name == name)

    @classmethod
    def cli_fields(cls):
        """``(name, default, CliSpec)`` of every option the command line offers, in declaration order."""
        return [(f.name, f.default, f.metadata["cli"]) for f in fields(cls) if "cli" in f.metadata]

    @classmethod
    def split(cls, keywords: dict) -> tuple[dict, dict]:
        """``keywords`` split into (those that are fit options, the rest)."""
        names = {f.name for f in fields(cls)}
        return ({k: v for k, v in keywords.items() if k in names},
                {k: v for k, v in keywords.items() if k not in names})

    @classmethod
    def build(cls, options: "FitOptions | None" = None, **changes) -> "FitOptions":
        """``options`` (default: every default) with ``changes``; what the Python API's keyword arguments make."""
        options = options if options is not None else cls()
        return options.replace(**changes) if changes else options

    def replace(self, **changes) -> "FitOptions":
        """A copy with ``changes`` (checked like the original); the options not given stay so (see ``unset``)."""
        refill = {name: None for name in self.unset if name not in changes}
        unset = tuple(name for name in self.unset if name not in changes)
        return dataclasses.replace(self, **refill, **changes, unset=unset)

    def to_json(self) -> dict:
        """Every option as JSON values (``summary.json`` "fit_options": what `rjfit refine` fits again with)."""
        record = {}
        for f in fields(self):
            value = getattr(self, f.name)
            record[f.name] = (str(value) if isinstance(value, Path) else list(value) if isinstance(value, tuple)
                              else value)
        return record

    @classmethod
    def from_json(cls, record: dict) -> "FitOptions":
        """The options :meth:`to_json` recorded (names it does not know are ignored: a newer rjfit's).

        Raises
        ------
        ValueError
            If a recorded option is out of range (as the constructor).
        """
        names = {f.name for f in fields(cls)}
        known = {k: (tuple(v) if isinstance(v, list) else v) for k, v in record.items() if k in names}
        return cls(**known)

    def burn_in_for(self, measured: bool) -> float:
        """The burn-in fraction: the option, or the paper's default for the data's kind (0.2 measured, 0.5 synthetic)."""
        if self.burn_in is not None:
            return self.burn_in
        return 0.2 if measured else 0.5
