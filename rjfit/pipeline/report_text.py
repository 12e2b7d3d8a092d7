"""What ``rjfit report`` says in words: every setting that shaped a fit, and each result with what it means.

A fit's ``summary.json`` keeps its settings and results under JSON keys (``map_model.n_u``,
``rhat_reason``); a reader of the report needs the setting's name, its value with the rule that
chose it, and for a result what the number measures and when it is good. :func:`fit_settings`
gives the former as ``(setting, value in words)`` rows, :func:`result_rows` the latter as
``(quantity, value, meaning)`` rows; :func:`figure_caption` says what a fit's figure shows.
Every function reads the summary defensively: a summary of an older rjfit lacks some entries,
and a row whose entry is missing is left out.
"""
from __future__ import annotations

from rjfit.data.light_field import field_extent
from rjfit.pipeline.regions import region_fit_of
from rjfit.pipeline.report_numbers import finite as _finite
from rjfit.pipeline.report_numbers import number as _number
from rjfit.pipeline.report_numbers import probability as _probability

__all__ = ["fit_settings", "result_rows", "figure_caption", "truth_note", "FIGURE_CAPTIONS"]

_CHANNELS = {"mean": "the mean of R, G and B", "luminance": "luminance (CIE Y, sRGB primaries)", "R": "red",
             "G": "green", "B": "blue", "rgb": "R, G and B fitted jointly (one segmentation, per-channel amplitudes)"}

#: what each figure of a fit folder shows, by its file name (stem)
FIGURE_CAPTIONS = {
    "materials": "MAP material of every pixel (one colour per material; white: off the object or left out).",
    "labels": "The label map held fixed (--regions fixed): one colour per label (white: no label).",
    "materials_histogram": "Posterior probability of each number of materials K (pooled over the chains, after "
                           "burn-in).",
    "materials_extra": "Each pixel's share of the kept label snapshots that hold it in a material beyond the "
                       "segmentation's number (cyan: the segmentation's outlines). Small, dark patches are the other "
                       "draws' specks: look at the images there (a spot, a shadow, a speck of dust).",
    "model_histogram": "Posterior probability of each change-point model (n_u, n_v) (pooled over the chains, after "
                       "burn-in).",
    "reflectance": "Posterior mean radiance, observed radiance and their absolute difference, each averaged over the "
                   "lights, beside the MAP labels. Equal colours in the first two panels mean equal radiance.",
    "traces": "Parameter traces of the MAP model's regions, one colour per chain; the dashed line ends the burn-in.",
    "changepoints": "Change points of the MAP model: their median and 95 % band, and 2-D histograms of their "
                    "positions.",
    "valid_images": "Number of images that observe each pixel (valid observations), beside a map per rule that left "
                    "observations out.",
}


def _region_model(summary: dict, options: dict) -> str | None:
    return region_fit_of(summary).describe(summary, options) or None


def _preset(options: dict) -> str:
    if options.get("preset") == "measured":
        return ("measured: the defaults for measured stacks (normals noise model, likelihood power auto, rim left "
                "out, calibration, no annealed warm-up; with materials the Potts prior by a rule on the mask and the "
                "edge term)")
    return "none: the options as given"


def _rim(summary: dict) -> str:
    angle = summary.get("max_view_angle")
    if not _finite(angle) or angle >= 90:
        return "90 deg: every view kept"
    rim = summary.get("rim_pixels")
    return (f"{angle:g} deg: observations seen further than this from the surface normal are left out"
            + (f" ({rim:,} pixels have none left; their labels follow their neighbours')" if isinstance(rim, int)
               else ""))


