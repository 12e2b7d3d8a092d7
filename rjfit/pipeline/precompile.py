"""Compile the sampler's kernels once, at set-up: ``python -m rjfit.pipeline.precompile``.

The passes are Numba functions cached on disk (``cache=True``, beside their modules). On a
fresh checkout nothing is cached, so the first fit of each region model compiles them: about
50 s on 2 cores, paid again by every process that starts before the cache exists (each
chain's worker process, each test worker). ``setup.sh`` runs this module once, so the first
real fit and the test suite start from the cache. It fits a tiny in-code sphere (24 x 24, 8
lights) with each region model, the joint colour fit and the measured default (``--preset
measured``: the edge term's kernels, the normals' noise model, the calibration), runs the gamma
passes once on a region too large for one thread (:func:`compile_threaded_passes`), and fits a tiny
rendered stack (8 x 8, Mitsuba) with an effect sampled in the fit (``--effects ambient``: the
effects' lobe kernels), a few iterations each, in a temporary folder that is removed; nothing of
the user's is read or written.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

__all__ = ["precompile", "compile_threaded_passes"]


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
    compile_threaded_passes()
    say(f"compiled the threaded passes of a large region ({time.perf_counter() - started:.0f} s so far)")
    return time.perf_counter() - started


def compile_threaded_passes() -> None:
    """Run the gamma passes (:func:`~rjfit.sampler.passes.sums.b_sums` and
    :func:`~rjfit.sampler.passes.sums.b_sums_newton`) and the label sweep's per-pixel log likelihoods
    (:func:`~rjfit.sampler.regions.materials.passes.labels.pixel_log_lik`) once on ``PARALLEL_MIN_OBS``
    observations of the problem's types.

    A measured object's regions are that large, and their passes run in pieces on the chain's threads: a kernel of
    its own, which the tiny fits above never reach (the ball's first fit on a fresh cache compiled it in each chain's
    process, 4 to 5 s each)."""
    import numpy as np

    from rjfit.sampler.passes.sums import PARALLEL_MIN_OBS, b_sums, b_sums_newton
    from rjfit.sampler.regions.materials.passes.labels import pixel_log_lik

    columns = [np.full(PARALLEL_MIN_OBS, value, np.float32) for value in (0.5, 0.8, -0.1)]   # y, C, log <h.n>
    starts, ends = np.array([0], np.int64), np.array([PARALLEL_MIN_OBS], np.int64)
    b_sums(*columns, starts, ends, 2.0)
    b_sums_newton(*columns, starts, ends, 2.0)
    pixel = np.repeat(np.arange(PARALLEL_MIN_OBS // 8, dtype=np.int32), 8)      # 8 lights a pixel
    pixel_log_lik(*columns, pixel, np.array([[1.0, 0.5, 2.0, 0.1]]), PARALLEL_MIN_OBS // 8)


if __name__ == "__main__":
    precompile()
