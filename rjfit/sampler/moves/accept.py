"""The one Metropolis-Hastings accept step that every move of the kernel uses."""
from __future__ import annotations

import math

import numpy as np

__all__ = ["accept"]


def accept(log_u, log_ratio, info, kind: str):
    """Whether to accept: ``log u < log ratio``, with ``log u`` already drawn by the move.

    The move draws its uniform where it always has (some draw it before they know whether
    the proposal is valid, and those draws must stay in the random stream), so this step
    only decides and never touches the generator.

    A NaN log ratio (a density that could not be evaluated) is a rejection, counted in
    ``info.nan_rejected[kind]``; ``-inf`` (an invalid proposal) is a plain rejection.
    Scalars give a bool; arrays (one log ratio per line of a sweep; lines with nothing to
    test carry -inf) an array of bools.

    Parameters
    ----------
    log_u : float or ndarray
        Log of the move's uniform draw(s).
    log_ratio : float or ndarray
        The complete log acceptance ratio(s).
    info : rjfit.sampler.state.StepInfo
        Where NaN ratios are counted.
    kind : str
        The move's name in the step's counts.
    """
    if isinstance(log_ratio, np.ndarray):
        nan = np.isnan(log_ratio)
        if nan.any():
            info.count_nan(kind, int(np.count_nonzero(nan)))
        return log_u < log_ratio          # False where NaN
    if math.isnan(log_ratio):             # a rejection, and seen
        info.count_nan(kind)
        return False
    return log_u < log_ratio
