"""Whether the data show an edge where two materials meet: a check of a material fit's MAP boundaries.

A change of paint is a step in the data between neighbouring pixels, under every light. A region
that one material's misfit bought (the lobe's shape, the normals' error, a light's fall-off
across the object: docs/results/measured-data.md, "What the ball's split is") has no such step: the
misfit is smooth, so neighbours across the boundary differ as neighbours inside a material do,
and the two materials' predictions, which jump there, fit those differences worse than either
material alone. The tempered likelihood of the fit cannot tell the two apart (each pixel counts
alone); the neighbours' differences can, since they cancel what varies smoothly.

For materials j and k adjacent in the MAP labels, over their boundary pairs (p in j, q in k, 3 px
apart along a row or a column: :data:`EDGE_GAP`) and every light that lit both:

    d = y_p - y_q,  SS_two = sum (d - (mu_j(p) - mu_k(q)))^2,
    SS_one = min over m in {j, k} of sum (d - (mu_m(p) - mu_m(q)))^2,

and ``log_likelihood_ratio = (SS_one - SS_two) / (2 s_d^2)``, ``s_d^2`` the mean of the same squared
difference residuals over pairs inside materials. Above ``log 100`` (:data:`EDGE_LOG_ODDS`): the data
step where the materials meet (an edge); below ``-log 100``: they do not (no edge); between: the
pairs do not decide (a contact of a few pixels, two fits of one paint). ``mu`` is each labelled
material's least-squares Lambert + Blinn fit on the plain forward model (:func:`least_squares_params`;
effects left out): a check of the labels, which holds where chains that disagree leave pooled
posterior means that no chain holds.
"""
from __future__ import annotations

import numpy as np

from rjfit.data.pixelfit import group_params
from rjfit.model.blinn import blinn_normalisation
from rjfit.sampler.regions.materials.edges import EDGE_GAP, matched_lights, pixel_pairs

__all__ = ["boundary_support", "least_squares_params", "unsupported_boundary_warnings", "edge_groups",
           "edge_group_count", "edge_verdict", "EDGE_GAP", "INSIDE_PAIRS", "FIT_OBSERVATIONS",
           "EDGE_LOG_ODDS"]

#: a boundary is an edge when the data favour the materials' step over either material alone by odds above 100:1
#: ("decisive" on Jeffreys' scale, the odds the measured preset's Potts rule asks of a further material), and no
#: edge when they favour either material alone by as much; two materials fitted to one paint read log ratios of
#: -1 to +2 (their fits' own noise; tests/posterior/test_boundaries.py), and two discs of different paints that
#: touch at one pixel -0.8 to +0.2 over their 2 or 3 pairs: a threshold of 0 decides both by chance
EDGE_LOG_ODDS = float(np.log(100.0))
#: pairs inside materials that estimate the differences' noise (every n-th of them, n chosen to keep about this many)
INSIDE_PAIRS = 20000
#: :func:`edge_group_count` fits each material by least squares on every n-th of its observations, n chosen to keep
#: about this many: two amplitudes and an exponent are settled long before a material of the ball's 1.3 million
#: observations, and a small material (a speck of a few pixels) keeps all of its own
FIT_OBSERVATIONS = 50_000


def _matched(pixel, light, first, second, gap: int):
    """Observation indices (i, j) of every light seen by both pixels of each pair (and the pixels between them,
    ``gap`` apart: :func:`~rjfit.sampler.regions.materials.edges.matched_lights`), and the pair of each match."""
    i, j, start = matched_lights(pixel, light, first, second, gap)
    return i, j, np.repeat(np.arange(first.size), np.diff(start))


def _prediction(params, C, log_cos_hn, index):
    """mu of observations ``index`` under one material's (I0, kd, gamma)."""
    I0, kd, gamma = params
    lobe = I0 * (1.0 - kd) * blinn_normalisation(gamma) * np.exp(gamma * log_cos_hn[index])
    return C[index] * (I0 * kd / np.pi + lobe)


