"""The sampler's settings of a fit, built field by field from its resolved options.

Each region model builds its own settings in its :class:`~rjfit.pipeline.regions.base.RegionFit`
(``sampler_config``), naming every option it reads (its ``reads`` lists the same names); :func:`assemble` adds what every model shares (the within-region sampler,
the burn-in and warm-up, the effects' schedule). A new option reaches the sampler where one of
these says so, never by its name.
"""
from __future__ import annotations

from dataclasses import replace

from rjfit.pipeline.options import FitOptions
from rjfit.sampler.state import KernelSettings, SamplerConfig

__all__ = ["assemble", "burn_in_iterations"]


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


def assemble(options: FitOptions, regions, burn: int) -> SamplerConfig:
    """The kernel's settings: the region model's ``regions`` settings with those every model shares.

    Raises
    ------
    ValueError
        If a settings class refuses a value.
    """
    config = SamplerConfig()
    within = replace(config.within, sampler=options.sampler, g_moves=options.gamma_moves)
    return SamplerConfig(regions=regions, within=within,
                         kernel=KernelSettings(burn_in=burn, anneal=int(round(options.anneal * burn))),
                         effects=replace(config.effects, every=options.effect_every))
