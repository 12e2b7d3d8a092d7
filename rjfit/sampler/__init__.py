"""The RJMCMC sampler of the paper's segmentation and BRDF posterior (exact and fast).

Modules: :mod:`~rjfit.sampler.changepoints` (regions from change points, model numbers),
:mod:`~rjfit.sampler.likelihood` (sufficient statistics, oracle), :mod:`~rjfit.sampler.priors`,
:mod:`~rjfit.sampler.moves`, :mod:`~rjfit.sampler.kernel` (``step``),
:mod:`~rjfit.sampler.runner` (chains, checkpoints, processes).
"""
from rjfit.sampler.changepoints import model_number, pixel_region_labels
from rjfit.sampler.kernel import initial_state, make_state, refresh, step
from rjfit.sampler.likelihood import Problem, oracle_log_likelihood
from rjfit.sampler.priors import Prior, make_prior
from rjfit.sampler.runner import ChainRecord, ChainSpec, run_chain, run_chains
from rjfit.sampler.state import ChainState, SamplerConfig, StepInfo

__all__ = ["ChainRecord", "ChainSpec", "ChainState", "Prior", "Problem", "SamplerConfig", "StepInfo",
           "initial_state", "make_prior", "make_state", "model_number", "oracle_log_likelihood",
           "pixel_region_labels", "refresh", "run_chain", "run_chains", "step"]
