"""The material model's compiled (Numba) passes (see :mod:`rjfit.sampler.passes` for what makes them fast).

- :mod:`~rjfit.sampler.regions.materials.passes.labels`: the label sweeps, cluster growth, split allocation;
- :mod:`~rjfit.sampler.regions.materials.passes.edges`: the edge term (its boundaries' sums, the
  label sweep's delayed acceptance);
- :mod:`~rjfit.sampler.regions.materials.passes.lloyd`: Lloyd's k-means iterations (the split guide's 2-means).
"""
