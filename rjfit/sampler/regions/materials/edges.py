"""The edge term of the material model's target: a boundary must be a step in the data.

Why
---
A tempered, pixel-independent likelihood cannot tell a change of paint from a material's
smooth misfit (the lobe's shape, the normals' error, a light's fall-off across the object):
a split along the misfit gains as much as a pebble (docs/results/measured-data.md, "What the ball's
split is"). Neighbours' differences can, since they cancel what varies smoothly: where two
materials meet, the data step as the two materials' predictions do if the paint changes
there, and not at all if the boundary follows the misfit.

The term
--------
Over pairs of labelled pixels ``gap`` px apart along a row or a column (:data:`EDGE_GAP`, odd),
and every light seen by both (the data's difference ``d = y_p - y_q``, on the fit's scale), where every
pixel between the two has data (:func:`~rjfit.sampler.regions.materials.edge_baseline.seen_between`: a pair
across a pixel off the object or with every
observation left out, such as an occluding contour's, does not see what lies between its ends),
with

    SS_pq(a, b) = sum over the lights (d - mu_a(p) + mu_b(q))^2,

the boundary between materials k and m (the pairs with one end in each) adds

    Phi_km = power (min(SS_kk, SS_mm, SS_0) - SS_km) / (2 s^2),

``SS_km`` the sum over its pairs of SS with each end in its own material, ``SS_kk`` and
``SS_mm`` with both ends in k, or in m, and ``SS_0`` the misfit of **no step**
(:func:`~rjfit.sampler.regions.materials.edge_baseline.no_step_sums`):
the data follow the reference fit (one material) up to a smoothly changing residual, so each
residual difference across the pair continues the trend of the residual differences just
outside it along its line (p', q' ``gap`` px beyond p and q), scaled by
:data:`~rjfit.sampler.regions.materials.edge_baseline.NO_STEP_NOISE`
so that white noise weighs alike in both. Phi is the Gaussian log-likelihood ratio of the
neighbours' differences under the materials' step against the best explanation without a boundary
there: one material across it, or the data's own trend. A boundary where the data step beyond
their own trend, as its materials do, **earns** (a paint's outline: the step is many times the
differences' spread); one whose step explains the differences no better than one material, or
no better than the data's trend, **costs** what it misfits beyond them (a shading band's edge, a
boundary off the step); pairs inside one material add nothing.

Why it earns: a misfit shared by neighbouring pixels makes the pixel term count a region's
interior at a small power, but a sharp step is evidence that misfit cannot fake, and the pixel
term cannot carry it (issue 45: the cat's nose, 1,500 px, was never a material without it).
Why the data's own trend in the baseline, not only a fitted material: two materials each fitted
to its side of a smooth but misfitted gradient (the ball's limb at 16 bits) explain the
differences across any line between them a little better than either alone, though the data do
not step there. Against either material alone only, such a line neither costs nor earns, and
once the materials' parameters follow their parts (the edge walks), the pixel term's gain from
shading parts decides: on the DiLiGenT ball the chain started with 4 materials kept 3 shading
parts, the pixel term +2,432 above a one-material chain's against the Potts prior's -1,785, their
boundaries' term +174 (docs/results/2026-11-28-trend-cost.md). Against the trend such a line costs what the one
material misfits the data's gradient along it.
``SS_0`` is a constant of the data, so it bounds the term above by ``power SS_0 / (2 s^2)``
whatever the parameters: the target stays proper. ``s^2`` is the robust variance (1.4826 MAD, squared) of
the differences' residuals under the reference (one material fitted by least squares to every
observation): a constant of the data. ``power``: the coarsening rule of
:func:`rjfit.data.coarsen.suggest_likelihood_power` applied to those residuals
(:func:`edge_power`; ``((1 - rho) / (1 + rho))^2``, rho their lag-1 correlation between
neighbouring pairs under one light), since the differences, though they cancel most of a
smooth misfit, keep some of its gradient.

The local gain
--------------
A measured surface's shading is off by a local factor that changes slowly over it (the given normals' error,
a lobe shape the model lacks, light that a fold adds): a pair's two ends, 3 px apart, share it, and it scales
the whole step, ``d = (1 + e) (mu_a(p) - mu_b(q))``. Without it a material's parameters must fit the step of its
own outline's place: two patches of one paint where the shading is off by different factors are then two
materials (a boundary fits each patch's step better by what that factor's difference misfits, 127 to 150 nats
for two painted discs on psm-horse, against a prior that pays 17 for one material fewer), and a material beside
an occluding contour, where the shading changes fast, earns by fitting the gain there (psm-horse's strip:
docs/results/2026-11-28-local-gain.md). So each pair's ``e ~ N(0, tau^2)`` is integrated out of each of its
hypotheses (the step, either material alone; :func:`rjfit.sampler.regions.materials.passes.edges.pair_misfit`):
what is left to earn is the step's shape over the lights and its size beyond the gain's spread. The
no-step baseline is unchanged (its trend already follows what changes slowly). ``tau`` is measured once on the
data (:func:`rjfit.sampler.regions.materials.edge_gain.shared_gain_sd`); 0 gives the term above.

The differences' noise
----------------------
On measured stacks a difference's misfit grows with how much the shading changes across its pair and how fast the
geometry turns there (the given normals' error, a lobe the model lacks, light from nearby surfaces), up to tens of
times its variance on flat, evenly lit parts: on one scale, pairs beside folds and occluding contours weigh as much
as a flat paint outline's, and a fold's step buys a material (psm-horse). With ``noise='measured'`` each match has
its own variance ``s^2 v``, ``v = a + b g^2 + c t^2`` measured once on the data
(:mod:`rjfit.sampler.regions.materials.edge_noise`: ``g`` the reference's predicted difference, ``t`` the pair's turn
as its lights see it), and every sum above weighs each match by ``1 / v``: the Gaussian log-likelihood ratio of
heteroscedastic differences. The matches' differences and columns are divided by ``sqrt(v)`` once, when the term is
built, so that the compiled passes are unchanged (the local gain's integral with them is the heteroscedastic one);
the no-step baseline weighs its matches alike. 'auto' power is measured on the differences' misfits as they are.

The moves (each stays exact for the new target)
-----------------------------------------------
- the label sweep: each pixel's Gibbs draw without the term, then a delayed acceptance of a
  new label with ``min(1, exp(delta Phi))``, the boundaries' sums updated pixel by pixel
  (:func:`rjfit.sampler.regions.materials.passes.edges.keep_new_label`);
- the cluster, segment and merge/split moves: ``delta Phi`` of the proposal in their log ratio
  (the one test of a proposal, :func:`rjfit.sampler.moves.base.decide`);
- a material's parameter moves: ``delta Phi`` of its new (I0, kd, gamma) in their log ratio
  (:func:`rjfit.sampler.moves.region_terms.edge_delta`; sigma^2 does not enter the term).

The term pins a material's parameters wherever its boundaries do not step (a shift of 1 %
in its prediction changes the sums by thousands), so its parameter moves, proposed without
the term, are rejected there: a chain started from parameters far from its start labels'
(the dispersed draws) can stay where it started. Chains with the term start every material
at its least-squares fit (:func:`start_theta`). For one channel without effects only (the
term reads the plain forward model's prediction).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from rjfit.data.pixelfit import fit_groups, group_params
from rjfit.sampler.colour import guide_rows, pixel_set_data
from rjfit.sampler.passes.densities import coefficients
from rjfit.sampler.regions.materials.edge_baseline import no_step_sums, observation_lookup, seen_between
from rjfit.sampler.regions.materials.edge_gain import shared_gain_sd
from rjfit.sampler.regions.materials.edge_noise import difference_noise, match_variance, pair_turn, valid_noise
from rjfit.sampler.regions.materials.passes.edges import (boundary_sums, changed_delta, changed_sums, changed_sums_from,
                                                          changed_value, edge_value, with_changed)

__all__ = ["EdgeTerm", "edge_term", "start_theta", "pixel_pairs", "matched_lights", "EDGE_GAP"]

#: the pixels of a pair lie this far apart (odd, so that they are of the two checkerboard colours): a measured
#: edge is spread over a pixel or two (optics, the pixel footprint, a blurred paint line), so neighbours across a
#: boundary straddle part of the step only, while a smooth misfit changes little over 3 px
EDGE_GAP = 3

#: the most matches the differences' noise is measured on (:func:`_match_noise`)
NOISE_FIT_MATCHES = 1 << 22

#: gamma of a colour material's start where its Laplace fit fails (the middle of the dispersed starts' 2 .. 30)
START_GAMMA = 8.0
#: how far inside (0, 1) a colour material's start kd is kept
KD_MARGIN = 1e-6


class EdgeTerm(NamedTuple):
    """The pairs of the edge term and their matched observations (module docstring); built by :func:`edge_term`.

    ``first``, ``second`` (P,): the pairs' flat pixels; ``start`` (P + 1,): each pair's matches;
    ``d``, ``c_first``, ``c_second``, ``l_first``, ``l_second`` (M,): per match the difference and
    both ends' ``C`` and ``log <h.n>``; ``no_step`` (P,): each pair's SS of no step
    (:func:`~rjfit.sampler.regions.materials.edge_baseline.no_step_sums`); ``pair_of`` (H W, 4):
    each pixel's pairs (-1: none); ``scale`` = power / (2 s^2); ``gap``: the pairs' pixels this far apart. Under a
    measured noise (``noise``: its fitted record), ``d`` and both ``C`` are each divided by its match's noise sd
    relative to ``s``, and ``typical_weight`` is the median of the matches' weights (1 / that sd squared; 1 under
    one scale).
    """

    power: float
    scale: float
    first: np.ndarray
    second: np.ndarray
    start: np.ndarray
    d: np.ndarray
    c_first: np.ndarray
    c_second: np.ndarray
    l_first: np.ndarray
    l_second: np.ndarray
    no_step: np.ndarray
    pair_of: np.ndarray
    channel: np.ndarray = np.zeros(0, np.int8)
    weight: np.ndarray = np.zeros(0)
    n_channels: int = 1
    gain: np.ndarray = np.zeros(2)
    noise: tuple | None = None
    typical_weight: float = 1.0
    gap: int = EDGE_GAP

    @property
    def gain_sd(self) -> float:
        """tau, the sd of the local gain integrated out of each pair (module docstring; 0: none): the given one
        (``sqrt(fl(tau^2)) = tau`` in binary floating point, so a term built again from it is this term)."""
        return float(np.sqrt(max(float(self.gain[0]), 0.0)))

    def total(self, pixels, theta, memo=None) -> float:
        """The edge term of the labels ``pixels`` (H, W; -1 unlabelled) with materials' ``theta`` (K C, 4: C rows
        per material); ``memo``: the chain's :class:`~rjfit.sampler.regions.materials.edge_memo.BoundaryMemo`
        (None: summed afresh; the same value either way)."""
        return float(edge_value(self.sums(pixels, theta, memo), self.scale))

    def sums(self, pixels, theta, memo=None) -> np.ndarray:
        """(K, K, 4) the boundaries' sums of the labels ``pixels`` with ``theta``
        (:func:`~rjfit.sampler.regions.materials.passes.edges.boundary_sums`), from ``memo`` where it has them."""
        theta = np.asarray(theta, float)
        coef = coefficients(theta)
        key = coef[:, :3]       # a / pi, b, gamma: all the term reads of a material
        sums = None if memo is None else memo.find(self, pixels, key)
        if sums is None:
            sums = boundary_sums(_flat(pixels), theta.shape[0] // self.n_channels, coef, *self._pair_arrays())
            if memo is not None:
                memo.keep(self, pixels, key, sums)
        return sums

    def _pair_arrays(self) -> tuple:
        return (self.first, self.second, self.start, self.d, self.c_first, self.c_second, self.l_first,
                self.l_second, self.no_step, self.channel, self.weight, self.n_channels, self.gain)

    def channel_scales(self) -> np.ndarray:
        """(C,) each channel's ``power / (2 s_c^2)``: what a squared misfit of that channel weighs in the term; under a
        measured noise, times the matches' typical weight."""
        scales = np.array([self.scale]) if self.n_channels == 1 else self.scale * self.weight
        return scales * self.typical_weight

    def rows_delta(self, pixels, theta, rows, new_rows, memo=None) -> float:
        """The change of the term when the parameter ``rows`` of ``theta`` become ``new_rows`` (a colour material's
        rows at a new gamma): :meth:`total`'s difference, summed over the changed materials' boundaries only.
        With ``memo`` (:meth:`total`'s) the current sums come from it and only the new ones are summed; the new
        state's sums are kept in it (the next question's current ones, if the move is accepted)."""
        theta = np.asarray(theta, float)
        new = theta.copy()
        new[list(rows)] = new_rows
        changed = np.zeros(theta.shape[0] // self.n_channels, np.bool_)
        changed[np.asarray(list(rows), np.int64) // self.n_channels] = True
        new_coef = coefficients(new)
        if memo is None:
            return float(changed_delta(_flat(pixels), changed, coefficients(theta), new_coef, *self._pair_arrays(),
                                       self.scale))
        before = self.sums(pixels, theta, memo)
        if self.n_channels == 1:      # the unchanged material alone across a boundary not summed again
            after = changed_sums_from(before, _flat(pixels), changed, new_coef, self.first, self.second, self.start,
                                      self.d, self.c_first, self.c_second, self.l_first, self.l_second, self.no_step,
                                      self.gain)
        else:
            after = with_changed(before, changed_sums(_flat(pixels), changed, new_coef, *self._pair_arrays()), changed)
        memo.keep(self, pixels, new_coef[:, :3], after)
        return float(changed_value(after, changed, self.scale) - changed_value(before, changed, self.scale))

    def region_delta(self, pixels, theta, r: int, theta_r, memo=None) -> float:
        """The change of the term when row ``r`` of ``theta`` (a material's; a joint colour fit's channel row)
        becomes ``theta_r`` (``memo``: :meth:`rows_delta`'s)."""
        return self.rows_delta(pixels, theta, [r], [theta_r], memo)

    def sweep_arrays(self, theta):
        """The ``edge`` argument of :func:`~rjfit.sampler.regions.materials.passes.labels.gibbs_sweep`."""
        return (self.pair_of, coefficients(np.asarray(theta, float)), self.first, self.second, self.start, self.d,
                self.c_first, self.c_second, self.l_first, self.l_second, self.no_step, self.scale, self.channel,
                self.weight, self.n_channels, self.gain)


def _flat(pixels) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(pixels).ravel(), dtype=np.int64)


def pixel_pairs(labelled, gap: int):
    """(p, q) of the labelled pixels ``gap`` apart along a row (q right of p), then along a column (q below), and
    the number of the first kind."""
    height, width = labelled.shape
    flat = labelled.ravel()
    p = np.arange(height * width)
    right = (p % width < width - gap) & flat & np.concatenate([flat[gap:], np.zeros(gap, bool)])
    below = np.concatenate([flat[gap * width:], np.zeros(min(gap * width, flat.size), bool)])[:flat.size]
    down = (p < (height - gap) * width) & flat & below
    return (np.concatenate([p[right], p[down]]), np.concatenate([p[right] + gap, p[down] + gap * width]),
            int(np.count_nonzero(right)))


def matched_lights(pixel, light, first, second, gap: int, chunk: int = 65536):
    """Per pair (``first[k]``, ``second[k]``, ``gap`` px apart), the observation indices (i of the first pixel, j of
    the second) of each light both saw, in the order of the lights, where every pixel between them has data
    (:func:`~rjfit.sampler.regions.materials.edge_baseline.seen_between`; else none), and the pairs' offsets into
    them: ``(i, j, start)``. ``pixel`` and
    ``light`` give each observation's; pairs are taken ``chunk`` at a time, so memory stays near the
    observations' own."""
    n_lights = int(np.max(light, initial=-1)) + 1
    find = observation_lookup(pixel, light)
    lights = np.arange(n_lights)
    has_data = np.zeros(int(max(np.max(pixel, initial=-1), np.max(second, initial=-1))) + 1, bool)
    has_data[np.asarray(pixel, np.int64)] = True

    def lookup(pixels):
        return find(np.repeat(pixels, n_lights), np.tile(lights, pixels.size)).reshape(pixels.size, n_lights)

    i_parts, j_parts, counts = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for lo in range(0, len(first), chunk):
        ends = np.asarray(first[lo:lo + chunk], np.int64), np.asarray(second[lo:lo + chunk], np.int64)
        a, b = lookup(ends[0]), lookup(ends[1])
        both = (a >= 0) & (b >= 0)
        both &= seen_between(has_data, ends[0], ends[1], gap)[:, None]     # no pixel without data between
        i_parts.append(a[both])
        j_parts.append(b[both])
        counts.append(both.sum(axis=1))
    start = np.concatenate([[0], np.cumsum(np.concatenate(counts))]).astype(np.int64)
    return np.concatenate(i_parts), np.concatenate(j_parts), start


def _coarsening_power(first, pair, n_right: int, light, n_lights: int, residual, width: int) -> float:
    """``((1 - rho) / (1 + rho))^2``, rho the lag-1 correlation of the matches' ``residual`` between neighbouring
    pairs under one light (:func:`_neighbour_correlation`), the mean of the row pairs' and the column pairs', floored
    at 0 (0 where not finite: power 1)."""
    rho = np.nanmean([_neighbour_correlation(first[pair[part]], light[part], residual[part], n_lights, width)
                      for part in (pair < n_right, pair >= n_right)])
    rho = max(0.0, float(rho)) if np.isfinite(rho) else 0.0
    return ((1.0 - rho) / (1.0 + rho)) ** 2


def _neighbour_correlation(first, light, residual, n_lights: int, width: int) -> float:
    """The lag-1 correlation of ``residual`` between pairs whose first pixels are neighbours along a row or a
    column, under one light (pairs of one direction); NaN with fewer than 3 such neighbours."""
    key = first.astype(np.int64) * n_lights + light
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    rhos = []
    for step in (1, width):
        if sorted_key.size == 0:
            break
        wanted = key + step * n_lights
        at = np.minimum(np.searchsorted(sorted_key, wanted), sorted_key.size - 1)
        hit = sorted_key[at] == wanted
        if step == 1:       # not the next row's first pixel
            hit &= first % width != width - 1
        x, z = residual[hit], residual[order[at[hit]]]
        rhos.append(float(np.corrcoef(x, z)[0, 1]) if x.size > 2 and np.std(x) > 0 and np.std(z) > 0 else np.nan)
    return float(np.nanmean(rhos)) if np.any(np.isfinite(rhos)) else np.nan


def edge_term(problem, labelled, power="auto", gap: int = EDGE_GAP, gain_sd=0.0, noise: str = "constant") -> EdgeTerm:
    """The edge term of ``problem`` over the ``labelled`` (H, W) pixels (module docstring).

    ``power``: a positive number, or 'auto' for ``((1 - rho) / (1 + rho))^2`` (rho the lag-1
    correlation of the reference's difference residuals between neighbouring pairs under one
    light, floored at 0: the coarsening rule of :func:`rjfit.data.coarsen.suggest_likelihood_power`).

    A joint colour fit (C channels) sums the term's misfits over the channels, each on its own scale: a
    pair's matches are the (light, channel) both pixels saw, the reference is one material per channel
    (its own residuals and no-step sums), and a match of channel c weighs ``power / (2 s_c^2)``, ``s_c``
    that channel's robust spread (``scale`` = power / 2, ``weight`` = 1 / s_c^2); 'auto' takes rho over
    every channel's differences, each divided by its ``s_c``. A boundary's step, either material alone and no
    step are then compared on the summed misfits, as a single channel's are.

    ``gain_sd``: tau, the sd of the local gain integrated out of each pair (module docstring, "The local gain"):
    a number >= 0 (0: none), or 'auto' for
    :func:`~rjfit.sampler.regions.materials.edge_gain.shared_gain_sd` on the reference's per-pixel gains.

    ``noise``: 'constant', every match of a channel on one scale; 'measured', each match's variance growing with
    the shading change and the geometry's turn across its pair as measured on the data (module docstring, "The
    differences' noise"; :mod:`~rjfit.sampler.regions.materials.edge_noise`); or that model's coefficients
    ``(white, shading, turn)`` as measured before (``EdgeTerm.noise``). 'auto' power is the same under either.

    Raises
    ------
    ValueError
        If ``power`` is neither positive nor 'auto', ``gain_sd`` neither a number >= 0 nor 'auto', ``noise`` not
        'constant', 'measured' or three coefficients >= 0 (white > 0), ``gap`` not odd and positive, or the problem
        has no lights per observation or has effects.
    """
    _check_arguments(problem, power, gap, gain_sd, noise)
    n_ch = problem.n_channels
    # a colour fit's matches pair (light, channel): one index for both, so each channel is matched in itself
    key_light = None if n_ch == 1 else (np.asarray(problem.light, np.int64) * n_ch
                                        + np.asarray(problem.channel, np.int64))
    first, second, n_right = pixel_pairs(np.asarray(labelled, bool), gap)
    i, j, start = matched_lights(problem.pixel, problem.light if n_ch == 1 else key_light, first, second, gap)
    y, C, lch = (np.asarray(a, np.float64) for a in (problem.y, problem.C, problem.log_cos_hn))
    group = np.zeros(y.size, np.int64) if n_ch == 1 else np.asarray(problem.channel, np.int64)
    reference_residual = fit_groups(y, C, lch, group, n_ch)["residuals"]
    d = y[i] - y[j]
    residual = reference_residual[i] - reference_residual[j]      # d minus the reference's step
    pair = np.repeat(np.arange(first.size), np.diff(start))
    channel = np.zeros(0, np.int8) if n_ch == 1 else np.asarray(problem.channel, np.int8)[i]
    spreads = _spreads(residual, channel, n_ch)
    s = spreads[0]
    weight = np.zeros(0) if n_ch == 1 else 1.0 / np.maximum(spreads, 1e-300) ** 2
    n_pix = problem.height * problem.width
    prediction = y - reference_residual
    match_spread = spreads[0] if n_ch == 1 else spreads[channel]
    noise_fit, variance = _match_noise(noise, residual, prediction[i] - prediction[j], match_spread, lch[i], lch[j],
                                       pair, first.size)
    root = 1.0 / np.sqrt(variance)       # each match on its own noise scale: scaling its difference and its columns
    if gain_sd == "auto":
        gain_sd = shared_gain_sd(y, prediction, problem.pixel, first, second, n_pix,
                                 None if n_ch == 1 else weight[np.asarray(problem.channel, np.int64)])
    unit = max(s, 1e-300) ** 2 if n_ch == 1 else 1.0      # what the pairs' sums are measured in
    gain = np.array([float(gain_sd) ** 2, unit])
    # each match's spread and weight (a colour fit's: its channel's), under its measured noise
    pair_no_step = no_step_sums(problem, first, second, n_right, gap, i, j, start, reference_residual,
                                match_spread * np.sqrt(variance), light=key_light,
                                weight=(1.0 if n_ch == 1 else weight[channel]) / variance, prediction=prediction,
                                gain=gain)
    pair_no_step[~np.isfinite(pair_no_step)] = np.inf     # no reference fit (tiny problems): no bound from it
    if power == "auto":
        every_light = np.asarray(problem.light, np.int64) if n_ch == 1 else key_light
        # the differences as they are, not over their measured sd: the power says how much of their evidence their
        # shared misfit repeats (on psm-cat the standardised ones gave 0.042 against 0.027, and two chains of four
        # split the head from the body along its shading: docs/results/2026-11-29-edge-noise.md)
        standardised = residual if n_ch == 1 else residual / np.maximum(spreads, 1e-300)[channel]
        power = _coarsening_power(first, pair, n_right, every_light[i], int(every_light.max()) + 1, standardised,
                                  problem.width)
    pair_of = _pairs_of_pixels(first, second, n_right, n_pix)
    scale = float(power) / (2.0 * max(s, 1e-300) ** 2) if n_ch == 1 else float(power) / 2.0
    return EdgeTerm(power=float(power), scale=scale, first=first.astype(np.int64),
                    second=second.astype(np.int64), start=start, d=d * root, c_first=(C[i] * root).astype(np.float32),
                    c_second=(C[j] * root).astype(np.float32), l_first=lch[i].astype(np.float32),
                    l_second=lch[j].astype(np.float32), no_step=pair_no_step, pair_of=pair_of, channel=channel,
                    weight=weight, n_channels=n_ch, gain=gain, noise=noise_fit,
                    typical_weight=float(np.median(root * root)) if root.size else 1.0, gap=int(gap))


def _match_noise(noise: str, residual, shading_change, match_spread, l_first, l_second, pair, n_pairs: int):
    """``(coefficients, variance)``: the noise model's ``(white, shading, turn)`` as given or fitted
    (:func:`~rjfit.sampler.regions.materials.edge_noise.difference_noise`; None for 'constant') and each match's
    variance relative to its channel's spread squared (ones for 'constant')."""
    if isinstance(noise, str) and noise == "constant":
        return None, np.ones(residual.size)
    spread = np.maximum(match_spread, 1e-300)
    turn = pair_turn(l_first, l_second, pair, n_pairs)[pair]
    if isinstance(noise, str):
        # at most NOISE_FIT_MATCHES evenly spaced matches measure it (a 2048 x 2048 stack has about 10^8; 10^4 per
        # cell measure its variance to about 1.5 %), so that it adds little memory beside the term's own arrays
        fit = np.linspace(0, residual.size - 1, min(residual.size, NOISE_FIT_MATCHES)).astype(np.int64)
        fit = fit[np.diff(fit, prepend=-1) > 0]     # np.unique's, without its hash (2 s on the ball): fit is sorted
        spread_fit = spread if np.ndim(spread) == 0 else spread[fit]
        fitted = difference_noise(residual[fit] / spread_fit, shading_change[fit] / spread_fit, turn[fit])
        noise = (fitted["white"], fitted["shading"], fitted["turn"])
    coefficients = tuple(float(c) for c in noise)
    return coefficients, match_variance(coefficients, shading_change / spread, turn)


def _check_arguments(problem, power, gap: int, gain_sd, noise) -> None:
    """:func:`edge_term`'s refusals (its Raises)."""
    if not valid_noise(noise):
        raise ValueError(f"the edge term's noise (--edge-noise) must be 'constant', 'measured' or three coefficients "
                         f">= 0 (white > 0), got {noise!r}")
    if power != "auto" and not (isinstance(power, (int, float)) and power > 0):
        raise ValueError(f"edge power (--edge-power) must be positive or 'auto', got {power!r}")
    if gain_sd != "auto" and not (isinstance(gain_sd, (int, float)) and np.isfinite(gain_sd) and gain_sd >= 0):
        raise ValueError(f"the edge term's gain sd (--edge-gain-sd) must be a number >= 0 or 'auto', got {gain_sd!r}")
    if gap < 1 or gap % 2 == 0:
        raise ValueError(f"the edge term's gap must be odd and positive (checkerboard colours), got {gap}")
    if problem.light is None or problem.effects is not None:
        raise ValueError("the edge term (--edge-power) needs a problem without effects, with each observation's light")


def _pairs_of_pixels(first, second, n_right: int, n_pixels: int) -> np.ndarray:
    """(n_pixels, 4) each pixel's pairs (-1: none): as the first end of a row's pair, of a column's, then as the
    second end of each."""
    pair_of = np.full((n_pixels, 4), -1, np.int64)
    ids = np.arange(first.size)
    horizontal = ids < n_right
    for slot, (ends, which) in enumerate(((first, horizontal), (first, ~horizontal), (second, horizontal),
                                          (second, ~horizontal))):
        pair_of[ends[which], slot] = ids[which]
    return pair_of


def _spreads(residual, channel, n_channels: int) -> np.ndarray:
    """(C,) the robust spread (1.4826 MAD) of the differences' residuals per channel (one channel: all of them); 1
    where there are none or it is not finite (no reference fit: the differences' own scale is moot)."""
    spreads = []
    for c in range(n_channels):
        mine = residual if n_channels == 1 else residual[channel == c]
        s = 1.4826 * float(np.median(np.abs(mine))) if mine.size else 1.0
        spreads.append(s if np.isfinite(s) else 1.0)
    return np.array(spreads)


def start_theta(problem, pixels, n_materials: int, prior) -> np.ndarray | None:
    """(K, 4) each material's least-squares (I0, kd, gamma) and mean squared residual as sigma^2 under the start
    labels ``pixels`` (H, W), where those lie inside the prior's support; None where any does not (the chain
    then starts from the usual dispersed draws). A joint colour fit: (K C, 4), each material's rows at one gamma
    (:func:`rjfit.sampler.colour.guide_rows`: gamma at its Laplace mode over the channels, each channel's
    amplitudes by least squares there)."""
    if problem.n_channels > 1:
        return _colour_start_theta(problem, pixels, n_materials, prior)
    group = np.asarray(pixels).ravel()[np.asarray(problem.pixel, np.int64)]
    keep = group >= 0
    theta = group_params(*(np.asarray(a, np.float64)[keep] for a in (problem.y, problem.C, problem.log_cos_hn)),
                         group[keep], n_materials)
    return _inside(theta, prior)


def _colour_start_theta(problem, pixels, n_materials: int, prior) -> np.ndarray | None:
    """:func:`start_theta` of a joint colour fit."""
    flat = np.asarray(pixels).ravel()
    rows = []
    for k in range(n_materials):
        fitted = guide_rows(pixel_set_data(problem, np.flatnonzero(flat == k)), prior, START_GAMMA)
        if fitted is None:
            return None
        rows.append(fitted)
    theta = np.concatenate(rows)
    # a channel without a lobe (b = 0) fits kd = 1, where the within moves' logit of kd is not defined: just inside
    theta[:, 1] = np.clip(theta[:, 1], KD_MARGIN, 1.0 - KD_MARGIN)
    return _inside(theta, prior)


def _inside(theta, prior) -> np.ndarray | None:
    """``theta`` where every row lies inside the prior's support, else None."""
    inside = all(np.all(np.isfinite(p.logpdf(theta[:, k]))) for k, p in enumerate(prior.params))
    return theta if inside else None
