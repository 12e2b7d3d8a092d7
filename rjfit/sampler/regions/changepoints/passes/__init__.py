"""The change-point model's compiled (Numba) passes (see :mod:`rjfit.sampler.passes` for what makes them fast).

- :mod:`~rjfit.sampler.regions.changepoints.passes.sweep`: the element sweep's proposals;
- :mod:`~rjfit.sampler.regions.changepoints.passes.paths`: forward filtering, backward sampling, rank chains.
"""
