"""What the data say across a pair of pixels without a boundary there: the edge term's no-step baseline
(:mod:`rjfit.sampler.regions.materials.edges`), and the lookups the pairs are built with.

A pair's no-step misfit is a constant of the data, computed once per fit: the data follow one material fitted to
every observation up to a residual that changes smoothly, with the pair's local gain integrated out where the
term has one.
"""
from __future__ import annotations

import numpy as np

from rjfit.sampler.regions.materials.passes.edges import pairs_misfit

__all__ = ["no_step_sums", "observation_lookup", "seen_between", "NO_STEP_NOISE"]

#: white noise of variance v gives a difference across a pair the variance 2 v and its misfit against the local trend
#: of the differences beside it 5 v (1.5^2 + 1.5^2 + 0.5^2 + 0.5^2): the factor that makes the two alike, so that a
#: boundary through smooth data earns nothing on average from the noise
NO_STEP_NOISE = 2.0 / 5.0


def observation_lookup(pixel, light):
    """``find(wanted_pixel, wanted_light)``: the index of the observation of each (pixel, light) among the
    observations' ``pixel`` and ``light``; -1 where there is none (a pixel off the image, negative, off the object
    or left out under that light). The observations are sorted once, then looked up as often as needed."""
    pixel, light = np.asarray(pixel, np.int64), np.asarray(light, np.int64)
    n_lights = int(light.max(initial=-1)) + 1
    key = pixel * n_lights + light
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]

    def find(wanted_pixel, wanted_light):
        wanted = np.asarray(wanted_pixel, np.int64) * n_lights + np.asarray(wanted_light, np.int64)
        if sorted_key.size == 0:
            return np.full(wanted.shape, -1, np.int64)
        at = np.minimum(np.searchsorted(sorted_key, wanted), sorted_key.size - 1)
        return np.where((sorted_key[at] == wanted) & (np.asarray(wanted_pixel) >= 0), order[at], -1)
    return find


def seen_between(has_data, start, end, gap: int) -> np.ndarray:
    """Per (``start``, ``end``): whether every pixel strictly between the two (``gap`` px apart along a row or a
    column, ``end`` after ``start``) has data (``has_data``, per flat pixel: at least one observation).

    Why: the edge term reads the data's difference across a pair (and the trend just beside it) as a change of the
    surface's reflectance between its ends. A pixel between them without any observation (off the object: a gap in
    the mask; every observation left out: the depth step of an occluding contour, a band at a grazing view) is
    where the fit does not know the surface, so a step across it may be a change of the geometry (another part of
    the object behind a contour) rather than of the paint, and the pair says nothing about a paint (issue 45:
    psm-horse's pixels beside its contours became a material of their own). A pixel between left out under some
    lights only still shows the surface there under the others; both ends are measured under each matched light.
    """
    start, end = np.asarray(start, np.int64), np.asarray(end, np.int64)
    unit = (end - start) // gap         # 1 along a row, the row's width down a column
    seen = np.ones(start.shape, bool)
    for k in range(1, gap):
        seen &= has_data[start + k * unit]
    return seen


