"""Caveats of a fit's summaries: each a plain sentence that names what is wrong, where, and why it matters.

:mod:`rjfit.posterior.summary` checks that the chains support the summaries (R-hat, ESS,
agreement over models); the checks here look at the numbers themselves:

- a region's posterior mean at or beyond its prior's plausible range, defined as the prior's
  central :data:`PLAUSIBLE_MASS` interval (:func:`prior_range_warnings`);
- a region's 95 % interval that reaches a hard bound of its prior's support (kd at 0 or 1):
  the data allow the bound itself, and the mean is only pulled off it by the bound
  (:func:`support_bound_warnings`);
- a region of the MAP model that holds no pixel with observations (:func:`empty_region_warnings`);
- a model cap that binds: more than :data:`CAP_MASS_MAX` of the posterior on the largest
  model allowed along an axis (:func:`model_cap_warnings`);
- a pooled mean outside its own 95 % interval (:func:`pooled_interval_warnings`);
- proposals rejected because their acceptance ratio was NaN (:func:`nan_rejection_warnings`);
- a material that lies mostly where the object is seen most steeply (:func:`steep_view_shares`,
  :func:`steep_view_warnings`);
- a material of the segmentation that the draws summarised for it mostly do not hold
  (:func:`label_agreements`, :func:`label_agreement_warnings`);
- what the draws with more materials than the segmentation add to it: their extra materials' size
  (:func:`extra_materials`, :func:`extra_materials_sentence`).
"""
from __future__ import annotations

import numpy as np

from rjfit.posterior.contrast import contrast_words
from rjfit.posterior.materials import last_labels
from rjfit.posterior.summary import RHAT_MAX
from rjfit.sampler.priors import PARAM_NAMES

__all__ = ["PLAUSIBLE_MASS", "CAP_MASS_MAX", "BOUND_SHARE", "prior_range_warnings", "support_bound_warnings",
           "empty_region_warnings", "model_cap_warnings", "pooled_interval_warnings", "nan_rejection_warnings",
           "acceptance_counts", "STEEP_TAIL", "STEEP_SHARE", "steep_view_shares", "steep_view_warnings",
           "chain_steep_warnings", "steep_view_caveats", "AGREEMENT_MIN", "label_agreements",
           "label_agreement_warnings", "extra_materials", "extra_materials_sentence"]

#: a prior's plausible range: its central 99.9 % interval (a posterior mean outside it lies
#: where the prior puts 1 in 2000 of its mass on either side)
PLAUSIBLE_MASS = 0.999
#: a 95 % interval "reaches" a finite bound of the prior's support when it ends within this
#: share of the support's width from it
BOUND_SHARE = 0.01
#: a model cap binds when more than this share of the kept draws sits on it
CAP_MASS_MAX = 0.05
#: a material's parameters are its own when the draws summarised for it give its pixels its label in at least this
#: share of them on average (a majority)
AGREEMENT_MIN = 0.5
#: the share of the object's labelled pixels seen most steeply (furthest from their normal) that a material's
#: pixels are compared against
STEEP_TAIL = 0.1
#: a material lies mostly in that tail when more than this share of its pixels do: five times what a material
#: placed without regard to the view holds (STEEP_TAIL)
STEEP_SHARE = 0.5


def prior_range_warnings(regions, prior, mass: float = PLAUSIBLE_MASS) -> list:
    """A warning per region parameter whose posterior mean lies at or beyond its prior's central ``mass`` interval.

    Parameters
    ----------
    regions : list of dict
        :func:`rjfit.posterior.summary.region_summaries` (a parameter a row lacks is skipped).
    prior : rjfit.sampler.priors.Prior
    mass : float
        The share of the prior the plausible range holds.
    """
    ranges = [p.central_interval(mass) for p in prior.params]
    out = []
    for index, region in enumerate(regions):
        for name, (low, high) in zip(PARAM_NAMES, ranges):
            if name not in region:        # a colour fit's channel rows carry gamma once
                continue
            mean = region[name]["mean"]
            if low < mean < high:
                continue
            side = "above" if mean >= high else "below"
            out.append(f"region {region.get('region', index)}: {name} posterior mean {mean:.4g} lies at or {side} its "
                       f"prior's plausible range [{low:.4g}, {high:.4g}] (the prior's central {100 * mass:g} % "
                       "interval): the data pull it where the prior puts almost no mass, or cannot identify it; do "
                       "not read it as a measurement")
    return out


