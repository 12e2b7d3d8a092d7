"""Posterior summaries of the material region model: K, MAP materials, per-material parameters.

Label switching. The posterior is invariant under the K! renumberings of the materials, so
material k of one draw need not be material k of another. Summaries use the kept draws
that have a label snapshot (every ``cp_thin``-th iteration after burn-in) with K equal to
the MAP K, each relabelled to a reference labelling by the optimal matching of pixel
overlaps (the Hungarian assignment on the K x K table of pixels that carry material i in
the draw and j in the reference, ``scipy.optimize.linear_sum_assignment``). The reference
is the kept snapshot of highest log posterior; the MAP material of a pixel is then its most
frequent relabelled material, and its probability is that frequency. One matching pass:
the reference is a single draw, so pixels it misassigns can shift a matching where
materials overlap little. The parameter summaries also use the draws between snapshots:
a chain numbers its materials the same way until a step changes their number (births,
deaths, merges, splits: ``ChainRecord.jumped``; label sweeps and cluster moves between
materials keep every material's row), so each snapshot's matching carries to the draws
after it up to the first such step. Before 2026-11-27 only the snapshots counted, one draw
in ``cp_thin``: R-hat and ESS then came from a tenth of the draws.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from rjfit.data.formats import COLOUR_CHANNELS
from rjfit.posterior.summary import diagnostics, region_summaries

__all__ = ["materials_posterior", "count_shares", "map_materials", "RelabelledDraws", "relabelled_draws",
           "material_summaries", "cap_warning", "RELABELLING"]

#: How draws are matched to the MAP labelling (written into the summary).
RELABELLING = ("kept draws with K = MAP K, each label snapshot relabelled to the snapshot of highest log posterior by "
               "the optimal one-to-one matching of pixel overlaps (Hungarian assignment), and the draws after a "
               "snapshot that number the materials as it does (no jump in between) by the snapshot's matching")


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

    def map_labels(self):
        """(MAP material per pixel, its posterior probability): the per-pixel mode of the relabelled labels."""
        stacked = np.concatenate([lab for lab in self.labels if len(lab)])
        k = int(self.reference.max()) + 1
        counts = np.stack([(stacked == m).sum(axis=0) for m in range(k)])
        labels = np.where(self.reference >= 0, np.argmax(counts, axis=0), -1)
        probability = np.where(self.reference >= 0, counts.max(axis=0) / stacked.shape[0], np.nan)
        return labels, probability


def _snapshots(rec, burn_in, k):
    for s in np.flatnonzero(rec.cp_iteration >= burn_in):
        t = int(rec.cp_iteration[s])
        if int(rec.n_materials[t]) == k:
            yield t, np.nan_to_num(rec.material_labels[s], nan=-1.0).astype(np.int64)


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


def relabelled_draws(records, burn_in: int, k: int, n_channels: int = 1) -> RelabelledDraws:
    """The draws at ``k`` materials relabelled to the reference (see the module docstring and :class:`RelabelledDraws`).

    A joint colour fit (``n_channels`` > 1) records a row per material and channel: its
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
    reference = best[1]
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
