"""The material model's boundary check: whether the data step where the fitted materials meet, on the MAP labels
and over the kept draws (:mod:`rjfit.posterior.boundaries`), into a fit's summary."""
from __future__ import annotations

import numpy as np

from rjfit.posterior import materials as mat
from rjfit.posterior.boundaries import boundary_support, edge_group_count, edge_groups, unsupported_boundary_warnings

__all__ = ["material_boundaries", "edge_groups_posterior", "add_boundary_check", "EDGE_GROUP_SNAPSHOTS"]

#: label snapshots per chain whose edge groups are counted (evenly spaced over the kept ones): each costs a
#: least-squares fit per material and the boundary check, 0.2 to 0.6 s on the DiLiGenT ball's 1.3 million
#: observations
EDGE_GROUP_SNAPSHOTS = 10


def material_boundaries(problem, observations, materials, labels) -> tuple[dict, list]:
    """Whether the data step where the MAP materials meet (:func:`rjfit.posterior.boundaries.boundary_support`).

    Returns the summary entries ``boundaries`` (a row per pair of adjacent materials),
    ``material_groups`` (the materials joined where they meet without an edge; each group's
    materials in order, the groups by their first) and ``edge_supported_materials`` (their
    number), and a warning per boundary without an edge; nothing for one material, a joint
    colour fit or a fit with effects (whose plain prediction the check would compare with the
    data in place of the fit's own).
    """
    if not _checkable(problem) or len(materials) < 2:
        return {}, []
    rows = boundary_support(labels, None, problem.y, problem.C, problem.log_cos_hn, problem.pixel,
                            problem.light, int(observations.n_lights))
    groups = edge_groups(rows, len(materials))
    return ({"boundaries": rows, "edge_supported_materials": len(groups), "material_groups": groups},
            unsupported_boundary_warnings(rows))


def _checkable(problem) -> bool:
    """Whether the boundary check applies: one channel and no effects (whose plain prediction the check would
    compare with the data in place of the fit's own)."""
    return problem.n_channels == 1 and problem.effects is None


def edge_groups_posterior(records, burn: int, problem, observations) -> tuple[dict, list]:
    """The posterior over the number of edge-supported material groups, and a warning when the chains disagree.

    Over :data:`EDGE_GROUP_SNAPSHOTS` kept label snapshots per chain (evenly spaced), the share
    whose materials form n groups once those that meet where the data show no edge are joined
    (:func:`rjfit.posterior.boundaries.edge_group_count`): a summary of the same draws as
    ``materials_posterior`` that counts a split along the model's smooth misfit as one material.
    Nothing for a joint colour fit or a fit with effects (as :func:`material_boundaries`).
    """
    if not _checkable(problem):
        return {}, []
    light, per_chain = problem.light, []
    for record in records:
        kept = np.flatnonzero(record.cp_iteration >= burn)
        chosen = kept[np.unique(np.linspace(0, kept.size - 1, min(EDGE_GROUP_SNAPSHOTS, kept.size)).round()
                                .astype(np.int64))] if kept.size else kept
        per_chain.append([edge_group_count(record.material_labels[s], problem.y, problem.C, problem.log_cos_hn,
                                           problem.pixel, light, int(observations.n_lights)) for s in chosen])
    pooled = [n for counts in per_chain for n in counts]
    if not pooled:
        return {}, []
    chain_posteriors = [mat.count_shares(counts) if counts else {} for counts in per_chain]
    modes = {next(iter(shares)) for shares in chain_posteriors if shares}
    warnings = [] if len(modes) < 2 else [
        f"the chains disagree on the number of edge-supported material groups (most frequent per chain: "
        f"{', '.join(next(iter(p)) if p else '-' for p in chain_posteriors)}): read edge_groups_posterior as a rough "
        f"guide and run longer or more chains"]
    return ({"edge_groups_posterior": mat.count_shares(pooled), "chain_edge_groups_posterior": chain_posteriors,
             "edge_groups_snapshots": len(pooled)}, warnings)


def add_boundary_check(result, observations, records) -> None:
    """:func:`material_boundaries` and :func:`edge_groups_posterior` into ``result``: their summary entries and
    warnings, and ``edge_group`` (the MAP labels with the joined materials' group per pixel, for ``maps.exr``)."""
    entries, warnings = material_boundaries(result.problem, observations, result.summary["regions"], result.labels)
    posterior, disagreement = edge_groups_posterior(records, result.burn, result.problem, observations)
    result.summary.update(entries)
    result.summary.update(posterior)
    result.summary["warnings"] += warnings + disagreement
    if "material_groups" in entries:
        group_of = np.empty(len(result.summary["regions"]))
        for index, members in enumerate(entries["material_groups"]):
            group_of[members] = index
        result.extra["edge_group"] = np.where(result.labels >= 0, group_of[np.maximum(result.labels, 0)], np.nan)
