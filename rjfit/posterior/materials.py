"""Posterior summaries of the material region model: K, the segmentation, per-material parameters.

The segmentation (the MAP labels the fit reports) is a point estimate of the partition: among
the kept label snapshots of every chain and every K, the one whose expected number of pixel
pairs grouped differently from the other kept snapshots is least (Binder's loss with equal
costs; the least-squares clustering of Dahl, "Model-based clustering for expression data via a
Dirichlet process mixture model", 2006, restricted to the sampled partitions; Wade and
Ghahramani, "Bayesian cluster analysis: point estimation and credible balls", Bayesian
Analysis 13(2), 2018). Why not the per-pixel mode at the most probable K (until 2026-11-28):
the draws at one K may hold different small materials (one chain a painted disc, another a
second disc, a third a strip at a contour); matched to one reference each is "the small
material", and no pixel of any of them is that material in half the draws, so the mode gave
the small material no pixel at all (psm-horse with two painted discs of 49 px, found in three
chains of four: the mode's second material held 0 px). Pair disagreements need no matching:
a disc that most draws set apart from the body is set apart in the estimate.

Label switching. The posterior is invariant under the K! renumberings of the materials, so
material k of one draw need not be material k of another. Parameter summaries use the kept
draws that have a label snapshot (every ``cp_thin``-th iteration after burn-in) with K equal to
the segmentation's, each relabelled to it by the optimal matching of pixel overlaps (the
Hungarian assignment on the K x K table of pixels that carry material i in the draw and j in
the segmentation, ``scipy.optimize.linear_sum_assignment``); a pixel's probability is the share
of those snapshots that give it the segmentation's material. The parameter summaries also use
the draws between snapshots: a chain numbers its materials the same way until a step changes
their number (births, deaths, merges, splits: ``ChainRecord.jumped``; label sweeps and cluster
moves between materials keep every material's row), so each snapshot's matching carries to the
draws after it up to the first such step. Before 2026-11-27 only the snapshots counted, one draw
in ``cp_thin``: R-hat and ESS then came from a tenth of the draws.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from rjfit.data.formats import COLOUR_CHANNELS
from rjfit.posterior.summary import diagnostics, region_summaries

__all__ = ["materials_posterior", "count_shares", "map_materials", "RelabelledDraws", "relabelled_draws",
           "central_snapshot", "segmentation_estimate", "snapshot_labels", "last_labels", "material_summaries",
           "cap_warning", "matched_draws", "MATCH_MIN", "RELABELLING", "SEGMENTATION", "CENTRAL_SNAPSHOTS",
           "CENTRAL_PIXELS"]

#: How the segmentation is chosen (written into the summary).
SEGMENTATION = ("the kept label snapshot (any chain, any K) whose expected number of pixel pairs grouped differently "
                "from the other kept snapshots is least (Binder's loss, Dahl's least-squares clustering among the "
                "sampled partitions), then whole materials joined or set apart while that number falls, and a "
                "material that no kept draw holds joined to another")
#: How draws are matched to the segmentation (written into the summary).
RELABELLING = ("kept draws with K = the segmentation's K, each label snapshot relabelled to the segmentation by the "
               "optimal one-to-one matching of pixel overlaps (Hungarian assignment), and the draws after a snapshot "
               "that number the materials as it does (no jump in between) by the snapshot's matching")
#: kept snapshots among which the segmentation is chosen, at most (evenly thinned beyond: the pairs' count grows as
#: their square)
CENTRAL_SNAPSHOTS = 200
#: labelled pixels on which two snapshots' disagreement is counted, at most (every n-th beyond: a share of the pairs
#: estimates the loss as well for choosing among snapshots)
CENTRAL_PIXELS = 2 ** 17
#: a snapshot holds a material of the segmentation when one of its own materials matches that material's pixels more
#: closely than this (Jaccard index: the pixels both hold over the pixels either holds); above one half, at most one of
#: the snapshot's materials can match
MATCH_MIN = 0.5


def materials_posterior(records, burn_in: int) -> dict:
    """{"K": probability} over the numbers of materials visited after burn-in, most probable first.

    Raises
    ------
    ValueError
        If no chain has a draw after burn-in.
    """
    ks = np.concatenate([r.n_materials[burn_in:] for r in records]).astype(np.int64)
    if ks.size == 0:
        raise ValueError("no draws after burn-in: lower the burn-in (--burn-in) or run more iterations (--iterations)")
    return count_shares(ks)


def count_shares(counts) -> dict:
    """{"n": share} of the integers in ``counts`` (not empty), most frequent first (ties: smaller n first)."""
    values, frequency = np.unique(np.asarray(counts, np.int64), return_counts=True)
    order = np.argsort(-frequency, kind="stable")
    return {str(int(values[i])): float(frequency[i] / frequency.sum()) for i in order}


def map_materials(records, burn_in: int) -> int:
    """The most probable number of materials after burn-in."""
    return int(next(iter(materials_posterior(records, burn_in))))


class RelabelledDraws:
    """The kept draws at the MAP K, relabelled to one labelling (see the module docstring).

    Attributes
    ----------
    theta : list of ndarray (D_c, K, 4)
        Per chain, the relabelled parameters of its draws at K: each snapshot draw and the
        draws after it that number the materials as it does (no jump in between).
    labels : list of ndarray (S_c, H, W)
        Per chain, the relabelled pixel labels of its snapshot draws at K (-1 unlabelled).
    reference : ndarray (H, W)
        The reference labelling.
    iterations : list of ndarray (D_c,)
        Per chain, the iteration of each of its draws in ``theta`` (None: not given).
    """

    def __init__(self, theta, labels, reference, iterations=None):
        self.theta, self.labels, self.reference, self.iterations = theta, labels, reference, iterations

    def agreement(self, labels) -> np.ndarray:
        """(H, W) per pixel the share of the relabelled snapshots that give it its material in ``labels`` (NaN
        unlabelled)."""
        labels = np.asarray(labels)
        inside = labels >= 0          # compared there only: an object is a few % of a measured stack's image
        held = np.zeros(int(inside.sum()))
        count = 0
        for snapshots in self.labels:
            if len(snapshots):
                held += np.sum(np.asarray(snapshots)[:, inside] == labels[inside], axis=0)
                count += len(snapshots)
        out = np.full(labels.shape, np.nan)
        out[inside] = held / count
        return out


def _snapshots(rec, burn_in, k):
    for s in np.flatnonzero(rec.cp_iteration >= burn_in):
        t = int(rec.cp_iteration[s])
        if int(rec.n_materials[t]) == k:
            yield t, snapshot_labels(rec, s)


def _numbered_as_at(rec, t: int) -> np.ndarray:
    """The kept draws that number their materials as snapshot draw ``t`` does: ``t`` and the draws
    after it, up to the next snapshot, while no step has changed the number of materials (only
    those steps renumber them: births, deaths, merges and splits). Only ``t`` where the chain
    did not record its jumps."""
    if rec.jumped is None:
        return np.array([t])
    next_snapshots = rec.cp_iteration[rec.cp_iteration > t]
    end = int(next_snapshots[0]) if next_snapshots.size else len(rec.jumped)
    later = np.flatnonzero(rec.jumped[t + 1:end])
    return np.arange(t, t + 1 + (later[0] if later.size else end - t - 1))


def central_snapshot(records, burn_in: int, max_snapshots: int = CENTRAL_SNAPSHOTS,
                     max_pixels: int = CENTRAL_PIXELS) -> tuple[int, int, np.ndarray]:
    """``(chain, iteration, labels)`` of the kept snapshot that least disagrees with the others.

    Two partitions a and b of N pixels group ``D(a, b) = (sum_i n_i.^2 + sum_j n_.j^2 - 2 sum_ij n_ij^2) / 2``
    pixel pairs differently (n their contingency table); the chosen snapshot has the least sum of D over the kept
    snapshots (any K). With more than ``max_snapshots`` the candidates and the snapshots they are compared with are
    thinned evenly, and D is counted on every n-th labelled pixel beyond ``max_pixels``.

    Raises
    ------
    ValueError
        If no chain has a label snapshot after burn-in.
    """
    kept, _, parts = _kept_partitions(records, burn_in, max_snapshots, max_pixels)
    (chain, index), _ = _central(kept, parts)
    return chain, int(records[chain].cp_iteration[index]), snapshot_labels(records[chain], index)


def segmentation_estimate(records, burn_in: int, max_snapshots: int = CENTRAL_SNAPSHOTS,
                          max_pixels: int = CENTRAL_PIXELS) -> tuple[np.ndarray, dict]:
    """The segmentation (:data:`SEGMENTATION`): ``(labels (H, W), origin)``.

    From the :func:`central_snapshot`, changes that lower the expected pair disagreements are made one at a time,
    the best first, until none does (a local search on Binder's loss, as SALSO's sweeps in Dahl, Johnson and
    Mueller, "Search algorithms and loss functions for Bayesian clustering", JCGS 31(4), 2022, but over whole
    materials): a material joined to another (a speck that the chosen snapshot happens to hold), or a material of
    a chain's last kept snapshot set apart (a detail that most draws hold and the chosen one does not). A change
    is made only where some kept snapshot has the number of materials it gives, so that the parameters can be
    summarised. Last, a material that no kept snapshot holds (a remnant of one that a set-apart material cut:
    :func:`_without_unheld`) is joined to another. ``origin``: the snapshot's chain and iteration and the changes
    made.
    """
    kept, pixels, parts = _kept_partitions(records, burn_in, max_snapshots, max_pixels)
    (chain, index), loss = _central(kept, parts)
    iteration, labels = int(records[chain].cp_iteration[index]), snapshot_labels(records[chain], index)
    counts = {int(records[c].n_materials[records[c].cp_iteration[s]]) for c, s in kept}
    lasts = [last for last in (last_labels(rec, burn_in) for rec in records) if last is not None]
    groups = [last == m for last in lasts for m in range(int(last.max()) + 1)
              if np.sum(last == m) < np.sum(last >= 0) / 2]
    changes = []
    while True:
        k = int(labels.max()) + 1
        best = None
        for what, change in _material_changes(labels, k, groups):
            candidate = _compact(change())
            if int(candidate.max()) + 1 not in counts:
                continue
            score = _expected_pairs(candidate.ravel()[pixels] + 1, parts)
            if score < loss and (best is None or score < best[0]):
                best = (score, what, candidate)
        if best is None:
            break
        loss, what, labels = best
        changes.append(what)
    labels = _without_unheld(records, kept, labels, counts, pixels, parts, changes)
    return labels, {"chain": chain, "iteration": iteration, "changes": changes}


def _without_unheld(records, kept, labels, counts, pixels, parts, changes: list) -> np.ndarray:
    """``labels`` with each material that no kept snapshot holds (:func:`_held`) joined, the smallest first, to the
    material that gives the least expected pair disagreements, while a kept snapshot has the K that leaves; each join
    appended to ``changes``.

    Why: setting a chain's material apart can leave the remnant of another that no draw holds (psm-rock at seed 2:
    11 px of a 400-px material; docs/results/2026-11-29-own-draws.md). Binder's loss may keep such a remnant apart,
    but the fit reports a material with parameters for every material of the segmentation, and a material that no
    draw holds has none.
    """
    while True:
        k = int(labels.max()) + 1
        if k - 1 not in counts:
            return labels
        sizes = np.bincount(labels[labels >= 0], minlength=k)
        unheld = [m for m in np.argsort(sizes, kind="stable") if not _held(records, kept, labels == m)]
        if not unheld:
            return labels
        m = int(unheld[0])
        joined = [(_expected_pairs(_compact(np.where(labels == m, b, labels)).ravel()[pixels] + 1, parts), b)
                  for b in range(k) if b != m]
        _, b = min(joined)
        labels = _compact(np.where(labels == m, b, labels))
        changes.append(f"material {m} ({int(sizes[m])} px, which no kept draw holds) joined to {b}")


def _held(records, kept, mask, least: float = MATCH_MIN) -> bool:
    """Whether a kept snapshot ``(chain, index)`` has a material matching the pixels ``mask`` with a Jaccard index
    above ``least`` (:func:`matched_draws`' rule)."""
    return any(_best_match(snapshot_labels(records[chain], index), mask)[1] > least for chain, index in kept)


def _best_match(labels, mask) -> tuple[int, float]:
    """``(material, Jaccard index)`` of the material of ``labels`` (-1 unlabelled) whose pixels best match ``mask``:
    the pixels both hold over the pixels either holds."""
    held = labels >= 0
    shared = np.bincount(labels[mask & held], minlength=1)
    sizes = np.bincount(labels[held], minlength=shared.size)[:shared.size]
    jaccard = shared / np.maximum(int(mask.sum()) + sizes - shared, 1)
    best = int(np.argmax(jaccard))
    return best, float(jaccard[best])


def _material_changes(labels, k: int, groups):
    """``(what, build)`` of every change the search tries: each material joined to each other, each group (a chain's
    material) not already a material set apart; ``build()`` gives the labels after it (one at a time: at 2048 x 2048
    every candidate at once would take gigabytes)."""
    for a in range(k):
        for b in range(k):
            if a != b:
                yield f"material {a} joined to {b}", lambda a=a, b=b: np.where(labels == a, b, labels)
    for group in groups:
        if not any(np.array_equal(group, labels == m) for m in range(k)):
            yield f"a chain's {int(group.sum())}-px material set apart", lambda group=group: np.where(group, k, labels)


def _kept_partitions(records, burn_in, max_snapshots, max_pixels):
    """The kept snapshots ``[(chain, index)]`` (thinned evenly to ``max_snapshots``), the flat labelled pixels they are
    compared on (every n-th beyond ``max_pixels``) and their labels there, + 1 (0: unlabelled). Only those pixels are
    held per snapshot: at 2048 x 2048, 200 whole label images would take gigabytes."""
    kept = [(c, s) for c, rec in enumerate(records) if rec.material_labels is not None
            for s, t in enumerate(rec.cp_iteration) if t >= burn_in]
    if not kept:
        raise ValueError("no label snapshot after burn-in: lower the burn-in (--burn-in) or run more iterations")
    if len(kept) > max_snapshots:
        kept = [kept[i] for i in np.linspace(0, len(kept) - 1, max_snapshots).round().astype(int)]
    pixels = np.flatnonzero(snapshot_labels(records[kept[0][0]], kept[0][1]).ravel() >= 0)
    pixels = pixels[::max(1, -(-pixels.size // max_pixels))]
    parts = np.stack([np.nan_to_num(np.asarray(records[c].material_labels[s]).ravel()[pixels], nan=-1.0)
                      .astype(np.int32) for c, s in kept]) + 1
    return kept, pixels, parts


def _central(kept, parts) -> tuple[tuple, float]:
    """The entry of ``kept`` whose labels (a row of ``parts``) least disagree with the others', and its loss."""
    losses = [_expected_pairs(part, parts) for part in parts]
    best = int(np.argmin(losses))
    return kept[best], float(losses[best])


def snapshot_labels(record, index: int) -> np.ndarray:
    """Label snapshot ``index`` of a material chain's ``record`` as integer labels (H, W), -1 unlabelled."""
    return np.nan_to_num(record.material_labels[index], nan=-1.0).astype(np.int64)


def last_labels(record, burn_in: int) -> np.ndarray | None:
    """The chain's last label snapshot after ``burn_in`` (:func:`snapshot_labels`); None without one."""
    if record.material_labels is None:
        return None
    kept = np.flatnonzero(np.asarray(record.cp_iteration) >= burn_in)
    return snapshot_labels(record, int(kept[-1])) if kept.size else None


def _expected_pairs(candidate, parts) -> float:
    """Sum over ``parts`` (S, N) of the pixel pairs grouped differently from ``candidate`` (N,) (labels >= 0), less
    a constant of ``parts`` (their own pairs, the same for every candidate): what candidates are compared on."""
    n_parts = int(parts.max(initial=0)) + 1
    own = np.sum(np.bincount(candidate).astype(float) ** 2)
    shared = sum(np.sum(np.bincount(candidate * n_parts + part).astype(float) ** 2) for part in parts)
    return (len(parts) * own - 2.0 * shared) / 2.0


def _compact(labels) -> np.ndarray:
    """``labels`` renumbered 0 .. K - 1 in the order of their first numbers (-1 kept)."""
    used = np.unique(labels[labels >= 0])
    lookup = np.full(int(labels.max(initial=0)) + 2, -1, np.int64)
    lookup[used] = np.arange(used.size)
    return np.where(labels >= 0, lookup[np.maximum(labels, 0)], -1)


def relabelled_draws(records, burn_in: int, k: int, n_channels: int = 1, reference=None) -> RelabelledDraws:
    """The draws at ``k`` materials relabelled to ``reference`` (see the module docstring and :class:`RelabelledDraws`).

    ``reference`` (H, W), a labelling with ``k`` materials (-1 unlabelled): default the kept snapshot of highest log
    posterior at ``k``. A joint colour fit (``n_channels`` > 1) records a row per material and channel: its
    draws are then (S_c, K, C, 4).

    Raises
    ------
    ValueError
        If no snapshot after burn-in has ``k`` materials.
    """
    best = None
    for rec in records:
        for t, labels in _snapshots(rec, burn_in, k):
            if best is None or rec.log_post[t] > best[0]:
                best = (rec.log_post[t], labels)
    if best is None:
        raise ValueError(f"no label snapshot with {k} materials after burn-in: run more iterations")
    reference = best[1] if reference is None else np.asarray(reference, np.int64)
    labelled = reference >= 0
    thetas, all_labels, all_iterations = [], [], []
    for rec in records:
        theta_c, labels_c, iterations_c = [], [], []
        for t, labels in _snapshots(rec, burn_in, k):
            overlap = np.zeros((k, k), np.int64)
            np.add.at(overlap, (labels[labelled], reference[labelled]), 1)
            rows, cols = linear_sum_assignment(-overlap)
            to_reference = np.empty(k, np.int64)
            to_reference[rows] = cols
            same_numbering = _numbered_as_at(rec, t)
            theta = np.empty((same_numbering.size, k, n_channels, 4))
            theta[:, to_reference] = rec.theta[same_numbering, :k * n_channels].reshape(-1, k, n_channels, 4)
            theta_c.extend(theta if n_channels > 1 else theta[:, :, 0])
            iterations_c.extend(same_numbering)
            labels_c.append(np.where(labelled, to_reference[np.clip(labels, 0, None)], -1))
        thetas.append(np.array(theta_c).reshape(-1, k, *((n_channels,) if n_channels > 1 else ()), 4))
        all_labels.append(np.array(labels_c).reshape(-1, *reference.shape))
        all_iterations.append(np.array(iterations_c, np.int64))
    return RelabelledDraws(thetas, all_labels, reference, all_iterations)


def matched_draws(records, burn_in: int, mask, n_channels: int = 1, least: float = MATCH_MIN) -> RelabelledDraws:
    """The kept draws of any K that hold the material whose pixels are ``mask`` (H, W, bool), as one material.

    At each label snapshot after burn-in, the snapshot's material whose pixels best match ``mask`` (Jaccard index)
    is taken when the match is above ``least``, with the draws that number the materials as the snapshot does.
    Why: a material of the segmentation that few draws at its K hold (one chain's detail, set apart by
    :func:`segmentation_estimate`) gets, by the Hungarian matching of :func:`relabelled_draws`, some other
    material's parameters from every draw that lacks it; the draws that hold it, at whatever K, are its own.

    Returns
    -------
    RelabelledDraws
        One material: per chain ``theta`` (D_c, 1, 4) ((D_c, 1, C, 4) for a joint colour fit) and the iterations;
        ``labels`` per chain (S_c, H, W), 0 where the matched material lies, -1 elsewhere; ``reference``
        ``mask`` as labels (0, -1). A chain that never holds it has no draws.

    Raises
    ------
    ValueError
        If ``mask`` holds no pixel or ``least`` is not in [0.5, 1) (below one half, two of a snapshot's materials
        could match).
    """
    mask = np.asarray(mask, bool)
    if not mask.any():
        raise ValueError("mask holds no pixel: give the pixels of a material of the segmentation")
    if not 0.5 <= least < 1.0:
        raise ValueError(f"least must be in [0.5, 1), got {least}")
    thetas, all_labels, all_iterations = [], [], []
    for rec in records:
        theta_c, labels_c, iterations_c = [], [], []
        for s in np.flatnonzero(np.asarray(rec.cp_iteration) >= burn_in):
            t, labels = int(rec.cp_iteration[s]), snapshot_labels(rec, s)
            best, jaccard = _best_match(labels, mask)
            if jaccard <= least:
                continue
            same_numbering = _numbered_as_at(rec, t)
            rows = rec.theta[same_numbering, best * n_channels:(best + 1) * n_channels]
            theta_c.extend(rows.reshape(-1, 1, n_channels, 4) if n_channels > 1 else rows.reshape(-1, 1, 4))
            iterations_c.extend(same_numbering)
            labels_c.append(np.where(labels == best, 0, -1).astype(np.int8))     # int8: at 2048^2, 4 MB each
        thetas.append(np.array(theta_c).reshape(-1, 1, *((n_channels,) if n_channels > 1 else ()), 4))
        all_labels.append(np.array(labels_c, np.int8).reshape(-1, *mask.shape))
        all_iterations.append(np.array(iterations_c, np.int64))
    return RelabelledDraws(thetas, all_labels, np.where(mask, 0, -1), all_iterations)


def material_summaries(draws: RelabelledDraws, map_labels) -> tuple[list, dict]:
    """Per material: pixel count (MAP labels) and posterior mean, sd, 95 % interval of each parameter; and diagnostics.

    Returns ``(summaries, diagnostics)``; :func:`rjfit.posterior.summary.diagnostics` of the
    relabelled draws (R-hat and ESS over chains).
    """
    if draws.theta[0].ndim == 4:
        return colour_summaries(draws, map_labels)
    summaries = region_summaries(draws.theta, map_labels)
    for entry in summaries:
        entry["material"] = entry["region"]
    return summaries, diagnostics(draws.theta)


def colour_summaries(draws: RelabelledDraws, map_labels, channel_names=COLOUR_CHANNELS) -> tuple[list, dict]:
    """:func:`material_summaries` of a joint colour fit: per material its pixels and gamma, and per channel
    I0, kd and sigma^2 (posterior mean, sd, 95 % interval); diagnostics over every (material, channel) row."""
    k, n_ch = draws.theta[0].shape[1:3]
    flat = [theta.reshape(len(theta), k * n_ch, 4) for theta in draws.theta]
    rows = region_summaries(flat, None)
    summaries = []
    for m in range(k):
        entry = {"region": m, "material": m, "pixels": int(np.sum(map_labels == m)), "gamma": rows[m * n_ch]["gamma"],
                 "channels": {name: {param: rows[m * n_ch + c][param] for param in ("I0", "kd", "sigma2")}
                              for c, name in enumerate(channel_names[:n_ch])}}
        summaries.append(entry)
    return summaries, diagnostics(flat)


def cap_warning(posterior: dict, max_materials: int, threshold: float = 0.05) -> str | None:
    """A warning when the posterior puts mass on K = K_max (the cap may bind), else None."""
    mass = posterior.get(str(int(max_materials)), 0.0)
    if mass < threshold:
        return None
    return (f"the posterior puts {mass:.2f} on K = {max_materials} materials, the cap (--max-materials): the data may "
            "support more materials than the cap allows; refit with a higher --max-materials")
