"""The RJMCMC sampler of the paper's segmentation and BRDF posterior (exact and fast).

Where things are:

- :mod:`~rjfit.sampler.forward`: the forward model and the :class:`Problem` it builds
  (observations sorted and compacted); :mod:`~rjfit.sampler.likelihood`: per-region
  sufficient statistics, the oracle; :mod:`~rjfit.sampler.priors`: parameter priors.
- :mod:`~rjfit.sampler.regions`: region models (what partitions the pixels; today the
  paper's change points) with their structure moves.
- :mod:`~rjfit.sampler.moves`: one move family per module, the :class:`~rjfit.sampler.moves.proposal.Proposal`
  type and the one accept step.
- :mod:`~rjfit.sampler.passes`: the compiled (Numba) passes over observations, by subject;
  :mod:`~rjfit.sampler.reference`: their NumPy twins, which the tests compare against.
- :mod:`~rjfit.sampler.state`: chain state, step info, the composed :class:`SamplerConfig`;
  :mod:`~rjfit.sampler.kernel`: ``step``; :mod:`~rjfit.sampler.runner`: chains,
  checkpoints, processes.
"""
from rjfit.sampler.forward import ForwardModel, LambertBlinnPhong, Problem
from rjfit.sampler.kernel import ChainContext, initial_state, log_posterior, make_state, refresh, step
from rjfit.sampler.likelihood import oracle_log_likelihood
from rjfit.sampler.priors import Prior, make_prior
from rjfit.sampler.regions.base import RegionModel
from rjfit.sampler.regions.changepoints.grid import Changepoints, model_number, pixel_region_labels
from rjfit.sampler.regions.changepoints import ChangepointRegions
from rjfit.sampler.runner import ChainRecord, ChainSpec, run_chain, run_chains
from rjfit.sampler.state import ChainState, SamplerConfig, StepInfo

__all__ = ["ChainContext", "ChainRecord", "ChainSpec", "ChainState", "ChangepointRegions", "Changepoints",
           "ForwardModel", "LambertBlinnPhong", "Prior", "Problem", "RegionModel", "SamplerConfig", "StepInfo",
           "initial_state", "log_posterior", "make_prior", "make_state", "model_number", "oracle_log_likelihood",
           "pixel_region_labels", "refresh", "run_chain", "run_chains", "step"]
