"""Compile the sampler's kernels once, at set-up: ``python -m rjfit.pipeline.precompile``.

The passes are Numba functions cached on disk (``cache=True``, beside their modules). On a
fresh checkout nothing is cached, so the first fit of each region model compiles them: about
50 s on 2 cores, paid again by every process that starts before the cache exists (each
chain's worker process, each test worker). ``setup.sh`` runs this module once, so the first
real fit and the test suite start from the cache. It fits a tiny in-code sphere (24 x 24, 8
lights) with each region model, the joint colour fit and the measured default (``--preset
measured``: the edge term's kernels, the normals' noise model, the calibration), and a tiny
rendered stack (8 x 8, Mitsuba) with an effect sampled in the fit (``--effects ambient``: the
effects' lobe kernels), a few iterations each, in a temporary folder that is removed; nothing of
the user's is read or written.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

__all__ = ["precompile"]


def precompile(say=print) -> float:
    """Run one short fit per region model (change points, materials, materials in colour), one of
    the measured default and one with an effect sampled, so that Numba compiles and caches every
    kernel they use; returns the seconds taken."""
    from rjfit.data.observations import stack_channels
    from rjfit.data.synthetic import sphere_stack
    from rjfit.pipeline.fit import fit
    from rjfit.pipeline.fit_dataset import fit_dataset
    from rjfit.render.hidden import render_hidden

    started = time.perf_counter()
    observations, _, _ = sphere_stack(24, n_lights=8, seed=1)
    colour = stack_channels([observations] * 3)
    runs = (("change points", observations, {}), ("materials", observations, {"regions": "materials"}),
            ("materials in colour", colour, {"regions": "materials", "channel": "rgb"}),
            ("measured default", observations, {"regions": "materials", "preset": "measured"}))
    with tempfile.TemporaryDirectory(prefix="rjfit-precompile-") as folder:
        for name, data, options in runs:
            fit(data, Path(folder) / name.replace(" ", "_"), iterations=20, n_chains=1, processes=1,
                progress=False, figures=False, seed=1, **options)
            say(f"compiled the kernels of a {name} fit ({time.perf_counter() - started:.0f} s so far)")
        dataset = render_hidden("ambient", Path(folder) / "ambient", resolution=8)
        fit_dataset(dataset, Path(folder) / "effects", allow_unvalidated=True, effects=("ambient",), n_chains=1,
                    iterations=20, figures=False, progress=False, seed=1)
        say(f"compiled the kernels of a fit with an effect ({time.perf_counter() - started:.0f} s so far)")
    return time.perf_counter() - started


if __name__ == "__main__":
    precompile()