def _calibration(summary: dict) -> str:
    record = summary.get("calibration")
    if not isinstance(record, dict):
        return "none: the images as loaded"
    parts = []
    response = record.get("response")
    if isinstance(response, dict) and _finite(response.get("kappa")):
        interval = response.get("kappa_interval")
        parts.append(f"camera response estimated, kappa {response['kappa']:.3g}"
                     + (f" (95 % {interval[0]:.3g} to {interval[1]:.3g})" if isinstance(interval, list) else "")
                     + ": the images raised to kappa")
    else:
        parts.append("camera response: the data set's own (linear), not estimated")
    gains = (record.get("light_gains") or {}).get("gains") if isinstance(record.get("light_gains"), dict) else None
    field = record["light_gains"].get("field") if isinstance(gains, list) else None
    if isinstance(gains, list) and gains:
        parts.append(f"per-light gains estimated for {len(gains)} lights ({min(gains):.3g} to {max(gains):.3g}) and "
                     f"divided out" + (f", each a degree-{field['degree']} field over the image ("
                                       f"{field_extent(field)[0]:.2f} to {field_extent(field)[1]:.2f}"
                                       f" of its mean)" if isinstance(field, dict) else ""))
    else:
        parts.append("light gains: not estimated (the intensities as declared)")
    isolated = (record.get("isolated_pixels") or {}).get("pixels_dropped")
    if isinstance(isolated, int):
        parts.append(f"{isolated} isolated mask pixel(s) left out")
    return "; ".join(parts)


def _noise(summary: dict) -> str | None:
    noise = summary.get("noise")
    if not isinstance(noise, dict) or not noise.get("model"):
        return None
    text = {"constant": "constant: one noise variance per region (the paper's)"}.get(noise["model"], noise["model"])
    if noise.get("formula"):
        text += f": {noise['formula']}"
    error = noise.get("normal_error")
    if isinstance(error, dict) and _finite(error.get("sigma_n_deg")):
        text += f"; the normals' error estimated at {error['sigma_n_deg']:.3g} deg (sd)"
    return text


def _power(summary: dict, options: dict) -> str | None:
    power = summary.get("likelihood_power")
    if not _finite(power):
        return None
    rule = options.get("likelihood_power")
    suggestion = summary.get("likelihood_power_suggestion") or {}
    if rule == "auto" and _finite(suggestion.get("rho")):
        how = (f"auto: ((1 - rho) / (1 + rho))^2 from the lag-1 spatial correlation rho = {suggestion['rho']:.3g} of "
               f"per-pixel fits' residuals")
    elif rule == "area":
        how = "area: one over the residuals' spatial autocorrelation summed within +-40 px"
    else:
        how = "as given" if power != 1 else "the plain posterior"
    return f"{power:.4g} ({how}); each observation counts as {power:.3g} of one"


def _model_misfit(summary: dict) -> str | None:
    misfit = summary.get("model_misfit")
    if not isinstance(misfit, dict) or not _finite(misfit.get("rho")):
        return None
    return (f"neighbours' residuals correlate at rho = {misfit['rho']:.3g} (lag 1, under one light), which would "
            f"imply a power of {misfit['implied_power']:.3g}; 0 and 1 when the model explains all but the noise")


def _effects(summary: dict) -> str:
    names = [e.get("name") for e in summary.get("effects") or [] if isinstance(e, dict)]
    return ", ".join(str(n) for n in names) + " (sampled with the regions)" if names else "none"


def _run(summary: dict, options: dict) -> list:
    rows = []
    if isinstance(summary.get("n_chains"), int) and isinstance(summary.get("iterations"), int):
        rows.append(("chains x iterations", f"{summary['n_chains']} chains x {summary['iterations']:,} iterations"))
    burn = summary.get("burn_in")
    if isinstance(burn, int) and isinstance(summary.get("iterations"), int) and summary["iterations"]:
        anneal = summary.get("anneal_iterations")
        share = 100 * burn / summary["iterations"]
        rows.append(("burn-in", f"the first {burn:,} iterations of each chain ({share:.0f} %) discarded"
                     + (f", the first {anneal:,} of them annealed" if anneal else "")))
    rows.append(("seed", summary.get("seed")))
    rows.append(("prior", summary.get("prior", {}).get("name") if isinstance(summary.get("prior"), dict) else None))
    rows.append(("sampler", {"adaptive": "adaptive block moves within a model", "paper": "the paper's component-wise "
                             "Metropolis-Hastings"}.get(summary.get("sampler"), summary.get("sampler"))))
    return rows