def no_step_sums(problem, first, second, n_right: int, gap: int, i, j, start, residual, spread,
                 chunk: int = 65536, light=None, weight=None, prediction=None, gain=None) -> np.ndarray:
    """(P,) each pair's sum over its matched lights of the squared misfit of "no step": the data follow the
    reference (one material fitted to every observation: ``residual``, per observation, is the data minus it) up
    to a residual that changes smoothly, so the residuals' difference across the pair continues the trend of
    their differences just outside it along the same line.

    With e the residual and p' and q' ``gap`` px beyond p and q, seen under that light: the trend is
    ``(e_p' - e_p + e_q - e_q') / 2`` and the misfit ``(e_p - e_q - trend)^2`` is scaled by
    :data:`NO_STEP_NOISE`; with one of them, the trend is that side's difference and the scale ``2 / 6`` (the same
    white-noise reasoning); with neither (a pair at the object's edge), the misfit is ``spread^2``, what a
    difference misfits by under white noise alone, so such a pair earns only where the materials' step fits
    better than noise would. Why the residuals, not the data: the reference carries the surface's own shading
    (normals that change from pixel to pixel included), so only a change of reflectance is left to step. A
    constant of the data: the baseline a boundary's step must beat to earn.

    A joint colour fit passes ``light`` (each observation's light and channel as one index, so that a pair's
    neighbours are looked up in its own channel), ``spread`` per match (its channel's) and ``weight`` per match
    (its channel's ``1 / s_c^2``), which scales each match's misfit; one channel: the problem's lights, one
    spread, unweighted.

    With ``gain`` (tau^2, unit; tau > 0) and the reference's ``prediction`` per observation, the pair's local gain
    is integrated out of no step as of the materials' hypotheses (module docstring, "The local gain"): the
    reference's own difference ``delta`` scaled by ``1 + e``, so each misfit ``x`` becomes ``x - e delta`` under
    its scale (:func:`rjfit.sampler.regions.materials.passes.edges.pair_misfit`); a match without a trend
    (``spread^2``) holds no gain. Without it, no step would be the one hypothesis that cannot follow a local error
    of the shading, and a boundary anywhere would earn what the gain fits (psm-cat: shading parts and shadowed
    creases became materials).
    """
    light_of, e = np.asarray(problem.light if light is None else light, np.int64), np.asarray(residual, np.float64)
    find = observation_lookup(problem.pixel, light_of)
    has_data = np.diff(problem.pixel_start) > 0
    sums = np.zeros(first.size)
    for lo in range(0, first.size, chunk):      # pairs a chunk at a time: memory stays near the matches' own
        hi = min(lo + chunk, first.size)
        pair = np.repeat(np.arange(lo, hi), np.diff(start[lo:hi + 1]))
        matches = slice(start[lo], start[hi])
        misfit, x, c, trend = _no_step_misfit(problem, first[pair], second[pair], pair < n_right, gap, i[matches],
                                              j[matches], light_of[i[matches]], e,
                                              spread if np.ndim(spread) == 0 else spread[matches], find, has_data)
        if weight is not None:
            misfit = misfit * weight[matches]
            c = c * weight[matches]
        ss = np.bincount(pair - lo, weights=misfit, minlength=hi - lo)
        if gain is None or gain[0] <= 0:
            sums[lo:hi] = ss
            continue
        # the matches with a trend only: one without holds no gain
        delta = np.asarray(prediction, np.float64)[i[matches]] - np.asarray(prediction, np.float64)[j[matches]]
        trend_c = np.where(trend, c, 0.0)
        rd = np.bincount(pair - lo, weights=trend_c * x * delta, minlength=hi - lo)
        dd = np.bincount(pair - lo, weights=trend_c * delta * delta, minlength=hi - lo)
        sums[lo:hi] = pairs_misfit(ss, rd, dd, np.asarray(gain, np.float64))
    return sums


def _no_step_misfit(problem, p, q, horizontal, gap: int, i, j, light, e, spread: float, find, has_data):
    """Per match (pair ends p, q; observations i, j under ``light``) the no-step misfit of :func:`no_step_sums`,
    ``c x^2``, with ``x``, ``c`` and whether the match has a trend (``has_data``: per flat pixel, whether it has an
    observation); a match without one has ``x = spread`` and ``c`` 1."""
    height, width = problem.height, problem.width
    step = np.where(horizontal, gap, gap * width)
    p_inside = np.where(horizontal, p % width >= gap, p >= gap * width)
    q_inside = np.where(horizontal, q % width < width - gap, q < (height - gap) * width)
    before = find(np.where(p_inside, p - step, -1), light)
    after = find(np.where(q_inside, q + step, -1), light)
    # a side with a pixel without data between it and the pair gives no trend (seen_between)
    before = np.where((before >= 0) & seen_between(has_data, np.where(p_inside, p - step, p), p, gap), before, -1)
    after = np.where((after >= 0) & seen_between(has_data, q, np.where(q_inside, q + step, q), gap), after, -1)
    d, d_before, d_after = e[i] - e[j], e[before] - e[i], e[j] - e[after]
    has_before, has_after = before >= 0, after >= 0
    cases = [has_before & has_after, has_before, has_after]
    x = np.select(cases, [d - 0.5 * (d_before + d_after), d - d_before, d - d_after], spread)
    misfit = np.select(cases, [NO_STEP_NOISE * (d - 0.5 * (d_before + d_after)) ** 2, (d - d_before) ** 2 / 3.0,
                               (d - d_after) ** 2 / 3.0], spread ** 2)
    return misfit, x, np.select(cases, [NO_STEP_NOISE, 1.0 / 3.0, 1.0 / 3.0], 1.0), has_before | has_after
