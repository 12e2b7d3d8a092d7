"""Posterior summaries, ArviZ export and figures of RJMCMC fits."""
