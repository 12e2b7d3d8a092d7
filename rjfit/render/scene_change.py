"""A change of a Mitsuba scene that a model extension asks for (an effect of the criticism
library, :mod:`rjfit.effects`), and how several combine.

Plain data: building and rendering the changed scene is :mod:`rjfit.render.effect_scenes`'
work. It lives in the render layer so that the renderer needs nothing from the criticism
package above it (layers import downwards only, ``docs/architecture.md``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["MitsubaChange", "merge_changes"]


@dataclass
class MitsubaChange:
    """The Mitsuba side of an effect (or of several, merged).

    bsdf_params : extra parameters of the plugin variant ``rjfit_blinn_ext`` (f0, mask_w, ggx_w, lobe2_v,
                  lobe2_alpha; :mod:`rjfit.render.ext_plugin`)
    extra       : extra scene entries (e.g. a ``constant`` emitter)
    max_depth   : the path integrator's path length (None: the gate's default, direct only)
    light_scales: per-light factors on the emitter intensities
    post_process: images (L, H, W) -> images, applied to the path-traced stack
    stochastic  : the change makes the path tracer's answer Monte Carlo noisy (the gate
                  then tests agreement statistically, see :func:`rjfit.diagnose.gate.gate`)
    notes       : what a reader of the gate's result must know about the change
    """

    bsdf_params: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)
    max_depth: int | None = None
    light_scales: np.ndarray | None = None
    post_process: object = None
    stochastic: bool = False
    notes: list = field(default_factory=list)


def merge_changes(changes) -> MitsubaChange:
    """One change doing all of ``changes``: BSDF parameters and scene entries united, the
    deepest path length, light scales multiplied, post-processes applied in order."""
    merged = MitsubaChange()
    for change in changes:
        merged.bsdf_params.update(change.bsdf_params)
        merged.extra.update(change.extra)
        if change.max_depth is not None:
            merged.max_depth = max(merged.max_depth or 0, change.max_depth)
        if change.light_scales is not None:
            merged.light_scales = (np.asarray(change.light_scales) if merged.light_scales is None
                                   else merged.light_scales * np.asarray(change.light_scales))
        if change.post_process is not None:
            previous = merged.post_process
            merged.post_process = change.post_process if previous is None else (
                lambda images, a=previous, b=change.post_process: b(a(images)))
        merged.stochastic |= change.stochastic
        merged.notes += change.notes
    return merged