def support_bound_warnings(regions, prior, share: float = BOUND_SHARE) -> list:
    """A warning per region parameter whose 95 % interval reaches a finite bound of its prior's support.

    Only priors with a bounded support (uniform, beta: kd in (0, 1)) have such a bound. An
    interval ending within ``share`` of the support's width from it means the data allow the
    bound (kd = 0: no diffuse part), and the posterior mean is off it only because the bound
    cuts the posterior there.

    Parameters
    ----------
    regions : list of dict
        :func:`rjfit.posterior.summary.region_summaries` (each parameter's ``q2.5``, ``q97.5``).
    prior : rjfit.sampler.priors.Prior
    share : float
        How close to the bound, as a share of the support's width.
    """
    out = []
    for index, region in enumerate(regions):
        for name, param in zip(PARAM_NAMES, prior.params):
            low, high = param.support()
            summary = region.get(name) or {}
            if not np.isfinite(high - low) or "q2.5" not in summary:
                continue
            margin = share * (high - low)
            for bound, end, reaches in ((low, summary["q2.5"], summary["q2.5"] <= low + margin),
                                        (high, summary["q97.5"], summary["q97.5"] >= high - margin)):
                if reaches:
                    out.append(f"region {region.get('region', index)}: {name}'s 95 % interval "
                               f"[{summary['q2.5']:.4g}, {summary['q97.5']:.4g}] reaches its prior's bound {bound:g} "
                               f"(mean {summary['mean']:.4g}): the data allow {name} = {bound:g}, and the mean is off "
                               f"the bound only because the bound cuts the posterior; report the interval, not the mean")
    return out


def empty_region_warnings(labels, observed, n_regions: int) -> list:
    """A warning per region of the MAP model with no pixel that has an observation.

    Parameters
    ----------
    labels : ndarray (H, W)
        MAP labels (-1 off the object).
    observed : ndarray of bool (H, W)
        Pixels with at least one observation in the fit.
    n_regions : int
        Regions of the MAP model.
    """
    labels = np.asarray(labels)
    held = np.bincount(labels[np.asarray(observed, bool) & (labels >= 0)].ravel(), minlength=n_regions)
    return [f"region {r} of the MAP model holds no pixel with observations (its pixels in the MAP labels: "
            f"{int(np.sum(labels == r))}): its parameters are drawn from their prior alone and say nothing about "
            f"the data, yet it counts among the model's {n_regions} regions"
            for r in range(n_regions) if held[r] == 0]


def model_cap_warnings(model_posterior: dict, caps: dict, threshold: float = CAP_MASS_MAX) -> list:
    """A warning per axis whose largest allowed model holds more than ``threshold`` of the posterior.

    Parameters
    ----------
    model_posterior : dict
        ``{"(k1,k2,...)": probability}`` (:func:`rjfit.posterior.summary.model_posterior`).
    caps : dict
        ``{key name: (largest allowed value, the option that sets it)}``, in the order of the
        model keys' entries (``{"n_u": (3, "--max-u"), "n_v": (3, "--max-v")}``).
    threshold : float
    """
    keys = [tuple(int(k) for k in key.strip("()").split(",")) for key in model_posterior]
    masses = np.array(list(model_posterior.values()), dtype=float)
    out = []
    for axis, (name, (cap, option)) in enumerate(caps.items()):
        at_cap = float(masses[[key[axis] == cap for key in keys]].sum()) if keys else 0.0
        if at_cap > threshold:
            out.append(f"the model cap binds: {at_cap:.0%} of the posterior has {name} = {cap}, the most allowed "
                       f"(warned above {threshold:.0%}): the posterior over models is cut there and the data may "
                       f"support more; rerun with {option} {cap + 1} to see")
    return out


