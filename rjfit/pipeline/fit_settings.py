"""The sampler's settings of a fit, built field by field from its resolved options: :func:`sampler_config`.

Each region model's settings are built by its own function (:func:`changepoint_regions`,
:func:`material_regions`), naming every option it reads (:data:`rjfit.pipeline.options.REGION_OPTIONS`
lists the same names): a new option reaches the sampler where one of these says so, never by its name.
"""
from __future__ import annotations

from dataclasses import replace

from rjfit.pipeline.fit_power import edge_power
from rjfit.pipeline.options import FitOptions
from rjfit.sampler.state import REGION_MODELS, KernelSettings, SamplerConfig

__all__ = ["sampler_config", "burn_in_iterations", "changepoint_regions", "material_regions"]


def burn_in_iterations(options: FitOptions) -> int:
    """Iterations discarded per chain (``burn_in`` of None: half, the paper's choice for rendered data).

    Raises
    ------
    ValueError
        If the burn-in leaves no iteration to keep.
    """
    fraction = 0.5 if options.burn_in is None else options.burn_in
    burn = int(round(fraction * options.iterations))
    if options.iterations - burn < 1:
        raise ValueError(f"burn-in {fraction} leaves no iteration of {options.iterations} to keep; lower --burn-in")
    return burn


def changepoint_regions(options: FitOptions, fixed: bool):
    """The change-point model's settings (``fixed``: the change points held, no jumps)."""
    model = REGION_MODELS["changepoints"]()
    # reproducing the paper's omission (--drop-jacobian): every jump must use its map
    free_prob = 0.0 if options.drop_jacobian else model.birth_death.free_prob
    return replace(model, max_u=options.max_u, max_v=options.max_v,
                   prior=replace(model.prior, kind=options.cp_prior),
                   birth_death=replace(model.birth_death, prob=options.jump_prob, split_map=options.split_map,
                                       drop_jacobian=options.drop_jacobian, free_prob=free_prob),
                   update_changepoints=not fixed, jumps=not fixed)


def material_regions(options: FitOptions, fixed: bool, power: float | str):
    """The material model's settings (``fixed``: the labels held, no jumps; ``power``: the edge term's)."""
    model = REGION_MODELS["materials"]()
    return replace(model, max_materials=options.max_materials,
                   potts=replace(model.potts, beta=options.potts_beta, rho=options.potts_rho),
                   cluster=replace(model.cluster, material_seed=options.cluster_material_seed),
                   segments=replace(model.segments, moves=options.segment_moves),
                   edge_power=power, update_labels=not fixed, jumps=not fixed)


def sampler_config(options: FitOptions, *, fixed: bool = False, problem=None) -> SamplerConfig:
    """The kernel's settings from resolved options (``fixed``: no segmentation moves; ``problem``: measures
    the edge power 'auto').

    Raises
    ------
    ValueError
        If the burn-in leaves no iteration, or a settings class refuses a value.
    """
    burn = burn_in_iterations(options)
    config = SamplerConfig()
    if options.regions == "materials":
        power = edge_power(problem, options) if problem is not None else options.edge_power
        regions = material_regions(options, fixed, power)
    else:
        regions = changepoint_regions(options, fixed)
    return SamplerConfig(regions=regions, within=replace(config.within, sampler=options.sampler),
                         kernel=KernelSettings(burn_in=burn, anneal=int(round(options.anneal * burn))),
                         effects=replace(config.effects, every=options.effect_every))
