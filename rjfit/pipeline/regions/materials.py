"""The material region model's part of a fit (``rjfit fit --regions materials``): its summary and files.

:func:`summarise_materials` turns the chains into the summary entries of the material model
(:data:`rjfit.pipeline.fit_folder.SUMMARY_FIELDS`): the posterior over K
(``materials_posterior``), the MAP K, per-material parameter summaries with pixel counts
(``regions``, one entry per material, after relabelling: :mod:`rjfit.posterior.materials`),
their R-hat and ESS, the cap warning, and the truth comparison of synthetic data.
:func:`write_material_files` writes what differs from a change-point fit's folder:
``chains.nc`` (:mod:`rjfit.posterior.inference_data`; posterior dims chain, draw, material, parameter: the
relabelled draws at the MAP K),
``materials.npz`` (every chain's label snapshots and K per iteration) and the figures
(``materials.png``, the MAP material map, a distinct colour per material however many;
``materials_histogram.png``; ``reflectance.png``; ``materials_extra.png`` where some kept draw holds more
materials than the segmentation). ``labels.exr`` holds the MAP material per pixel and ``maps.exr`` gains
``map_probability``, the posterior probability of that material, and ``extra_material_share`` (written by
:func:`rjfit.pipeline.fit.write_results`).
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from rjfit.data.calibrate import small_components
from rjfit.data.formats import COLOUR, COLOUR_CHANNELS
from rjfit.pipeline.fit_chains import write_chains
from rjfit.pipeline.fit_folder import save_chain_arrays
from rjfit.posterior import caveats, contrast
from rjfit.posterior import materials as mat
from rjfit.posterior import summary as post
from rjfit.pipeline.fit_power import edge_settings
from rjfit.pipeline.fit_settings import assemble
from rjfit.pipeline.options import FURTHER_MATERIAL_ODDS, FitOptions
from rjfit.pipeline.regions.base import FitResult, RegionFit, truth_summary
from rjfit.pipeline.regions.material_boundaries import add_boundary_check, edge_groups_posterior, material_boundaries
from rjfit.pipeline.regions.material_resolution import (material_resolution, resolution_sentence, resolution_size,
                                                        resolution_warning)
from rjfit.pipeline.report_numbers import finite, number, probability
from rjfit.posterior.boundaries import edge_verdict
from rjfit.posterior.resolution import RESOLUTION_WARN_PIXELS
from rjfit.sampler.regions.materials import MaterialRegions
from rjfit.sampler.regions.materials.edge_noise import MIN_WHITE
from rjfit.sampler.state import SamplerConfig

__all__ = ["MaterialFit", "summarise_materials", "edge_noise_record", "edge_noise_warnings", "material_resolution",
           "material_boundaries", "add_boundary_check", "add_contrasts", "contrast_notes",
           "edge_groups_posterior", "resolution_warning", "material_number_warnings", "write_material_files",
           "EMPTY_MATERIALS_NOTE", "resolution_size", "resolution_sentence", "ghost_material_prior", "GHOST_PIXELS",
           "GHOST_ODDS"]

EMPTY_MATERIALS_NOTE = ("no material is ever empty: every state's K materials each hold at least one pixel (the label "
                        "sweep keeps a material's last pixel, a cluster move that empties a material removes it)")


def summarise_materials(records, problem, options, burn: int, config, edges=None):
    """The material model's summary entries and results: ``(summary, MAP labels, prediction, extra)``; ``config``:
    the chains' sampler settings (the edge term's power as they took it); ``edges``: the chains' edge term where the
    caller has it (else the resolution builds its own).

    ``extra`` holds ``map_probability`` (H, W), the relabelled ``draws``
    (:class:`rjfit.posterior.materials.RelabelledDraws`) and ``extra_material_share`` (H, W: the share of the kept
    snapshots in which a pixel is in a material beyond the segmentation's number,
    :func:`rjfit.posterior.caveats.extra_materials`).
    """
    posterior = mat.materials_posterior(records, burn)
    labels, origin = mat.segmentation_estimate(records, burn)
    k = int(labels.max()) + 1
    draws = mat.relabelled_draws(records, burn, k, problem.n_channels, reference=labels)
    probability = draws.agreement(labels)
    summaries, diag = mat.material_summaries(draws, labels)
    agreements = caveats.label_agreements(labels, probability, k)
    for material, (entry, share) in enumerate(zip(summaries, agreements)):
        entry["label_agreement"] = float(share) if np.isfinite(share) else None
        if np.isfinite(share) and share < caveats.AGREEMENT_MIN:
            summarise_from_own_draws(entry, records, burn, labels == material, problem.n_channels)
    chain_posteriors = [mat.materials_posterior([r], burn) for r in records]
    extra, extra_share = caveats.extra_materials(records, burn, k)
    add_contrasts(problem, labels, summaries, extra, extra_share)
    summary = {
        "materials_posterior": posterior, "map_materials": int(next(iter(posterior))), "regions": summaries,
        "segmentation_materials": k, "segmentation": mat.SEGMENTATION,
        "segmentation_snapshot": origin,
        "material_relabelling": mat.RELABELLING, "empty_materials": EMPTY_MATERIALS_NOTE,
        "map_probability_mean": float(np.nanmean(probability)),
        "rhat_max": diag["rhat_max"], "rhat_reason": diag.get("rhat_reason"),
        "ess_min": min(diag["ess_bulk_min"], diag["ess_tail_min"]),
        "ess_bulk_min": diag["ess_bulk_min"], "ess_tail_min": diag["ess_tail_min"], "diagnostics": diag,
        "max_materials": options.max_materials, "potts_beta": options.potts_beta, "potts_rho": options.potts_rho,
        "edge_power": float(config.regions.edge_power), "edge_gain_sd": float(config.regions.edge_gain_sd),
        "edge_noise": edge_noise_record(config.regions.edge_noise), "chain_materials_posterior": chain_posteriors,
        "extra_materials": extra,
    }
    summary["warnings"] = post.convergence_warnings(diag, chain_posteriors, options.n_chains,
                                                    post.chain_log_posterior_means(records, burn))
    summary["warnings"] += caveats.label_agreement_warnings(summaries, agreements, k)
    cap = mat.cap_warning(posterior, options.max_materials)
    if cap:
        summary["warnings"].append(cap)
    summary["warnings"] += edge_noise_warnings(summary["edge_noise"])
    resolution = material_resolution(problem, summaries, labels, options, float(config.regions.edge_power),
                                     config.regions.edge_noise, None if edges is None else edges.channel_scales())
    if resolution is not None:
        summary["material_resolution"] = resolution
        if RESOLUTION_WARN_PIXELS < resolution["pixels"] < np.inf:
            summary["warnings"].append(resolution_warning(resolution))
    prediction = post.posterior_mean_prediction(records, burn, problem)
    maps = {"map_probability": probability, "draws": draws}
    if extra_share is not None:
        maps["extra_material_share"] = extra_share
    return summary, labels, prediction, maps


def summarise_from_own_draws(entry: dict, records, burn: int, mask, n_channels: int) -> None:
    """Summarise a material's parameters (``entry``, from :func:`rjfit.posterior.materials.material_summaries`)
    afresh over the kept draws of any K that hold its pixels ``mask``
    (:func:`rjfit.posterior.materials.matched_draws`), and record them in ``entry["parameters_from"]`` (None, the
    entry unchanged, where no draw holds it).

    Why: a material that few draws at the segmentation's K hold gets other pixels' parameters from the draws that
    lack it (psm-rock at seed 1: a lighter patch reported with I0 below the matrix's; docs/results/
    2026-11-29-compact-starts.md); the draws that hold it are its own.
    """
    own = mat.matched_draws(records, burn, mask, n_channels)
    chains = [c for c, theta in enumerate(own.theta) if len(theta)]
    if not chains:
        entry["parameters_from"] = None
        return
    holding = mat.RelabelledDraws([own.theta[c] for c in chains], [own.labels[c] for c in chains], own.reference)
    (fresh,), diag = mat.material_summaries(holding, own.reference)
    kept = {key: entry[key] for key in ("region", "material", "pixels", "label_agreement")}
    entry.clear()
    entry.update({**fresh, **kept})
    entry["parameters_from"] = {"draws": int(sum(len(own.theta[c]) for c in chains)), "chains": chains,
                                "match_min": mat.MATCH_MIN, "rhat_max": diag["rhat_max"],
                                "ess_bulk_min": diag["ess_bulk_min"]}


def add_contrasts(problem, labels, regions: list, extra: dict | None, extra_share) -> None:
    """Each material's intensity against its surroundings, light by light (``regions[m]["contrast_to_surroundings"]``),
    and that of the place where the extra materials lie most often (``extra["most_often"]["contrast"]``):
    :mod:`rjfit.posterior.contrast`, from the fitted observations and their Lambertian shading at the given normals
    (after calibration, the noise scales undone; a colour fit's per channel too). Nothing is added where the problem
    does not record each observation's light."""
    if problem.light is None:
        return
    scale = 1.0 if problem.noise_scale is None else problem.noise_scale
    y, shading = problem.y * scale, problem.C * scale
    n_lights, inside = int(np.max(problem.light)) + 1, np.asarray(labels) >= 0
    colour = ({} if problem.channel is None else
              {"channel": problem.channel, "channel_names": COLOUR_CHANNELS[:problem.n_channels]})
    found = contrast.material_contrasts(y, problem.light, problem.pixel, labels, n_lights, shading, **colour)
    for entry, reading in zip(regions, found):
        entry["contrast_to_surroundings"] = reading
    where = (extra or {}).get("most_often")
    if where:
        place = contrast.piece_around(extra_share, where["row"], where["column"], inside)
        where["contrast"] = contrast.piece_contrast(y, problem.light, problem.pixel, place, inside, n_lights, shading,
                                                    **colour)


def edge_noise_record(noise) -> dict | None:
    """The summary's ``edge_noise``: the measured coefficients of the edge term's noise (``noise``: the sampler's
    setting, coefficients or a word; None: one scale)."""
    if isinstance(noise, str):
        return None
    white, shading, turn = (float(c) for c in noise)
    return {"white": white, "shading": shading, "turn": turn, "floored": white <= MIN_WHITE}


def edge_noise_warnings(record) -> list:
    """The caveat of a measured noise whose white part sits at its floor (``record``: :func:`edge_noise_record`)."""
    if record is None or not record["floored"]:
        return []
    return [f"the edge term's measured noise left almost no white part: its white variance is held at its floor "
            f"{MIN_WHITE} (of the differences' robust spread squared), so no pair weighs more than "
            f"{1 / MIN_WHITE:.0f} times a typical one (--edge-noise)"]


def material_number_warnings(materials, prior) -> list:
    """The caveats of the material summaries' own numbers (:mod:`rjfit.posterior.caveats`): a material without
    a pixel in the MAP labels, a mean beyond its prior's plausible range, an interval at a bound of its prior's
    support, a pooled mean outside its own interval. A colour fit's material is checked per channel
    (``"2 (G)"``), its gamma once."""
    rows, empty = [], []
    for material in materials:
        if material.get("pixels") == 0:
            # every state's materials hold pixels, but the pooled MAP labels (each pixel's most frequent
            # relabelled material) can leave one without: it is a mode some chains hold, not a material here
            empty.append(f"material {material['material']} of the MAP number of materials holds no pixel in the MAP "
                         f"labels: the chains that hold it put it on pixels the others give to another material; read "
                         f"chain_materials_posterior, and do not read its parameters as a material's")
        if "channels" not in material:
            rows.append(material)
            continue
        for index, (name, params) in enumerate(material["channels"].items()):
            rows.append({"region": f"{material['material']} ({name})", **params,
                         **({"gamma": material["gamma"]} if index == 0 else {})})
    return (empty + caveats.prior_range_warnings(rows, prior) + caveats.support_bound_warnings(rows, prior)
            + caveats.pooled_interval_warnings(rows))


def write_material_files(staging: Path, result, records, options, attributes: dict) -> None:
    """``chains.nc``, ``materials.npz`` and (with ``options.figures``) the figures, into ``staging``; the files with
    ``attributes`` (:func:`rjfit.pipeline.fit_folder.file_attributes`)."""
    summary, draws = result.summary, result.extra["draws"]
    write_chains(staging / "chains.nc", records, result, (draws.theta, draws.iterations), options, attributes,
                 region_dim="material", key_names=("n_materials",),
                 about=f"the kept draws with K = {summary['segmentation_materials']} (the segmentation's K), relabelled: "
                       f"{mat.RELABELLING}; every kept draw's K is in sample_stats (n_materials); a material whose "
                       "summary records parameters_from is summarised over other draws (summary.json)")
    save_chain_arrays(staging / "materials.npz", records, ("cp_iteration", "material_labels", "n_materials"),
                      attributes)
    if options.figures:
        from rjfit.posterior import figures as figs  # matplotlib: only when figures are drawn

        folder = staging / "figures"
        written = {"materials": figs.material_map(result.labels, folder / "materials.png"),
                   "materials_histogram": figs.materials_histogram(summary["materials_posterior"],
                                                                   folder / "materials_histogram.png"),
                   "reflectance": figs.reflectance(result.labels, result.prediction, folder / "reflectance.png")}
        share = result.extra.get("extra_material_share")
        if share is not None and np.nanmax(share, initial=0.0) > 0:      # drawn only where some draw holds more
            written["materials_extra"] = figs.extra_materials_map(share, result.labels,
                                                                  folder / "materials_extra.png")
        summary["figures"] = {name: f"figures/{Path(path).name}" for name, path in written.items()}



# --preset measured's Potts rule (docs/options.md): a material whose parameters equal an existing one's
# holds about S(beta) = sum_p exp(-beta n_p) scattered pixels under the prior (n_p: p's labelled 4-neighbours);
# beta is raised until S <= GHOST_PIXELS, so such a material shrinks to its last pixel often enough for the
# cluster moves to remove it, and rho makes its prior odds rho S / 2 = GHOST_ODDS, the odds every further
# material has (FURTHER_MATERIAL_ODDS, 1:100; 1:20 until 2026-11-27).
GHOST_PIXELS = 1.0
GHOST_ODDS = FURTHER_MATERIAL_ODDS


def ghost_material_prior(object_mask, beta: float) -> tuple[float, float]:
    """``(beta, rho)`` of the measured preset's Potts prior for this mask (the rule above ``GHOST_PIXELS``).

    beta: the smallest of ``beta``, ``beta + 0.05``, ... with ``S(beta) <= GHOST_PIXELS`` (at most 8);
    rho: ``2 GHOST_ODDS / S(beta)``. Pixels without a labelled neighbour are not counted: no beta
    binds them (the preset's calibration leaves them out, :func:`rjfit.data.calibrate.drop_small_components`).
    """
    mask = np.asarray(object_mask, bool)
    padded = np.pad(mask, 1)
    neighbours = (padded[:-2, 1:-1].astype(int) + padded[2:, 1:-1] + padded[1:-1, :-2] + padded[1:-1, 2:])[mask]
    neighbours = neighbours[neighbours > 0]
    ghost_pixels = lambda b: float(np.sum(np.exp(-b * neighbours)))      # noqa: E731
    while ghost_pixels(beta) > GHOST_PIXELS and beta < 8.0:
        beta = round(beta + 0.05, 2)
    return beta, 2.0 * GHOST_ODDS / ghost_pixels(beta)


def _fitted_mask(object_mask, calibrate: bool) -> np.ndarray:
    """The mask the fit sees: the calibration leaves small parts out (:func:`rjfit.data.calibrate.small_components`)."""
    mask = np.asarray(object_mask, bool)
    return mask & ~small_components(mask) if calibrate else mask


def _potts_words(summary: dict, options: dict) -> str | None:
    if not finite(summary.get("potts_beta")):
        return None
    beta, rho = summary["potts_beta"], summary.get("potts_rho")
    text = f"beta {beta:.3g} per pair of neighbouring pixels of different materials"
    if finite(rho):
        text += f"; rho {rho:.3g} per material (prior odds of each further material 1:{1 / rho:.0f})"
    if options.get("preset") == "measured":
        text += "; the measured preset sets both by its rule on the mask unless --potts-rho is given"
    return text


def _edge_words(summary: dict, options: dict) -> str:
    power = summary.get("edge_power")
    if not finite(power) or power == 0:
        return "none (0): a boundary costs only the Potts prior"
    how = "measured (auto: the coarsening rule on the data's differences across 3 px)" \
        if options.get("edge_power") == "auto" else "as given"
    text = f"{power:.3g}, {how}: a boundary earns where the data step as its materials do and costs where they do not"
    gain = summary.get("edge_gain_sd")
    if finite(gain) and gain > 0:
        text += (f"; a local gain of sd {gain:.3g} on the shading, shared by a pair's two ends, is integrated out of "
                 f"each pair ({'measured on the data' if options.get('edge_gain_sd') == 'auto' else 'as given'})")
    noise = summary.get("edge_noise")
    if isinstance(noise, dict):
        text += (f"; each pair's noise measured on the data (variance {noise['white']:.3g} + {noise['shading']:.3g} "
                 f"g^2 + {noise['turn']:.3g} t^2 of the differences' spread squared: g the shading's change, t the "
                 f"geometry's turn across the pair)")
    return text


def contrast_notes(summary: dict) -> list:
    """Each material's contrast to its surroundings in words (:func:`rjfit.posterior.contrast.contrast_words`), and
    what it means where the summary states any (the extra materials' place has its own in their sentence)."""
    notes = [f"Material {entry['material']} ({entry.get('pixels', 0):,} px): {words}."
             for entry in summary.get("regions", [])
             if (words := contrast.contrast_words(entry.get("contrast_to_surroundings")))]
    place = ((summary.get("extra_materials") or {}).get("most_often") or {}).get("contrast")
    return notes + [contrast.MEANING] if notes or place else []


def _boundary_notes(summary: dict) -> list:
    """The boundary check and the edge-supported groups in words (their summary entries, where present)."""
    notes = []
    boundaries = summary.get("boundaries")
    if boundaries:
        verdicts = [edge_verdict(row) for row in boundaries]
        notes.append(f"Boundaries: of the {len(boundaries)} boundaries between MAP materials, "
                     f"{verdicts.count('edge')} show a step in the data and {verdicts.count('no edge')} show none "
                     f"(odds of 100:1); joined where they show none, the materials form "
                     f"{summary.get('edge_supported_materials')} group(s).")
    edge_groups = summary.get("edge_groups_posterior")
    if edge_groups:
        shares = ", ".join(f"{n}: {share:.2f}" for n, share in edge_groups.items())
        notes.append(f"Edge-supported groups over {summary.get('edge_groups_snapshots')} label snapshots (materials "
                     f"that meet where the data show no step joined): {shares}.")
    return notes


class MaterialFit(RegionFit):
    """Free-form materials under a Potts prior (``--regions materials``)."""

    name = "materials"
    reads = frozenset({"max_materials", "potts_beta", "potts_rho", "edge_power", "edge_gain_sd", "edge_noise",
                       "cluster_material_seed", "segment_moves", "component_moves", "spatial_split_moves",
                       "scatter_moves"})
    noun = "material"
    measured_default = True
    joint_colour = True

    def __init__(self):
        # (problem, the edge term that measured its settings on it in sampler_config): the chains' shared start and
        # the summary's resolution take it instead of building it again (minutes and gigabytes at 2048 x 2048)
        self._measured_edges = None

    def measured_edges(self, problem, regions):
        """The edge term this fit measured on ``problem`` where the sampler settings ``regions`` are its (else
        None: the caller builds its own)."""
        if self._measured_edges is None or self._measured_edges[0] is not problem:
            return None
        edges = self._measured_edges[1]
        return edges if regions.has_edge_term and regions.built_with(edges) else None

    @staticmethod
    def edge_term_applies(values: dict) -> bool:
        # the edge term reads the plain prediction (one channel, or each channel of a joint colour fit) under the
        # adaptive moves
        return not values["effects"] and values["effects_from"] is None and values["sampler"] == "adaptive"

    @staticmethod
    def preset_values(values: dict, data) -> dict:
        """The edge term's power 'auto' where it applies and is not given, its noise 'measured' (one channel or a
        joint colour fit), and in one channel its local gain 'auto' too (none of them under a given ``--edge-power
        0``; a joint colour fit gained nothing from the gain on psm-cat, docs/results/2026-11-29-gain-default.md;
        without the measured noise a colour fit of the DiLiGenT ball kept highlight specks in one chain of four,
        docs/results/2026-11-30-colour-noise.md); the Potts rule on the data's mask (:func:`ghost_material_prior`)
        unless ``potts_rho`` is given (its beta starts at the given one); no spatial splits unless given
        (docs/results/2026-12-01-spatial-splits.md)."""
        out = {} if "spatial_split_moves" in values else {"spatial_split_moves": 0}
        if MaterialFit.edge_term_applies(values):
            if "edge_power" not in values:
                out["edge_power"] = "auto"
            with_term = values.get("edge_power", "auto") != 0
            if "edge_gain_sd" not in values and with_term and values.get("channel") != COLOUR:
                out["edge_gain_sd"] = "auto"
            if "edge_noise" not in values and with_term:
                out["edge_noise"] = "measured"
        if "potts_rho" not in values and data.object_mask is not None:
            mask = _fitted_mask(data.object_mask, values.get("calibrate", False))
            out["potts_beta"], out["potts_rho"] = ghost_material_prior(
                mask, values.get("potts_beta", FitOptions.default("potts_beta")))
        return out

    @staticmethod
    def describe(summary: dict, options: dict) -> str:
        return (f"materials: a material label per pixel under a Potts prior, the number of materials K unknown (at "
                f"most {summary.get('max_materials', options.get('max_materials', '?'))}), one BRDF per material")

    @staticmethod
    def settings_rows(summary: dict, options: dict) -> list:
        return [("Potts prior (beta, rho)", _potts_words(summary, options)),
                ("edge term power", _edge_words(summary, options))]

    @staticmethod
    def result_rows(summary: dict) -> list:
        k = summary.get("map_materials")
        posterior = summary.get("materials_posterior") or {}
        rows = [("MAP number of materials K", k, "the K of highest posterior probability; its share "
                 f"{number(posterior.get(str(k), float('nan')), '.3f')} of the kept draws"),
                ("materials of the segmentation", summary.get("segmentation_materials", k),
                 "the kept label snapshot that least disagrees with the others (pixel pairs grouped differently); "
                 "the maps and the regions are its"),
                ("mean probability of a pixel's MAP material", probability(summary.get("map_probability_mean")),
                 "over the object's pixels, the share of label snapshots that give a pixel its MAP material; near 1: "
                 "the segmentation is certain, below 0.9: boundaries or whole materials are in doubt")]
        if "materials_right_probability" in summary:
            rows.append(("probability of the true number of materials",
                         probability(summary["materials_right_probability"]),
                         "posterior probability of K equal to the truth's (rendered data only); good near 1"))
        return rows

    @staticmethod
    def report_notes(summary: dict) -> list:
        resolution = summary.get("material_resolution")
        notes = []
        if isinstance(resolution, dict) and resolution.get("pixels") is not None:
            sentence = resolution_sentence(resolution, summary.get("edge_power"))
            notes.append(f"Resolution: {sentence}.")
        extra = caveats.extra_materials_sentence(summary.get("extra_materials"))
        if extra:
            notes.append(f"{extra[0].upper()}{extra[1:]}.")
        return notes + contrast_notes(summary) + _boundary_notes(summary)

    def sampler_config(self, options, *, burn: int, fixed: bool = False, problem=None) -> SamplerConfig:
        model = MaterialRegions()
        power, gain_sd, noise, edges = edge_settings(problem, options) if problem is not None else \
            (options.edge_power, options.edge_gain_sd, options.edge_noise, None)
        self._measured_edges = None if edges is None else (problem, edges)
        regions = replace(model, max_materials=options.max_materials,
                          potts=replace(model.potts, beta=options.potts_beta, rho=options.potts_rho),
                          cluster=replace(model.cluster, material_seed=options.cluster_material_seed),
                          segments=replace(model.segments, moves=options.segment_moves),
                          merge_split=replace(model.merge_split, spatial_moves=options.spatial_split_moves),
                          edge_power=power, edge_gain_sd=gain_sd, edge_noise=noise,
                          component_moves=options.component_moves, scatter_moves=options.scatter_moves,
                          update_labels=not fixed, jumps=not fixed)
        return assemble(options, regions, burn)

    def shared_start(self, config, problem) -> dict:
        return config.regions.shared_start(problem, edges=self.measured_edges(problem, config.regions))

    def chain_start(self, options, chain: int, start: dict, fixed_segmentation=None) -> dict:
        if fixed_segmentation is not None:      # (H, W) material labels
            start.setdefault("pixel_labels", fixed_segmentation)
        elif "pixel_labels" not in start:
            # starts stratified over K0 = 1 .. min(4, K_max), not drawn: on a large image a jump between
            # numbers of materials is rare once a chain has settled, so a mode at a K that no chain started
            # near could be missed by all of them, and R-hat would not show it; with the edge term every chain
            # starts at the top, which it leaves by merges (MaterialRegions.start_materials)
            edge_term = options.edge_power == "auto" or float(options.edge_power) > 0
            start.setdefault("n_materials", MaterialRegions.start_materials(chain, options.max_materials,
                                                                             edge_term=edge_term))
        return start

    def summarise(self, records, problem, prior, config, options, run: dict, warnings: list, truth_labels,
                  observations) -> FitResult:
        burn = config.kernel.burn_in
        summary, labels, prediction, extra = summarise_materials(records, problem, options, burn, config,
                                                                 self.measured_edges(problem, config.regions))
        summary.update(run)
        summary["warnings"] += material_number_warnings(summary["regions"], prior) + warnings
        if truth_labels is not None:
            summary.update(truth_summary(records, burn, labels, truth_labels))
            summary["materials_right_probability"] = summary["materials_posterior"].get(
                str(summary["true_region_count"]), 0.0)
        result = FitResult(summary=summary, labels=labels, prediction=prediction, problem=problem, burn=burn,
                           model=(summary["segmentation_materials"],), extra=extra)
        add_boundary_check(result, observations, records)
        return result

    def write_files(self, staging, result: FitResult, records, options, attributes: dict) -> None:
        write_material_files(staging, result, records, options, attributes)

    @staticmethod
    def place_by_view(result: FitResult, view_angle, records) -> None:
        """Each material's share of pixels in the object's most steeply seen tenth, the MAP's and each chain's last
        labels', warned of above one half (:func:`rjfit.posterior.caveats.steep_view_caveats`)."""
        entries, warnings = caveats.steep_view_caveats(result.summary["regions"], result.labels, view_angle, records,
                                                       result.burn)
        result.summary.update(entries)
        result.summary["warnings"] += warnings

    @staticmethod
    def printed_line(summary: dict) -> str:
        k = summary["map_materials"]
        line = (f"MAP number of materials {k} (posterior {summary['materials_posterior'][str(k)]:.3f}), mean "
                f"probability of a pixel's MAP material {summary['map_probability_mean']:.3f}")
        segmentation = summary.get("segmentation_materials", k)
        if segmentation != k:
            line += (f"; the segmentation (the kept labels that least disagree with the others) holds {segmentation} "
                     f"material{'' if segmentation == 1 else 's'}")
        extra = caveats.extra_materials_sentence(summary.get("extra_materials"))
        if extra:
            line += f"; {extra}"
        return line

    @staticmethod
    def printed_notes(summary: dict) -> list:
        """The resolution (a sentence of its own: on the model's line it hid R-hat and ESS at the line's end) and the
        materials' contrasts to their surroundings."""
        resolution = summary.get("material_resolution")
        notes = []
        if isinstance(resolution, dict) and resolution.get("pixels") is not None:
            notes.append(f"resolution: {resolution_sentence(resolution, summary.get('edge_power'))}")
        return notes + [note[0].lower() + note[1:] for note in contrast_notes(summary)]