def pooled_interval_warnings(regions) -> list:
    """A warning per region parameter whose pooled mean lies outside its own 95 % interval (separated modes)."""
    out = []
    for index, region in enumerate(regions):
        for name in PARAM_NAMES:
            entry = region.get(name)
            if entry is None or entry["q2.5"] <= entry["mean"] <= entry["q97.5"]:
                continue
            out.append(f"region {region.get('region', index)}: the pooled mean of {name}, {entry['mean']:.4g}, lies "
                       f"outside its own 95 % interval [{entry['q2.5']:.4g}, {entry['q97.5']:.4g}]: the draws fall "
                       "into separate modes (chains in different modes, or a few extreme draws); the mean describes "
                       "none of them: read chain_regions")
    return out


def acceptance_counts(records) -> dict:
    """Per move kind over all chains: proposals, acceptances and rejections for a NaN acceptance ratio."""
    kinds = sorted({k for r in records for k in r.proposed} | {k for r in records for k in r.nan_rejected})
    return {k: {"proposed": sum(r.proposed.get(k, 0) for r in records),
                "accepted": sum(r.accepted.get(k, 0) for r in records),
                "nan_rejected": sum(r.nan_rejected.get(k, 0) for r in records)} for k in kinds}


def nan_rejection_warnings(counts: dict) -> list:
    """A warning per move kind with proposals rejected because their acceptance ratio was NaN."""
    return [f"{c['nan_rejected']} of {c['proposed']} '{kind}' proposals were rejected because their acceptance "
            "ratio was NaN (a density that could not be evaluated there): the chain never goes where those "
            "proposals lead, whatever the posterior says there; please report it with the data set"
            for kind, c in counts.items() if c["nan_rejected"]]


def steep_view_shares(labels, view_angle, n_regions: int, tail: float = STEEP_TAIL,
                      angle_of: float | None = None) -> tuple[np.ndarray, float]:
    """Per region, the share of its pixels among the object's ``tail`` most steeply seen; and that tail's angle.

    Why: where the surface turns away from the camera (towards an occluding contour, into a fold) a pixel's
    radiance is changed most by what the model does not hold: the given normals' errors, pixels that mix two
    surfaces at a contour, interreflection in a concavity, grazing reflectance. A second material found on
    psm-horse held 63 % of its 186 pixels in that tenth, every paint and pebble of the shared stacks 25 % or
    less (docs/results/2026-11-28-steep-materials.md).

    Parameters
    ----------
    labels : ndarray of int (H, W)
        MAP labels, -1 off the object.
    view_angle : ndarray (H, W)
        Degrees between each pixel's normal and its view direction (NaN where unknown).
    n_regions : int
        Regions of the MAP model.
    tail : float
        The steep share of the labelled pixels with a view angle, in (0, 1).
    angle_of : float, optional
        The tail's angle, where it is known already (another labelling of the same object: a chain's).

    Returns
    -------
    shares : ndarray (n_regions,)
        NaN for a region without a pixel of known view angle.
    angle : float
        The tail's lower angle (the ``1 - tail`` quantile of the labelled pixels' angles); NaN when no
        labelled pixel has one.

    Raises
    ------
    ValueError
        If ``labels`` and ``view_angle`` differ in shape, or ``tail`` is not in (0, 1).
    """
    labels, view_angle = np.asarray(labels), np.asarray(view_angle, float)
    if labels.shape != view_angle.shape:
        raise ValueError(f"view_angle must have the labels' shape {labels.shape}, got {view_angle.shape}")
    if not 0.0 < tail < 1.0:
        raise ValueError(f"tail must lie in (0, 1), got {tail}")
    known = (labels >= 0) & np.isfinite(view_angle)
    if not known.any():
        return np.full(n_regions, np.nan), float("nan")
    angle = float(np.quantile(view_angle[known], 1.0 - tail)) if angle_of is None else float(angle_of)
    held = np.bincount(labels[known], minlength=n_regions)[:n_regions].astype(float)
    steep = np.bincount(labels[known & (view_angle >= angle)], minlength=n_regions)[:n_regions]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(held > 0, steep / held, np.nan), angle


