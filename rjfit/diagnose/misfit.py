"""Where a misfit no library effect explains sits: highlight or diffuse observations, the rim,
single lights, a spatial pattern (issue 26, item 3).

When the search names nothing (or nothing more) and the final model's gap is still above
:data:`UNEXPLAINED_GAP`, the diagnosis reports an "unexplained misfit" with this description
instead of a list of effects. Each part is the gap (:mod:`rjfit.diagnose.gap`, same noise
estimate) over a subset of the observations:

- highlight: the 10 % of observations nearest the mirror direction (largest <h.n>), against
  the rest (diffuse): a lobe of another shape or a second lobe misfits there;
- rim: grazing view (<v.n> < 0.3, more than 72.5 degrees from the normal), against the
  interior: Fresnel, masking and a rough surface's retro-reflection live there;
- per light: the lights carrying the most excess (a miscalibrated or misplaced light);
- spatial pattern: the lag-1 correlation of the per-pixel mean standardised residual (over
  lights), horizontally and vertically; white noise gives ~0, a smooth misfit (shading-like,
  an indirect light, a wrong normal field) gives a large value.
"""
from __future__ import annotations

import numpy as np

from rjfit.data.observations import RIM_COS
from rjfit.diagnose.document import gap_text
from rjfit.diagnose.gap import gap, gap_breakdown

__all__ = ["UNEXPLAINED_GAP", "HIGHLIGHT_FRACTION", "RIM_COS", "describe_misfit"]

#: a final gap above this with no qualifying effect is an unexplained misfit (0.1: a misfit
#: carrying a tenth of the noise power; the gap's own sampling error is ~sqrt(2 / N), far below)
UNEXPLAINED_GAP = 0.1
HIGHLIGHT_FRACTION = 0.1
#: a part "concentrates" the misfit when its gap is at least this many times the rest's
CONCENTRATION = 2.0


def _lag1(image) -> float | None:
    """Mean lag-1 correlation of a map (H, W) with NaN off the object, over rows and columns."""
    rhos = []
    for first, second in ((image[:, :-1], image[:, 1:]), (image[:-1, :], image[1:, :])):
        keep = np.isfinite(first) & np.isfinite(second)
        if keep.sum() > 2 and np.std(first[keep]) > 0 and np.std(second[keep]) > 0:
            rhos.append(float(np.corrcoef(first[keep], second[keep])[0, 1]))
    return float(np.mean(rhos)) if rhos else None


def _split(residuals, sigma2_hat, inside) -> tuple:
    """(gap over ``inside``, gap over the rest), None where a part is empty."""
    return tuple(gap(residuals[part], sigma2_hat) if part.any() else None for part in (inside, ~inside))


def describe_misfit(ctx, residuals, sigma2_hat) -> dict:
    """Where the misfit of ``residuals`` (standardised, of the final model on ``ctx``) sits.

    Returns
    -------
    dict
        ``gap``; ``highlight`` and ``diffuse``, ``rim`` and ``interior`` gaps; ``worst_lights``
        (up to three ``{"light", "gap", "share_of_excess"}``); ``spatial_lag1`` (None when the
        map is too small); ``where`` (the parts that concentrate it) and ``text``, one sentence.
    """
    residuals = np.asarray(residuals, float)
    total = gap(residuals, sigma2_hat)
    highlight = ctx.cos_hn >= np.quantile(ctx.cos_hn, 1.0 - HIGHLIGHT_FRACTION)
    gap_highlight, gap_diffuse = _split(residuals, sigma2_hat, highlight)
    gap_rim, gap_interior = _split(residuals, sigma2_hat, ctx.cos_vn < RIM_COS)
    per_light = gap_breakdown(ctx, residuals, sigma2_hat)["per_light"]
    excess = np.array([(g or 0.0) * np.count_nonzero(ctx.light == light) for light, g in enumerate(per_light)])
    positive = np.clip(excess, 0.0, None)
    order = np.argsort(-positive)[:3]
    worst = [{"light": int(light), "gap": per_light[light],
              "share_of_excess": float(positive[light] / positive.sum()) if positive.sum() > 0 else None}
             for light in order if positive[light] > 0]
    lag1 = _lag1(ctx.per_pixel_mean(residuals) / np.sqrt(sigma2_hat))
    where = []
    for name, part, rest in (("highlight", gap_highlight, gap_diffuse), ("diffuse", gap_diffuse, gap_highlight),
                             ("rim", gap_rim, gap_interior), ("interior", gap_interior, gap_rim)):
        if part is not None and rest is not None and part > CONCENTRATION * max(rest, 0.0) and part > UNEXPLAINED_GAP:
            where.append(name)
    fair_share = 1.0 / max(ctx.n_lights, 1)
    if worst and worst[0]["share_of_excess"] is not None and worst[0]["share_of_excess"] > 3.0 * fair_share:
        where.append(f"light {worst[0]['light']}")
    if lag1 is not None and lag1 > 0.3:
        where.append("spatially smooth")
    return {"gap": total, "highlight": gap_highlight, "diffuse": gap_diffuse, "rim": gap_rim,
            "interior": gap_interior, "worst_lights": worst, "spatial_lag1": lag1, "where": where,
            "text": _text(total, gap_highlight, gap_diffuse, gap_rim, gap_interior, worst, lag1, where)}


def _fmt(value) -> str:
    return "n/a" if value is None else gap_text(value)     # every gap as the diagnosis writes it


def _text(total, gap_highlight, gap_diffuse, gap_rim, gap_interior, worst, lag1, where) -> str:
    lights = ", ".join(f"{w['light']} ({w['share_of_excess']:.0%})" for w in worst if w["share_of_excess"] is not None)
    located = ", ".join(where) if where else "spread over the observations (no part concentrates it)"
    # no grazing observation: the fit left the rim out (--max-view-angle, --preset measured), or there is none
    rim = (f"rim (grazing view) {_fmt(gap_rim)} vs interior {_fmt(gap_interior)}" if gap_rim is not None else
           "no observation at a grazing view (the rim left out of the fit, or none)")
    return (f"unexplained misfit (gap {_fmt(total)}): {located}. Gap on highlight observations {_fmt(gap_highlight)} "
            f"vs diffuse {_fmt(gap_diffuse)}; {rim}; "
            f"lights carrying most of the excess: {lights or 'none'}; lag-1 correlation of the mean residual map "
            f"{_fmt(lag1)} (about 0 for white noise)")