def least_squares_params(labels, y, C, log_cos_hn, pixel) -> np.ndarray:
    """(K, 3): each material of ``labels``' (I0, kd, gamma) from one Lambert + Blinn least-squares fit over its
    observations (:func:`rjfit.data.pixelfit.fit_groups`: amplitudes unconstrained, gamma on a grid refined by
    golden section); NaN for a material without a fit. ``I0 kd`` and ``I0 (1 - kd)`` are the fit's two
    amplitudes, so the prediction is the fit's even where an amplitude is negative."""
    n_materials = int(np.max(labels, initial=-1)) + 1
    group = np.asarray(labels).ravel()[np.asarray(pixel, np.int64)]
    labelled = group >= 0
    return group_params(np.asarray(y)[labelled], np.asarray(C)[labelled], np.asarray(log_cos_hn)[labelled],
                        group[labelled], n_materials)[:, :3]


def boundary_support(labels, params, y, C, log_cos_hn, pixel, light, n_lights: int, gap: int = EDGE_GAP) -> list:
    """Per pair of adjacent materials of ``labels``: whether the data step where they meet (module docstring).

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        MAP material per pixel, -1 where no pixel is labelled.
    params : ndarray, shape (K, 3), or None
        Each material's (I0, kd, gamma); None: :func:`least_squares_params`.
    y, C, log_cos_hn : ndarray, shape (N,)
        Observations and their columns (``E <l.n>``, ``log <h.n>``), on one scale (the fit's
        problem divides both y and C by the known noise scales).
    pixel, light : ndarray of int, shape (N,)
        Each observation's flat pixel and light.
    n_lights : int
        The stack's number of lights (unused: pairs are matched by each observation's light).
    gap : int
        How far apart the pixels of a pair lie (:data:`EDGE_GAP`).

    Returns
    -------
    list of dict
        ``materials`` [j, k], ``pairs`` (boundary pairs), ``observations`` (matched lights over them),
        ``log_likelihood_ratio`` and ``step_explained`` (``1 - SS_two / SS_one``); empty with one
        material or no matched observation.

    Raises
    ------
    ValueError
        If the observation arrays differ in length or a label has no row of ``params``.
    """
    labels = np.asarray(labels)
    arrays = [np.asarray(a) for a in (y, C, log_cos_hn, pixel, light)]
    if len({a.shape for a in arrays}) != 1:
        raise ValueError("y, C, log_cos_hn, pixel and light must have one entry per observation")
    params = least_squares_params(labels, y, C, log_cos_hn, pixel) if params is None else np.asarray(params, float)
    if labels.max(initial=-1) >= len(params):
        raise ValueError(f"labels name material {labels.max()}, but params has {len(params)} rows")
    y, C, log_cos_hn = (a.astype(np.float64) for a in arrays[:3])
    pixel, light = arrays[3].astype(np.int64), arrays[4].astype(np.int64)
    first, second, _ = pixel_pairs(labels >= 0, gap)
    flat = labels.ravel()
    across = flat[first] != flat[second]
    if not np.any(across):
        return []
    inside = np.flatnonzero(~across)
    inside = inside[::max(1, inside.size // INSIDE_PAIRS)]
    # the differences' noise: pairs inside materials, each at its material
    a, b, which = _matched(pixel, light, first[inside], second[inside], gap)
    material = flat[first[inside]][which]
    residual = np.zeros(a.size)
    for m in np.unique(material):
        sel = material == m
        residual[sel] = (y[a[sel]] - y[b[sel]]) - (_prediction(params[m], C, log_cos_hn, a[sel])
                                                     - _prediction(params[m], C, log_cos_hn, b[sel]))
    noise = float(np.mean(residual ** 2)) if residual.size else np.nan
    a, b, which = _matched(pixel, light, first[across], second[across], gap)
    j_of, k_of = flat[first[across]][which], flat[second[across]][which]
    low, high = np.minimum(j_of, k_of), np.maximum(j_of, k_of)
    pair_of = np.flatnonzero(across)[which]
    rows = []
    for j, k in sorted(set(zip(low.tolist(), high.tolist()))):
        sel = (low == j) & (high == k)
        row = _step_fit(params, C, log_cos_hn, j, k, a[sel], b[sel], j_of[sel], y[a[sel]] - y[b[sel]], noise)
        rows.append({"materials": [int(j), int(k)], "pairs": int(np.unique(pair_of[sel]).size), **row})
    return rows


def _step_fit(params, C, log_cos_hn, j, k, first, second, first_material, step, noise) -> dict:
    """The log-likelihood ratio and share explained of the materials' step against either material alone, over
    matched observations (``first`` in ``first_material``, ``second`` in the other of j, k)."""
    two, one_j, one_k = np.empty(first.size), np.empty(first.size), np.empty(first.size)
    for m_a, m_b in ((j, k), (k, j)):         # p in m_a, q in m_b
        s = first_material == m_a
        mu_p = _prediction(params[m_a], C, log_cos_hn, first[s])
        mu_q = _prediction(params[m_b], C, log_cos_hn, second[s])
        two[s] = mu_p - mu_q
        same_as_p = mu_p - _prediction(params[m_a], C, log_cos_hn, second[s])
        same_as_q = _prediction(params[m_b], C, log_cos_hn, first[s]) - mu_q
        one_j[s], one_k[s] = (same_as_p, same_as_q) if m_a == j else (same_as_q, same_as_p)
    ss_two = float(np.sum((step - two) ** 2))
    ss_one = min(float(np.sum((step - one_j) ** 2)), float(np.sum((step - one_k) ** 2)))
    return {"observations": int(first.size), "log_likelihood_ratio": (ss_one - ss_two) / (2.0 * noise),
            "step_explained": 1.0 - ss_two / ss_one if ss_one > 0 else float("nan")}


def edge_verdict(row) -> str:
    """A row of :func:`boundary_support` read at odds of 100:1 (:data:`EDGE_LOG_ODDS`): ``"edge"``, ``"no edge"``
    or ``"undecided"`` (between, or NaN)."""
    ratio = row["log_likelihood_ratio"]
    return "edge" if ratio > EDGE_LOG_ODDS else "no edge" if ratio < -EDGE_LOG_ODDS else "undecided"


def unsupported_boundary_warnings(rows) -> list:
    """A warning per pair of materials whose boundary the data show not to be an edge (:func:`edge_verdict`)."""
    return [f"materials {j} and {k} meet where the data show no edge: across their {row['pairs']} boundary pairs a "
            f"step between their predictions fits the neighbours' differences worse than either material alone (log "
            f"likelihood ratio {row['log_likelihood_ratio']:.3g}, below -log 100), so the boundary follows the "
            f"model's smooth misfit rather than a change of paint; read them as one material unless `rjfit diagnose` "
            f"closes the gap (docs/materials.md, 'Boundaries')"
            for row in rows for j, k in [row["materials"]] if edge_verdict(row) == "no edge"]


def edge_groups(rows, n_materials: int) -> list:
    """The materials 0 .. n_materials - 1 joined wherever :func:`boundary_support`'s ``rows`` show no edge
    (:func:`edge_verdict`; an undecided boundary joins nothing): each group's materials in order, the groups by
    their first."""
    parent = list(range(n_materials))

    def root(m):
        while parent[m] != m:
            m = parent[m]
        return m
    for row in rows:
        if edge_verdict(row) == "no edge":
            j, k = row["materials"]
            parent[root(j)] = root(k)
    groups = {}
    for m in range(n_materials):
        groups.setdefault(root(m), []).append(m)
    return sorted(groups.values())


def edge_group_count(labels, y, C, log_cos_hn, pixel, light, n_lights: int) -> int:
    """How many groups the materials of one label map form once those that meet where the data show no edge are
    joined (:func:`edge_groups`).

    ``labels`` may number its materials with gaps (a state's labels); -1 or NaN marks unlabelled
    pixels. A group whose materials hold no observation (pixels labelled by their neighbours
    alone, such as the rim under ``--max-view-angle``) is not counted. Each material's fit is
    :func:`least_squares_params` on every n-th of its observations (:data:`FIT_OBSERVATIONS` per
    material); the check itself (:func:`boundary_support`) uses every pair.
    """
    labels = np.asarray(labels, dtype=float)
    labels = np.where(np.isfinite(labels), labels, -1).astype(np.int64)
    present = np.unique(labels[labels >= 0])
    if present.size < 2:
        return int(present.size)
    compact = np.where(labels >= 0, np.searchsorted(present, labels), -1)
    group = compact.ravel()[np.asarray(pixel, np.int64)]
    subset = np.concatenate([members[::max(1, members.size // FIT_OBSERVATIONS)]
                             for members in (np.flatnonzero(group == m) for m in range(present.size))])
    params = least_squares_params(compact, *(np.asarray(a)[subset] for a in (y, C, log_cos_hn, pixel)))
    rows = boundary_support(compact, params, y, C, log_cos_hn, pixel, light, n_lights)
    fitted = np.all(np.isfinite(params), axis=1)
    return sum(1 for members in edge_groups(rows, int(present.size)) if np.any(fitted[members]))