def steep_view_warnings(regions, shares, angle: float, share: float = STEEP_SHARE, tail: float = STEEP_TAIL) -> list:
    """A warning per material (``regions`` entries with ``material`` and ``pixels``) of which more than ``share``
    of the pixels lie in the object's steep ``tail`` (:func:`steep_view_shares`), the largest material excepted."""
    if not regions:
        return []
    largest = max(regions, key=lambda region: region.get("pixels", 0)).get("material")
    out = []
    for region, fraction in zip(regions, shares):
        if region.get("material") == largest or not np.isfinite(fraction) or fraction <= share:
            continue
        out.append(f"material {region['material']} ({region.get('pixels', 0)} px): {fraction:.0%} of its pixels lie "
                   f"where the object is seen most steeply (more than {angle:.0f} deg from their normal, the object's "
                   f"steepest {tail:.0%}), where normal errors, pixels mixing two surfaces at an occluding "
                   "contour, interreflection in a fold and grazing reflectance change the radiance most: it more "
                   "likely holds the model's misfit there than a paint of its own")
    return out


def chain_steep_warnings(per_chain, angle: float, share: float = STEEP_SHARE) -> list:
    """One warning naming the chains whose last label snapshot holds a material (other than its largest) with more
    than ``share`` of its pixels beyond ``angle``; ``per_chain``: per chain, ``{"pixels", "steep_view_share"}`` of
    those materials."""
    named = [(c, m["pixels"], m["steep_view_share"]) for c, materials in enumerate(per_chain) for m in materials
             if m["steep_view_share"] > share]
    if not named:
        return []
    listed = "; ".join(f"chain {c}: {pixels} px, {fraction:.0%}" + (" of them there" if i == 0 else "")
                       for i, (c, pixels, fraction) in enumerate(named))
    return [f"the chains' last labels hold materials that lie mostly where the object is seen most steeply, more "
            f"than {angle:.0f} deg from their normal ({listed}): normal errors, pixels mixing two surfaces at an "
            "occluding contour, interreflection in a fold and grazing reflectance change the radiance most there, so "
            "such a material more likely holds the model's misfit than a paint"]


def steep_view_caveats(regions, labels, view_angle, records, burn_in: int) -> tuple[dict, list]:
    """A material fit placed by the view: ``(entries, warnings)``.

    ``entries``: ``steep_view_angle``, the tail's angle, and ``chain_steep_materials``, per chain the materials of its
    last label snapshot but its largest (:func:`rjfit.posterior.materials.last_labels`), each with its pixels and
    share (a chain's extra material need not be in the segmentation); each of ``regions`` gains its
    ``steep_view_share`` (in place). ``warnings``: :func:`steep_view_warnings` and :func:`chain_steep_warnings`.
    """
    shares, angle = steep_view_shares(labels, view_angle, len(regions))
    for region, share in zip(regions, shares):
        region["steep_view_share"] = float(share) if np.isfinite(share) else None
    per_chain = []
    for record in records:
        last = last_labels(record, burn_in)
        if last is None:
            per_chain.append([])
            continue
        counts = np.bincount(last[last >= 0], minlength=1)
        chain_shares, _ = steep_view_shares(last, view_angle, counts.size, angle_of=angle)
        per_chain.append([{"pixels": int(counts[k]), "steep_view_share": float(chain_shares[k])}
                          for k in range(counts.size) if k != int(np.argmax(counts)) and counts[k] > 0
                          and np.isfinite(chain_shares[k])])
    entries = {"steep_view_angle": float(angle) if np.isfinite(angle) else None, "chain_steep_materials": per_chain}
    return entries, steep_view_warnings(regions, shares, angle) + chain_steep_warnings(per_chain, angle)


