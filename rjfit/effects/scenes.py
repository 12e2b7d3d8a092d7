"""A criticism context's fitted model in Mitsuba: the scene to render it on and the indirect-light
feature (interreflection's, :mod:`rjfit.effects.interreflection`; the posterior predictive
simulation's scene, :mod:`rjfit.diagnose.simulate`).

The rendering is the render layer's (:mod:`rjfit.render.effect_scenes`); what is per context
stays here: the data set and segmentation it renders, the mesh cut by region (once per
context, cached in ``ctx.features``), the diagnosis' seed, and the Monte Carlo error kept
beside the feature.
"""
from __future__ import annotations

from rjfit.render.effect_scenes import region_materials, region_parts, render_indirect

__all__ = ["model_scene", "indirect_radiance"]


def model_scene(ctx, region_params):
    """The data set to render the fitted model on, and its materials (``{I0, kd, gamma}``).

    The mesh is cut into one part per fit region (:func:`rjfit.render.effect_scenes.region_parts`,
    once per context), each region's parameters its material, so Mitsuba renders the fitted model
    and not the data's own materials: a rendered data set's mesh parts are cut along the fit's
    regions inside each part (a part that one region covers stays whole), a measured mesh stack's
    one mesh by the regions alone. (Giving each true part its majority region's parameters instead
    would render a fit of 8 regions on 4 parts as a fit of 4, and its gap would measure the
    segmentation, with the truth's outlines, not a missing effect.)
    """
    dataset, _ = ctx.feature("region_parts", lambda: region_parts(ctx.dataset, ctx.labels))
    return dataset, region_materials(region_params)


def indirect_radiance(ctx, region_params, *, spp=32, max_depth=8, seed=None, batches=8):
    """Mitsuba's indirect radiance of the fitted model per light: path(max_depth) - path(2).

    ``seed`` defaults to the diagnosis' seed (``ctx.seed``).

    Returns the (L, H, W) mean; its Monte Carlo standard error (from ``batches`` independent
    batches) is kept in ``ctx.features["indirect_se"]``.
    """
    dataset, materials = model_scene(ctx, region_params)
    indirect, se = render_indirect(dataset, materials, seed=ctx.seed if seed is None else seed, spp=spp,
                                   max_depth=max_depth, batches=batches)
    ctx.features["indirect_se"] = se
    return indirect
