"""Convergence warnings of a fit (rjfit.posterior.summary.convergence_warnings) on chains with known properties."""
import numpy as np

from rjfit.posterior.summary import ESS_PER_CHAIN_MIN, RHAT_MAX, convergence_warnings, diagnostics

AGREE = [{"(1,1)": 0.97, "(1,2)": 0.03}] * 4


def _iid_chains(rng, n_chains=4, draws=1000):
    # 4 regions x 4 parameters, independent standard normal draws
    return [rng.normal(size=(draws, 4, 4)) for _ in range(n_chains)]


def test_well_mixed_chains_give_no_warning():
    # iid draws: ESS ~ 4000 >> 400; split R-hat of 4 x 1000 iid draws scatters about 1 by ~0.001
    # (sd of R-hat - 1 ~ 1 / n_draws), so 1.01 is some ten sd away for each of the 16 parameters.
    diag = diagnostics(_iid_chains(np.random.default_rng(0)))
    assert diag["rhat_max"] < RHAT_MAX and diag["ess_bulk_min"] > 4 * ESS_PER_CHAIN_MIN
    assert convergence_warnings(diag, AGREE, 4) == []


def test_a_shifted_chain_is_caught_by_rhat():
    chains = _iid_chains(np.random.default_rng(1))
    chains[2] = chains[2] + 1.0          # one chain one sd away: R-hat about 1.1
    warnings = convergence_warnings(diagnostics(chains), AGREE, 4)
    assert any(w.startswith("R-hat max") for w in warnings), warnings


def test_a_sticky_chain_is_caught_by_ess():
    rng = np.random.default_rng(2)
    chains = []
    for _ in range(4):
        # AR(1) with phi = 0.995: ESS per 1000 draws about 1000 (1 - phi) / (1 + phi) = 2.5 per chain
        x = np.empty((1000, 4, 4))
        x[0] = rng.normal(size=(4, 4))
        for t in range(1, 1000):
            x[t] = 0.995 * x[t - 1] + np.sqrt(1 - 0.995 ** 2) * rng.normal(size=(4, 4))
        chains.append(x)
    warnings = convergence_warnings(diagnostics(chains), AGREE, 4)
    assert any(w.startswith("ESS min") for w in warnings), warnings


def test_chains_in_different_models_are_named():
    rng = np.random.default_rng(3)
    chain_models = [{"(1,2)": 1.0}, {"(2,1)": 0.98, "(1,2)": 0.02}]
    # the MAP model's draws come from one chain only (the other never visits it)
    diag = diagnostics([rng.normal(size=(500, 6, 4)), np.empty((0, 6, 4))])
    warnings = convergence_warnings(diag, chain_models, 2)
    assert any("disagree" in w and "chain 0: (1,2) (1.00)" in w and "chain 1: (2,1) (0.98)" in w for w in warnings)
    assert any("only 1 of 2 chains" in w for w in warnings), warnings


def test_chains_that_each_visit_both_models_do_not_disagree():
    # a genuinely bimodal model posterior: each chain's most frequent model is a coin flip,
    # but their frequencies agree (total variation 0.04 << 0.5)
    chain_models = [{"(1,1)": 0.52, "(1,2)": 0.48}, {"(1,2)": 0.50, "(1,1)": 0.50}, {"(1,1)": 0.54, "(1,2)": 0.46}]
    diag = diagnostics(_iid_chains(np.random.default_rng(5), n_chains=3))
    assert convergence_warnings(diag, chain_models, 3) == []


def test_one_chain_is_flagged():
    diag = diagnostics(_iid_chains(np.random.default_rng(4), n_chains=1))
    warnings = convergence_warnings(diag, AGREE[:1], 1)
    assert len(warnings) == 1 and warnings[0].startswith("one chain only")