def label_agreements(labels, agreement, n_materials: int) -> np.ndarray:
    """Per material of ``labels`` (H, W; -1 unlabelled), the mean over its pixels of ``agreement`` (H, W: per pixel
    the share of the relabelled draws giving it its label, :meth:`rjfit.posterior.materials.RelabelledDraws
    .agreement`); NaN for a material without a pixel of finite agreement.

    Raises
    ------
    ValueError
        If ``labels`` and ``agreement`` differ in shape.
    """
    labels, agreement = np.asarray(labels), np.asarray(agreement, float)
    if labels.shape != agreement.shape:
        raise ValueError(f"agreement must have the labels' shape {labels.shape}, got {agreement.shape}")
    known = (labels >= 0) & np.isfinite(agreement)
    held = np.bincount(labels[known], minlength=n_materials)[:n_materials].astype(float)
    total = np.bincount(labels[known], weights=agreement[known], minlength=n_materials)[:n_materials]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(held > 0, total / held, np.nan)


def label_agreement_warnings(regions, agreements, n_materials: int, least: float = AGREEMENT_MIN) -> list:
    """A warning per material (``regions`` entries with ``material`` and ``pixels``) whose pixels the draws at the
    segmentation's K give its label in less than ``least`` of them on average (:func:`label_agreements`).

    Why: the segmentation may take a material from one chain's draws (:func:`rjfit.posterior.materials
    .segmentation_estimate` sets apart what a chain's last labels hold) while its parameters are summarised over
    every kept draw with that K, relabelled to it by overlap; where the chains disagree, those draws' matching
    material lies mostly elsewhere, and its numbers are not this material's (psm-rock at seed 1: a 9,282-px material
    whose pixels those draws gave its label in 0.1 % of them, its I0 below the body's though its pixels are brighter:
    docs/results/2026-11-29-compact-starts.md). Where ``regions`` carries ``parameters_from``
    (:func:`rjfit.pipeline.regions.materials.summarise_from_own_draws`: its parameters summarised afresh over the draws
    that hold it), the warning says so instead.
    """
    out = []
    for region, share in zip(regions, agreements):
        if not np.isfinite(share) or share >= least:
            continue
        head = (f"material {region['material']} ({region.get('pixels', 0)} px): the draws with K = {n_materials} give "
                f"its pixels this material in {share:.1%} of them on average, so the chains disagree on it")
        own = region.get("parameters_from")
        if own:
            chains = ", ".join(str(c) for c in own["chains"])
            rhat = own.get("rhat_max")
            mixed = (f" (R-hat {rhat:.2f} over them: those chains hold different versions of it)"
                     if rhat is not None and np.isfinite(rhat) and rhat > RHAT_MAX else "")
            out.append(f"{head}; its parameters are summarised over the {own['draws']} kept draws (of any K; chain "
                       f"{chains}) whose material matches its pixels (Jaccard index above {own['match_min']:g}), not "
                       f"over the draws at that K{mixed}; read its outline as those chains'")
        else:
            out.append(f"{head}, and in most of those draws the parameters reported for it belong to other pixels: "
                       "read its parameters as unknown and its outline as one chain's")
    return out


def extra_materials(records, burn_in: int, n_materials: int) -> tuple:
    """What the kept label snapshots with more materials than the segmentation's ``n_materials`` add to it, and
    where.

    In such a snapshot its K - ``n_materials`` smallest materials are its extra ones; their pixels are counted
    together. Why: a K posterior below 1 says that other draws hold more materials, not whether those are a second
    paint of thousands of pixels or specks of a few, which a user reading "K = 1: 0.73" needs to know (psm-horse:
    the chains at K = 2 hold 2 to 30 px; docs/results/2026-12-03-extra-materials.md), nor where they lie (a spot, a
    shadow, a speck of dust: docs/results/2026-12-03-speck-places.md). One pass over the snapshots gives both.

    Returns
    -------
    (dict or None, ndarray or None)
        The entry: ``snapshots``, the kept snapshots (every chain's after ``burn_in``); ``share``, the share of them
        with more materials; ``chain_shares``, the same per chain (None for a chain without kept snapshots);
        ``pixels``, the extra materials' pixels per such snapshot, ``min``, ``median`` and ``max`` (None where no
        snapshot has more); ``most_often``, the pixel most often in an extra material (the first in raster order
        where several are), ``row``, ``column`` and ``share`` (the share of the kept snapshots in which it is; None
        where no snapshot has more). And (H, W) every pixel's share of the kept snapshots in which it is in an extra
        material (NaN where no snapshot labels it). ``(None, None)`` when no record holds material label snapshots.
    """
    counted = _extra_material_counts(records, burn_in, n_materials)
    if counted is None:
        return None, None
    extra, chain_shares, total, often, labelled = counted
    pixels = most_often = None
    if extra:
        pixels = {"min": int(min(extra)), "median": float(np.median(extra)), "max": int(max(extra))}
        row, column = np.unravel_index(int(np.argmax(often)), often.shape)
        most_often = {"row": int(row), "column": int(column), "share": float(often[row, column]) / total}
    entry = {"materials": int(n_materials), "snapshots": int(total), "share": len(extra) / total,
             "chain_shares": chain_shares, "pixels": pixels, "most_often": most_often}
    return entry, np.where(labelled, often / total, np.nan)


