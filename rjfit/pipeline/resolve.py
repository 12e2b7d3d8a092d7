"""The options a fit runs with, resolved once: :func:`resolve_options`.

Every option that was not given is filled here, and only here: by the data's kind (a measured
stack's default is ``--regions materials --preset measured``), by the preset (:data:`MEASURED_PRESET`,
and the Potts rule on the mask), by the data set's declared calibration need (``{"response":
"unknown"}``: calibrated under every preset), else by the field's plain default. A given option
that the fit's region model, noise model or effects do not read is refused, naming its flag. The
result records where each value came from (``FitOptions.sources``), which the fit's summary keeps
and the command line reports (:func:`default_lines`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rjfit.data.formats import COLOUR
from rjfit.data.calibrate import LIGHT_FIELD_DEGREE
from rjfit.pipeline.options import CHOICE_OPTIONS, EFFECT_OPTIONS, GIVEN, RIM_VIEW_ANGLE, FitOptions
from rjfit.pipeline.regions import REGION_FITS
from rjfit.pipeline.regions.materials import GHOST_ODDS, GHOST_PIXELS, ghost_material_prior

__all__ = ["refuse_early", "resolve_options", "DataFacts", "MEASURED_DEFAULTS", "MEASURED_PRESET", "default_lines",
           "ghost_material_prior", "GHOST_PIXELS", "GHOST_ODDS"]

#: What a measured stack (anything `rjfit render` did not write) gets where not given: the region model that
#: says so (``RegionFit.measured_default``) and the measured preset.
MEASURED_DEFAULTS = {"regions": next(name for name, fit in REGION_FITS.items() if fit.measured_default),
                     "preset": "measured"}
#: What ``--preset measured`` sets where an option is not given (docs/options.md); beyond these, what the
#: region model's ``RegionFit.preset_values`` sets (the material model: its edge term where it applies, with its
#: measured noise and, in one channel, its local gain; the Potts beta and rho by
#: :func:`rjfit.pipeline.regions.materials.ghost_material_prior`).
MEASURED_PRESET = {"noise": "normals", "likelihood_power": "auto", "anneal": 0.0, "calibrate": True,
                   "max_view_angle": RIM_VIEW_ANGLE, "gamma_moves": 8, "iterations": 500, "light_field": LIGHT_FIELD_DEGREE}
#: the fraction of each chain discarded, by the data's kind (the paper's choices)
BURN_IN = {"measured": 0.2, "rendered": 0.5}
PRESET, DATA, DEFAULT = "preset", "data", "default"

@dataclass(frozen=True, eq=False)
class DataFacts:
    """What the options' resolution reads of the data set.

    Attributes
    ----------
    kind : str
        'measured' (anything `rjfit render` did not write) or 'rendered'.
    layout : str
        How the folder is laid out, for the printed line ('diligent', 'mesh-stack', ...).
    object_mask : ndarray or None
        The object's pixels (the Potts rule's); None: no rule.
    response_unknown : bool or None
        The data set declares an unknown camera response (``{"response": "unknown"}``): the fit
        must calibrate it. None: not read yet (:func:`refuse_early`).
    """

    kind: str = "rendered"
    layout: str = ""
    object_mask: np.ndarray | None = None
    response_unknown: bool | None = False

    @classmethod
    def of(cls, dataset) -> "DataFacts":
        """The facts of a loaded :class:`rjfit.data.dataset.Dataset`."""
        return cls(kind="measured" if dataset.meta.get("kind") == "measured" else "rendered",
                   layout=str(dataset.meta.get("layout") or ""), object_mask=dataset.object_mask,
                   response_unknown=dataset.response == "unknown")


def resolve_options(options: FitOptions, data: DataFacts | None = None) -> FitOptions:
    """Every option of ``options`` filled, with its source; the given ones checked against each other.

    Parameters
    ----------
    options : FitOptions
        The options given (an already resolved one is resolved again from what was given).
    data : DataFacts, optional
        The data set's kind, mask and calibration need (default: rendered, no mask).

    Returns
    -------
    FitOptions
        With ``sources``: per field 'given', 'data' (the data's kind or its calibration need),
        'preset' or 'default'.

    Raises
    ------
    ValueError
        In one line naming the flag: a given option the fit's region model, noise model or effects
        do not read; ``calibrate=False`` on a data set that declares an unknown response; an edge
        power where the edge term cannot apply; a joint colour fit with effects, the area power, the
        change-point model or the paper's sampler.
    """
    data = data if data is not None else DataFacts()
    values = dict(options.given())
    sources = dict.fromkeys(values, GIVEN)

    def fill(name, value, source):
        if name not in values:
            values[name], sources[name] = value, source

    for name, value in MEASURED_DEFAULTS.items():
        if data.kind == "measured":
            fill(name, value, DATA)
    _check_calibration(values, data)
    for name in ("preset", "regions", "channel", "effects", "effects_from", "sampler"):
        fill(name, FitOptions.default(name), DEFAULT)
    if values["preset"] == "measured":
        for name, value in MEASURED_PRESET.items():
            if name == "light_field" and data.response_unknown is False:
                continue            # estimated with the per-light gains, which a declared response does not get
            fill(name, value, PRESET)
        for name, value in REGION_FITS[values["regions"]].preset_values(values, data).items():
            values[name] = value           # the model's rule (the Potts prior on the mask) starts from a given value
            sources.setdefault(name, PRESET)
    if data.response_unknown:       # a declared need: applied under every preset (a given False is refused above)
        fill("calibrate", True, DATA)
    fill("burn_in", BURN_IN[data.kind], DATA if data.kind == "measured" else DEFAULT)
    for name in (f for f in FitOptions.__dataclass_fields__ if f != "sources"):
        fill(name, FitOptions.default(name), DEFAULT)
    resolved = FitOptions(**values, sources=tuple(sorted(sources.items())))
    _refuse_unread(resolved)
    _check_combinations(resolved)
    return resolved


def refuse_early(options: FitOptions, kind: str) -> None:
    """Refuse, before a data set of ``kind`` ('measured' or 'rendered') is loaded, options its fit would refuse.

    The resolution again once the data set is loaded (:func:`resolve_options`) adds its mask and
    calibration need, which only add the Potts rule and the calibration; this check makes the
    one line come before any work or progress line.

    Raises
    ------
    ValueError
        As :func:`resolve_options`.
    """
    resolve_options(options, DataFacts(kind=kind, response_unknown=None))


def _check_calibration(values: dict, data: DataFacts) -> None:
    if data.response_unknown and values.get("calibrate") is False:
        raise ValueError("the data set declares an unknown camera response ({\"response\": \"unknown\"}): its raw "
                         "codes are not radiances; the fit must calibrate it (calibrate=True, what every preset does)")
    if values.get("light_field") and (data.response_unknown is False or values.get("calibrate") is False):
        raise ValueError("--light-field is estimated with the per-light gains, which only a data set declaring an "
                         "unknown response ({\"response\": \"unknown\"}) gets: leave it out")


def _edge_term_applies(values: dict) -> bool:
    """Whether the region model of ``values`` applies the edge term under their channel, effects and sampler."""
    return REGION_FITS[values["regions"]].edge_term_applies(values)


def _refuse_unread(options: FitOptions) -> None:
    """A given option that the chosen region model, noise model, sampler or effects do not read: refused, naming it."""
    for name in options.given():
        flag = FitOptions.cli(name).flag if FitOptions.cli(name) else name
        readers = [model for model, fit in REGION_FITS.items() if name in fit.reads]
        if readers and options.regions not in readers:
            raise ValueError(f"{flag} is an option of --regions {' / '.join(readers)}, not of --regions "
                             f"{options.regions} ({_chosen_by(options, 'regions')}): leave it out")
        for field_name, table in CHOICE_OPTIONS:        # --noise, --sampler
            readers = [choice for choice, names in table.items() if name in names]
            chosen = getattr(options, field_name)
            if readers and chosen not in readers:
                by = FitOptions.cli(field_name).flag
                raise ValueError(f"{flag} is an option of {by} {' / '.join(readers)}, not of {by} {chosen} "
                                 f"({_chosen_by(options, field_name)}): leave it out")
        if name in EFFECT_OPTIONS and not options.effects and options.effects_from is None:
            raise ValueError(f"{flag} is an option of sampled effects (--effects, --effects-from), and none are "
                             f"sampled: leave it out")


def _chosen_by(options: FitOptions, name: str) -> str:
    """Why the option has its value, in words (for the refusal)."""
    return {GIVEN: "given", PRESET: f"the preset {options.preset}'s", DATA: "the measured data's default",
            DEFAULT: "the default"}[options.source(name)]


def _check_normals(options: FitOptions) -> None:
    """Sampled normals (--normals sample) are for one channel without effects, under a noise model without the
    footprint term."""
    if options.normals != "sample":
        if options.source("normal_sd") == GIVEN:
            raise ValueError("--normal-sd is an option of --normals sample, and the normals are fixed: leave it out")
        return
    if options.effects or options.effects_from is not None:
        raise ValueError("--normals sample is for fits without effects (the effects' columns assume the given "
                         "normals): leave out --effects / --effects-from, or fit with --normals fixed")
    if options.channel == COLOUR:
        raise ValueError("--normals sample is for a single channel, not yet --channel rgb: fit one channel "
                         "(--channel mean) or give --normals fixed")
    if options.noise == "footprint":
        raise ValueError("--normals sample is not for --noise footprint (its footprint term reads the given normals' "
                         "error): use --noise normals (its normal-error estimate sets the prior) or constant")


def _check_combinations(options: FitOptions) -> None:
    _check_normals(options)
    if options.edge_power == "auto" or options.edge_power > 0:
        if not _edge_term_applies(vars(options)):
            edge = " / ".join(name for name, fit in REGION_FITS.items() if "edge_power" in fit.reads)
            raise ValueError(f"--edge-power works with --regions {edge}, no effects and the adaptive sampler: "
                             f"give --edge-power 0 or fit without effects")
    elif options.edge_gain_sd == "auto" or options.edge_gain_sd > 0:
        raise ValueError(f"--edge-gain-sd is an option of the edge term, and there is none (--edge-power 0, "
                         f"{_chosen_by(options, 'edge_power')}): leave it out or give --edge-power")
    elif options.edge_noise != "constant":
        raise ValueError(f"--edge-noise is an option of the edge term, and there is none (--edge-power 0, "
                         f"{_chosen_by(options, 'edge_power')}): leave it out or give --edge-power")
    if options.channel != COLOUR:
        return
    if options.effects or options.effects_from is not None:
        # the effects' features and the criticism are of one channel (a colour fit is diagnosed on its mean)
        raise ValueError("--effects and --effects-from are for single-channel fits, not yet --channel rgb: fit "
                         "one channel (--channel mean) with the effects")
    if options.likelihood_power == "area":
        # its summed autocorrelation would pool a pixel's channels as one channel's observations
        raise ValueError("--likelihood-power area measures one channel: not yet with --channel rgb; use "
                         "--likelihood-power auto (what --preset measured sets) or fit one channel (--channel mean)")
    joint = " / ".join(name for name, fit in REGION_FITS.items() if fit.joint_colour)
    if not REGION_FITS[options.regions].joint_colour or options.sampler != "adaptive":
        raise ValueError(f"--channel rgb (a joint colour fit) works with --regions {joint} and the adaptive "
                         f"sampler only (the other models' passes see one channel): use --regions {joint}, "
                         f"or fit one channel (--channel mean, R, G, B or each)")


_LAYOUTS = {"diligent": "a photometric-stereo folder", "mesh-stack": "a mesh stack with photographs"}


def default_lines(options: FitOptions, data: DataFacts) -> list[str]:
    """What the fit says of the options the data chose (resolved ``options``): the measured default
    and how to opt out, and a calibration applied because the data set declares it."""
    lines = []
    chosen = [name for name in MEASURED_DEFAULTS if options.source(name) == DATA]
    if chosen:
        what = " ".join(f"{FitOptions.cli(name).flag} {MEASURED_DEFAULTS[name]}" for name in chosen)
        opt_out = " or ".join({"regions": f"--regions {FitOptions.default('regions')}", "preset": "--preset none"}[n]
                              for n in chosen)
        lines.append(f"measured data ({_LAYOUTS.get(data.layout, 'not written by rjfit render')}): fitted with the "
                     f"measured default {what}; give {opt_out} to fit otherwise")
    if options.source("calibrate") == DATA:
        lines.append("the data set declares an unknown camera response (rjfit.json): the response and per-light "
                     "gains are estimated and applied before the fit under every preset")
    return lines