def fit_settings(summary: dict) -> list:
    """``(setting, value in words)`` for every setting that shaped the fit, those the summary lacks left out."""
    options = summary.get("fit_options") if isinstance(summary.get("fit_options"), dict) else {}
    crop = summary.get("crop")
    validation = summary.get("validation") if isinstance(summary.get("validation"), dict) else {}
    rows = [("data set", summary.get("dataset")),
            ("channel", _CHANNELS.get(summary.get("channel"), summary.get("channel"))),
            ("region model", _region_model(summary, options)),
            ("preset", _preset(options) if options else None),
            *region_fit_of(summary).settings_rows(summary, options),
            # what a summary without its options (an older rjfit's) leaves unsaid is not guessed
            ("rim (max. view angle)", _rim(summary) if options else None),
            ("calibration (response, gains)", _calibration(summary) if options else None),
            ("noise model", _noise(summary)),
            ("likelihood power (zeta)", _power(summary, options)),
            ("misfit the fitted model leaves", _model_misfit(summary)),
            ("effects", _effects(summary) if options else None)]
    rows += _run(summary, options)
    rows += [("observations", f"{summary['n_observations']:,} (pixel, light) pairs"
              if isinstance(summary.get("n_observations"), int) else None),
             ("crop (first row, column of the files)", f"{crop.get('row0')}, {crop.get('col0')}"
              if isinstance(crop, dict) else None),
             ("forward-model cross-check", f"the forward model {validation['note']}" if validation.get("note")
              else ("passed" if validation.get("passed") else None)),
             ("fit id", summary.get("fit_id"))]
    return [(name, value) for name, value in rows if value is not None]


def result_rows(summary: dict) -> list:
    """``(quantity, value, what it means and when it is good)`` for the fit's headline results."""
    rows = list(region_fit_of(summary).result_rows(summary))
    if "label_accuracy" in summary:
        rows.append(("label accuracy", _probability(summary["label_accuracy"]),
                     "share of object pixels whose MAP label matches the truth after the best one-to-one matching "
                     "(rendered data only); good near 1"))
    rhat = summary.get("rhat_max")
    rows.append(("largest split R-hat", f"{rhat:.3f}" if _finite(rhat) else
                 f"not computable ({summary.get('rhat_reason') or 'no reason recorded'})",
                 "the chains' agreement on every parameter of the MAP model (Vehtari et al. 2021): good at most "
                 "1.01; above it the chains disagree and the tables mix their modes"))
    ess = summary.get("ess_min")
    rows.append(("smallest effective sample size", f"{ess:.0f}" if _finite(ess) else "not computable",
                 f"independent draws' worth in the worst parameter (bulk and tail): good at least 100 per chain "
                 f"({100 * summary['n_chains']} here)" if isinstance(summary.get("n_chains"), int) else
                 "independent draws' worth in the worst parameter: good at least 100 per chain"))
    if _finite(summary.get("seconds")):
        rows.append(("run time", f"{summary['seconds']:.0f} s", "wall time of the whole fit, chains and summary"))
    return [row for row in rows if row[1] is not None]


def truth_note(summary: dict) -> str | None:
    """The sentence that tells the exact partition's probability from the true regions' (both on rendered data)."""
    if "exact_truth_probability" not in summary or "true_regions_probability" not in summary:
        return None
    return (f"The probability of the true regions ({_number(summary['true_regions_probability'], '.3g')}) counts a "
            f"draw whose regions match the truth on at least 99 % of the object's pixels; the probability of the exact "
            f"partition ({_number(summary['exact_truth_probability'], '.3g')}) asks for every pixel. About 0.2 % of "
            f"the pixels sit at the silhouette, where a few grazing observations cannot tell two regions apart, so "
            f"the exact partition is rarely drawn even when the regions are right: read the first.")


def figure_caption(stem: str) -> str:
    """What the figure ``stem``.png of a fit folder shows (its name in words for one this module does not know)."""
    return FIGURE_CAPTIONS.get(stem, stem.replace("_", " ").capitalize() + ".")