def _extra_material_counts(records, burn_in: int, n_materials: int):
    """``(extra, chain_shares, total, often, labelled)`` of :func:`extra_materials`: the extra materials' pixels per
    snapshot with more, the per-chain shares, the kept snapshots, per pixel (H, W) the snapshots in which it is in an
    extra material, and whether any chain labels it; None without any kept snapshot."""
    extra, chain_shares, total, often, seen = [], [], 0, None, None
    for record in records:
        kept = np.flatnonzero(np.asarray(record.cp_iteration) >= burn_in)
        if getattr(record, "material_labels", None) is None or not kept.size:
            chain_shares.append(None)
            continue
        shape = np.shape(record.material_labels)[1:]
        flat = np.asarray(record.material_labels).reshape(len(record.material_labels), -1)
        often = np.zeros(shape) if often is None else often
        seen = np.zeros(shape, bool) if seen is None else seen
        # the labelled pixels (a chain labels the same ones in every snapshot; any other NaN counts as unlabelled),
        # gathered one snapshot at a time: the whole image per snapshot took 1.2 s on psm-horse, and all snapshots at
        # once would hold gigabytes at 2048 x 2048
        labelled = np.flatnonzero(np.isfinite(flat[kept[0]]))
        seen.ravel()[labelled] = True
        more = 0
        for index in kept:
            labels = np.nan_to_num(flat[index, labelled], nan=-1.0).astype(np.int64)
            counts = np.bincount(labels[labels >= 0])
            used = np.flatnonzero(counts)
            if used.size > n_materials:
                # the snapshot's smallest materials beyond the segmentation's number (ties: the lower label first)
                smallest = used[np.argsort(counts[used], kind="stable")[:used.size - n_materials]]
                extra.append(int(counts[smallest].sum()))
                often.ravel()[labelled[np.isin(labels, smallest)]] += 1
                more += 1
        chain_shares.append(more / kept.size)
        total += kept.size
    return None if not total else (extra, chain_shares, total, often, seen)


def extra_materials_sentence(entry: dict | None) -> str | None:
    """:func:`extra_materials`' entry in words; None where no kept snapshot has more materials than the segmentation."""
    if not entry or not entry.get("pixels"):
        return None
    pixels = entry["pixels"]
    size = (f"{pixels['min']:,} px" if pixels["min"] == pixels["max"] else
            f"{pixels['min']:,} to {pixels['max']:,} px (median {pixels['median']:,.0f})")
    where = entry.get("most_often")
    place = ("" if not where else f", most often at row {where['row']}, column {where['column']} of the maps "
             f"({where['share']:.0%} of the snapshots; maps.exr's extra_material_share shows where)")
    words = contrast_words((where or {}).get("contrast"))
    if words:
        place += f", a place of {where['contrast']['pixels']:,} px: {words}"
    elif where and "contrast" in where:         # read, but no light saw both it and its surroundings
        place += ", a place whose observations cannot be compared with its surroundings' (none there, or none around)"
    return (f"{entry['share']:.0%} of the kept label snapshots hold more materials than the segmentation's "
            f"{entry['materials']}, their extra materials {size} in all{place}")
