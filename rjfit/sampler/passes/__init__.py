"""Compiled loops (Numba) for the sampler's passes over observations, grouped by subject.

- :mod:`~rjfit.sampler.passes.special`: a vectorising ``exp``, the normal CDF and quantile;
- :mod:`~rjfit.sampler.passes.sums`: sufficient statistics and the B sums at any gamma;
- :mod:`~rjfit.sampler.passes.densities`: per-observation log densities (building blocks);
- :mod:`~rjfit.sampler.passes.shifts`: element moves (observations that change region);
- :mod:`~rjfit.sampler.passes.cells`: per-pixel and per-cell sums of change-point vectors;

Each region model's own passes live in its package (:mod:`rjfit.sampler.regions.changepoints.passes`:
forward filtering, backward sampling, rank chains, the element sweep's proposals;
:mod:`rjfit.sampler.regions.materials.passes`: label sweeps, the edge term, Lloyd's iterations).

Why a JIT: profiling the full kernel (``validation/bench_sampler.py``'s
segmentation-sampled row, 256 x 256 chains) showed it spending its time in NumPy passes
that each make several float64 temporaries of up to N entries (upcast, ``exp``, products,
``bincount``), and in Python loops over lines (the vector redraw's forward filter). Fused
into one loop each, a pass reads the float32 arrays once and keeps every temporary in
registers.

What makes a loop fast here (measured; ``tests/sampler/test_passes.py`` checks each against
:mod:`rjfit.sampler.reference`): the exponentials use
:func:`~rjfit.sampler.passes.special.fast_exp`, plain arithmetic that vectorises, where
libm's scalar ``exp`` costs about 5 ns; a loop vectorises only without gathers
(per-observation lookups by label: those go to a scalar phase per block, then the
densities over each run of one region in a vectorised phase, then a scalar scatter; a
region's passes run over its runs of consecutive observations, see
:func:`rjfit.sampler.likelihood.label_runs`, so they need no lookup at all), when it
indexes views from 0 (``y[start + k]`` inside the loop left the gamma-move sums scalar and
3 times slower) and when its accumulators fit in the vector registers (nine in one loop
made the gamma-move sums 1.7 times slower than three loops of three).

Every sum is accumulated in float64 in blocks of
:data:`~rjfit.sampler.passes.sums.BLOCK` terms, so rounding error grows like
``BLOCK + n / BLOCK`` ulps, not n. Compiled once per machine (``cache=True`` keeps the
machine code beside each module).

Threads within one chain: the passes that dominate an iteration (the B sums, the per-pixel
sums) cut a pass of at least :data:`~rjfit.sampler.passes.sums.PARALLEL_MIN_OBS`
observations into :data:`~rjfit.sampler.passes.sums.PARTS` pieces of near-equal size and
add the pieces' sums in order; the pieces run on the chain's Numba threads
(``numba.set_num_threads``, set by :func:`rjfit.sampler.runner.run_chain`). The pieces do
not depend on the number of threads, so neither does any sum, to the last bit: a chain
gives the same samples on one thread or eight. Smaller passes run whole, because starting
threads (a few microseconds) would cost more than they save.
"""
