"""A material fit's resolution: the smallest region of another paint that the fit would give a material of its own,
counting what its outline earns under the edge term, and its words (:mod:`rjfit.posterior.resolution` holds the rule).
"""
from __future__ import annotations

import numpy as np

from rjfit.data.formats import COLOUR_CHANNELS
from rjfit.model.blinn import radiance
from rjfit.pipeline.report_numbers import finite
from rjfit.posterior.resolution import smallest_material
from rjfit.sampler.regions.materials.edge_baseline import NO_STEP_NOISE
from rjfit.sampler.regions.materials.edges import EDGE_GAP, edge_term
from rjfit.sampler.regions.materials.layout import labelled_pixels

__all__ = ["material_resolution", "resolution_warning", "resolution_size", "resolution_sentence"]


def material_resolution(problem, materials, labels, options, term_power: float = 0.0,
                        term_noise="constant", channel_scales=None) -> dict | None:
    """The smallest region of half the albedo that the fit would give a material of its own inside its largest
    material (:func:`rjfit.posterior.resolution.smallest_material`, at that material's posterior means and on
    the plain forward model: effects are left out of the prediction), its outline's earning under the edge
    term counted where the fit has one (``term_power``, its power, > 0; ``term_noise``, its noise: a measured noise
    counts the matches' typical weight; ``channel_scales``: the term's :meth:`~rjfit.sampler.regions.materials.edges
    .EdgeTerm.channel_scales` where the caller has the term, else it is built here). A joint colour fit: half the albedo in every channel, each channel's
    observations on its own variance and edge scale."""
    if not materials:
        return None
    edge_scales = np.zeros(problem.n_channels)
    if term_power > 0:
        # the term's power / (2 s_c^2), s_c a constant of the data; an outline pair's step of S beats no step by about
        # NO_STEP_NOISE S^2 per light (edges.no_step_sums: the trend beside the pair leaves the step out)
        if channel_scales is None:
            channel_scales = edge_term(problem, labelled_pixels(problem), term_power, EDGE_GAP,
                                       noise=term_noise).channel_scales()
        edge_scales = np.asarray(channel_scales, float) * NO_STEP_NOISE
    largest = max(materials, key=lambda m: m["pixels"])
    mine = np.asarray(labels).ravel()[problem.pixel] == largest["material"]
    cos_hn = np.exp(problem.log_cos_hn[mine].astype(float))
    if problem.n_channels == 1:
        I0, kd, gamma, sigma2 = (largest[name]["mean"] for name in ("I0", "kd", "gamma", "sigma2"))
        edge_scale = float(edge_scales[0])
    else:       # per observation, its channel's rows
        channel = np.asarray(problem.channel)[mine].astype(np.int64)
        rows = [largest["channels"][name] for name in COLOUR_CHANNELS[:problem.n_channels]]
        I0, kd, sigma2 = (np.array([row[name]["mean"] for row in rows])[channel] for name in ("I0", "kd", "sigma2"))
        gamma, edge_scale = largest["gamma"]["mean"], edge_scales[channel]
    # eq. 2 on the problem's columns: C = E <l.n> (divided by the noise scales) stands for <l.n> at irradiance 1
    mu = radiance(I0, kd, gamma, problem.C[mine], cos_hn, 1.0)
    return {"material": int(largest["material"]), "likelihood_power": float(problem.likelihood_power),
            "potts_beta": float(options.potts_beta), "potts_rho": float(options.potts_rho),
            **smallest_material(mu, problem.pixel[mine], sigma2, float(problem.likelihood_power),
                                options.potts_beta, options.potts_rho, len(materials), edge_scale=edge_scale,
                                edge_gap=EDGE_GAP if term_power > 0 else 0)}


def resolution_warning(resolution: dict) -> str:
    """The caveat of a fit whose material model cannot resolve small details (``resolution`` from
    :func:`material_resolution`)."""
    return (f"materials smaller than {resolution_size(resolution)} are not resolved: a region of "
            f"{resolution['contrast']:g} times material {resolution['material']}'s albedo must be that large before its evidence (likelihood power "
            f"{resolution['likelihood_power']:.3g}) pays for its boundary (Potts beta {resolution['potts_beta']:.3g}) and the "
            f"prior odds of one more material (rho {resolution['potts_rho']:.3g}), so smaller painted details are merged into "
            f"the material around them (docs/materials.md, 'Resolution')")


def resolution_size(resolution: dict) -> str:
    """The smallest region that gets a material of its own (``resolution`` from :func:`material_resolution`), in
    words: a single pixel where the evidence per pixel is so high that any one pays for its boundary."""
    if resolution["pixels"] <= 1.0:
        return "a single pixel (the smallest possible)"
    return f"about {max(resolution['pixels'], 2.0):.0f} pixels (a disc of radius {resolution['radius_px']:.1f} px)"


def resolution_sentence(resolution: dict, edge_power=None) -> str:
    """What the fit can resolve, for the report and the printed line; with an edge term (``edge_power`` > 0) the
    note that the figure counts the outline's earning."""
    text = (f"a region of {resolution['contrast']:g} times material {resolution['material']}'s albedo gets a material "
            f"of its own from {resolution_size(resolution)}")
    if resolution["pixels"] > 1.0:      # below one pixel there is nothing smaller to merge
        text += "; smaller ones are merged into the material around them"
    if finite(edge_power) and edge_power > 0:
        text += (" (counting the edge term's earning along its outline, where the data step as the paints' "
                 "albedos do; this is the target's resolution: a chain finds a small detail only once one of its "
                 "moves proposes it, so a detail near this size may be missed in a short run)")
    return text
