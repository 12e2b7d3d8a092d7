"""Exactness of the material region model against posteriors computed by enumeration and quadrature.

On a 2 x 2 image (3 lights, 12 observations; every set partition of the 4 pixels, Bell
number 15) and a 2 x 3 image (18 observations; the 31 partitions into two blocks), the
exact posterior of a partition S is

    rho^K(S) exp(-beta B(S)) x prod over its blocks of the block's evidence

(the evidence integrates I0, kd, gamma on a grid and sigma^2 analytically:
:class:`builders.Quadrature`). The chains' labelled states are mapped to partitions
(labels renumbered by first appearance) and their frequencies compared with the exact
posterior by a chi-square test scaled by the effective sample size
(:func:`builders.ess_scaled_chi2`), level 0.001 (p > 0.001 passes; fixed seeds make each
outcome deterministic); so are the frequencies of K. The parameters of pixel 0's material
are compared with their exact marginal (a mixture over partitions of the blocks'
quadrature marginals) by one-sample KS tests on draws thinned to about one per effective
sample, level 0.001. K changes by the cluster moves' births and deaths, by the segment
moves' (:mod:`rjfit.sampler.regions.materials.segment_move`; on these images the family's superpixels
are single pixels) and by the merge/split moves of whole materials
(:mod:`rjfit.sampler.regions.materials.merge_split`), together and, in several tests, by one family alone.
The negative controls must be rejected with p < 1e-6: the segment moves without the Potts
change, the cluster moves without their cut products (their ``log(1 - q)`` sums) with
bonds near q_max, the merge/split moves with the split probability q(X, Y) missing the
coin's second half, and the scatter moves' dissolves without their reverse allocation
(:mod:`rjfit.sampler.regions.materials.scatter_move`).
"""
import dataclasses
import math

import numpy as np
import pytest
from scipy import stats
from threadpoolctl import threadpool_limits

from rjfit.sampler.forward import Problem
from rjfit.sampler.kernel import ChainContext, initial_state, step
from rjfit.sampler.regions.materials import cluster_swc, component_move, merge_split, scatter_move, segment_move
from rjfit.sampler.regions.materials.passes.labels import allocate_split
from rjfit.sampler.regions.materials.layout import boundary_count
from rjfit.sampler.state import SamplerConfig

from builders import Quadrature, canonical, ess_scaled_chi2, exact_partition_posterior, set_partitions, tiny_problem

LEVEL = 1e-3
ENUMERATION_ITERATIONS, ENUMERATION_BURN = 3000, 300
CONTROL_ITERATIONS, CONTROL_BURN = 1500, 150
STUCK_ITERATIONS = 600       # the coin control's wrong chain reaches K = 4 within its first iterations and stays


def run(problem, prior, config, iterations, seed, **start):
    rng = np.random.default_rng(seed)
    state = initial_state(problem, prior, config, rng, **start)
    context = ChainContext()       # the chain's reusable work, as a fit's runner keeps it
    parts, theta0 = [], np.zeros((iterations, 4))
    with threadpool_limits(1):
        for t in range(iterations):
            state, _ = step(state, rng, problem, prior, config, context)
            z = state.layout.pixels.ravel()
            parts.append(canonical(z))
            theta0[t] = state.theta[z[0]]
    return parts, theta0


def partition_test(parts, exact):
    cells = list(exact)
    index = {p: i for i, p in enumerate(cells)}
    draws = np.array([index[p] for p in parts])
    p_value, freq, n_eff = ess_scaled_chi2(list(range(len(cells))), draws, np.array([exact[c] for c in cells]))
    return p_value, {"n_eff": n_eff, "worst": sorted(zip(np.abs(freq - np.array(list(exact.values()))), cells))[-3:]}


def k_test(parts, exact):
    ks = sorted({max(p) + 1 for p in exact})
    probs = np.array([sum(v for p, v in exact.items() if max(p) + 1 == k) for k in ks])
    draws = np.array([max(p) + 1 for p in parts])
    p_value, freq, n_eff = ess_scaled_chi2(ks, draws, probs)
    return p_value, {"exact": probs, "freq": freq, "n_eff": n_eff}


def theta0_ks(quad, exact, theta0):
    """KS p-values of pixel 0's material's (I0, kd, gamma) against the exact mixture marginals.

    (sigma^2's marginal is a mixture of inverse gammas whose table costs minutes here; the
    within-material moves that draw it are the change-point model's, KS-tested in
    ``test_exact_rj.py``.)
    """
    import arviz as az

    blocks = {}
    for part, prob in exact.items():
        block = tuple(np.flatnonzero(np.array(part) == part[0]))
        blocks[block] = blocks.get(block, 0.0) + prob
    mixture = [(prob, quad.marginal_cdfs(block, with_sigma2=False)) for block, prob in blocks.items()]
    total = sum(prob for prob, _ in mixture)
    p_values = []
    for k in range(3):
        ess = float(az.ess(theta0[:, k][None], method="bulk"))
        draws = theta0[::max(1, int(np.ceil(len(theta0) / ess))), k]
        cdf = lambda x, k=k: sum(prob * cdfs[k](x) for prob, cdfs in mixture) / total   # noqa: E731
        p_values.append(stats.kstest(draws, cdf).pvalue)
    return p_values


@pytest.fixture(scope="module")
def square():
    obs, prior = tiny_problem()
    return prior, Problem.from_observations(obs), Quadrature(obs, prior)


def materials_config(**options):
    flat = dict(region_model="materials", burn_in=0, cluster_moves=2, potts_beta=1.0)
    flat.update(options)
    return SamplerConfig.from_flat(**flat)


# K moved by every jump move, by the cluster moves' births and deaths alone, by merges and splits alone,
# by the segment moves' births and deaths alone (and by the cluster moves alone with half their seeds
# drawn as a material, then a pixel of it), by the component moves' alone (beta 1 and 2: bonds 0.63 and 0.86, so
# a piece is cut and moved whole in turn), by the spatial splits and merges alone, by the scatter moves' births and
# dissolves alone (beta 1 and 0.3)
JUMP_MOVES = {"all": {"merge_split_moves": 1}, "cluster": {"merge_split_moves": 0, "segment_moves": 0},
              "merge_split": {"cluster_moves": 0, "segment_moves": 0, "merge_split_moves": 1},
              "segment": {"cluster_moves": 0, "merge_split_moves": 0, "segment_moves": 2},
              "cluster_material_seeds": {"merge_split_moves": 0, "segment_moves": 0, "cluster_material_seed": 0.5},
              "component": {"cluster_moves": 0, "merge_split_moves": 0, "segment_moves": 0, "component_moves": 2},
              "spatial": {"cluster_moves": 0, "merge_split_moves": 0, "segment_moves": 0, "spatial_split_moves": 2},
              "scatter": {"cluster_moves": 0, "merge_split_moves": 0, "segment_moves": 0, "scatter_moves": 2}}


@pytest.mark.parametrize("jumps,beta,rho,seed", [("all", 1.0, 1.0, 1), ("cluster", 0.5, 0.1, 2),
                                                 ("merge_split", 2.0, 0.5, 4), ("segment", 1.0, 0.5, 3),
                                                 ("cluster_material_seeds", 0.5, 0.1, 2), ("component", 1.0, 0.5, 6),
                                                 ("component", 2.0, 0.3, 7), ("spatial", 1.0, 0.5, 8),
                                                 ("scatter", 1.0, 0.5, 9), ("scatter", 0.3, 0.2, 10)])
def test_partitions_k_and_parameters_match_enumeration(square, jumps, beta, rho, seed):
    """All 15 partitions of the 2 x 2 image, K_max 4: Gibbs sweeps and the jump moves ``jumps``."""
    prior, problem, quad = square
    exact = exact_partition_posterior(quad, (2, 2), beta, rho)
    config = materials_config(max_materials=4, potts_beta=beta, potts_rho=rho, **JUMP_MOVES[jumps])
    parts, theta0 = run(problem, prior, config, ENUMERATION_ITERATIONS, seed)
    parts, theta0 = parts[ENUMERATION_BURN:], theta0[ENUMERATION_BURN:]
    p_part, details = partition_test(parts, exact)
    p_k, k_details = k_test(parts, exact)
    print(jumps, beta, rho, p_part, details, p_k, k_details)
    assert np.sort(k_details["exact"])[-2] > 0.05, "the exact posterior should spread over K for the test to bite"
    assert p_part > LEVEL, details
    assert p_k > LEVEL, k_details
    if jumps == "all":        # once: the mixture marginals cost seconds
        p_theta = theta0_ks(quad, exact, theta0)
        print("KS", p_theta)
        assert min(p_theta) > LEVEL, p_theta


def test_fixed_k_gibbs_and_cluster_moves_match_enumeration():
    """The 31 two-block partitions of a 2 x 3 image: labels moved by Gibbs sweeps, cluster and segment moves (K = 2)."""
    obs, prior = tiny_problem(width=3)
    problem, quad = Problem.from_observations(obs), Quadrature(obs, prior, points=61)
    exact = exact_partition_posterior(quad, (2, 3), 1.0, 1.0, n_blocks=2)
    config = materials_config(max_materials=2, jumps=False)
    parts, _ = run(problem, prior, config, 2500, 5, n_materials=2)
    p_part, details = partition_test(parts[250:], exact)
    print(p_part, details)
    assert p_part > LEVEL, details


def without_cut_products(grow):
    """``grow`` (grow_cluster) with the cut products it returns set to 0: the negative controls' broken ratio."""
    def grown(*args):
        members, n_to, log_cut_to = grow(*args)
        return members, n_to, np.zeros_like(log_cut_to)
    return grown


def test_dropping_the_cut_products_is_detected(square, monkeypatch):
    """Negative control: bonds at their ceiling 0.95 (tau huge) and the cut products left out of the ratio.

    K moves by the cluster moves alone here (no merges and splits, whose ratios are right).
    """
    prior, problem, quad = square
    exact = exact_partition_posterior(quad, (2, 2), 1.0, 1.0)
    base = materials_config(max_materials=4, **JUMP_MOVES["cluster"])
    config = dataclasses.replace(base, regions=dataclasses.replace(
        base.regions, cluster=dataclasses.replace(base.regions.cluster, bond_q_max=0.95, bond_tau=1e6)))
    right, _ = run(problem, prior, config, CONTROL_ITERATIONS, 7)
    p_right, details_right = partition_test(right[CONTROL_BURN:], exact)
    monkeypatch.setattr(cluster_swc, "grow_cluster", without_cut_products(cluster_swc.grow_cluster))
    wrong, _ = run(problem, prior, config, CONTROL_ITERATIONS, 7)
    p_wrong, details_wrong = partition_test(wrong[CONTROL_BURN:], exact)
    print(p_right, details_right, p_wrong, details_wrong)
    assert p_right > LEVEL, details_right
    assert p_wrong < 1e-6, details_wrong


def test_component_moves_without_their_cut_products_are_detected(square, monkeypatch):
    """Negative control: the component moves alone (beta 1: bonds 0.63) with the cut products left out of the
    ratio. (Leaving out the seed's chance instead is not detected on this 2 x 2 image, p 0.98: a piece there is
    mostly its whole material; its formula is the cluster moves' material seeds', tested above at a share of 0.5.)"""
    prior, problem, quad = square
    exact = exact_partition_posterior(quad, (2, 2), 1.0, 0.5)
    config = materials_config(max_materials=4, potts_beta=1.0, potts_rho=0.5, **JUMP_MOVES["component"])
    monkeypatch.setattr(component_move, "grow_cluster", without_cut_products(component_move.grow_cluster))
    wrong, _ = run(problem, prior, config, CONTROL_ITERATIONS, 7)
    p_wrong, details_wrong = partition_test(wrong[CONTROL_BURN:], exact)
    print(p_wrong, details_wrong)
    assert p_wrong < 1e-6, details_wrong


def test_split_probability_without_the_coins_second_half_is_detected(square, monkeypatch):
    """Negative control: q(X, Y) taken as 1/2 P(X to part 0, Y to part 1) alone, merges and splits only.

    The right chain of this setting is the enumeration test's ``merge_split`` case (same
    beta, rho and moves), which passes.
    """
    prior, problem, quad = square
    exact = exact_partition_posterior(quad, (2, 2), 2.0, 0.5)
    config = materials_config(max_materials=4, potts_beta=2.0, potts_rho=0.5, **JUMP_MOVES["merge_split"])

    def half_coin(members, guide, in_first, problem, beta):
        first = np.asarray(in_first, np.int8)
        _, log_a = allocate_split(members, guide, float(problem.likelihood_power), beta, problem.height,
                                  problem.width, np.empty(0), 1 - first)
        return float(log_a - np.log(2.0))

    monkeypatch.setattr(merge_split, "split_log_prob", half_coin)
    wrong, _ = run(problem, prior, config, STUCK_ITERATIONS, 8)
    p_wrong, details_wrong = partition_test(wrong[CONTROL_BURN:], exact)
    print(p_wrong, details_wrong)
    assert p_wrong < 1e-6, details_wrong


def test_segment_moves_without_their_potts_change_are_detected(square, monkeypatch):
    """Negative control: the segment moves' edges to each label taken as none (the Potts change left
    out of their ratio), segment moves the only jumps. The right chain of this setting is the
    enumeration test's ``segment`` case (same beta, rho and moves), which passes."""
    prior, problem, quad = square
    exact = exact_partition_posterior(quad, (2, 2), 1.0, 0.5)
    config = materials_config(max_materials=4, potts_beta=1.0, potts_rho=0.5, **JUMP_MOVES["segment"])
    monkeypatch.setattr(segment_move, "edges_to_labels", lambda pixels, members, n_labels: np.zeros(n_labels, int))
    wrong, _ = run(problem, prior, config, CONTROL_ITERATIONS, 9)
    p_wrong, details_wrong = partition_test(wrong[CONTROL_BURN:], exact)
    print(p_wrong, details_wrong)
    assert p_wrong < 1e-6, details_wrong


SBC_REPLICATES, SBC_DRAWS, SBC_THIN, SBC_BURN = 60, 9, 5, 50


def test_sbc_ranks_of_the_material_model_are_uniform():
    """Simulation-based calibration (Talts et al. 2018) of the whole material model on the 2 x 2 image.

    Per replicate: a partition drawn from the Potts prior (beta 1, rho 1, K_max 4, by
    enumeration), each material's parameters from the prior, the 12 observations
    simulated; a chain from a dispersed start, burn-in 50, 9 draws thinned by 5 (K's
    autocorrelation time is about 4 iterations in the enumeration tests). The
    ranks of the truth among the draws, for label-free statistics (K, and pixel 0's
    material's I0 and gamma; ties in K broken uniformly at random), must be uniform on
    0 .. 9: chi-square on 5 bins of 2 ranks, 60 replicates, level 0.001 per statistic.
    """
    from rjfit.model.blinn import radiance

    base, prior = tiny_problem()
    rng = np.random.default_rng(2025)
    parts = list(set_partitions(4))
    log_w = np.array([-boundary_count(np.array(p).reshape(2, 2)) for p in parts], float)
    weights = np.exp(log_w - log_w.max())
    config = materials_config(max_materials=4)
    ranks = np.zeros((SBC_REPLICATES, 3), int)
    with threadpool_limits(1):
        for i in range(SBC_REPLICATES):
            part = np.array(parts[rng.choice(len(parts), p=weights / weights.sum())])
            theta = np.array([prior.sample(rng) for _ in range(part.max() + 1)])[part[base.pixel]]
            y = radiance(theta[:, 0], theta[:, 1], theta[:, 2], base.cos_ln, base.cos_hn, base.irradiance)
            y = y + rng.normal(0.0, np.sqrt(theta[:, 3]))
            problem = Problem.from_observations(dataclasses.replace(base, y=y))
            truth = np.array([part.max() + 1, theta[0, 0], theta[0, 2]], float)
            state = initial_state(problem, prior, config, rng)
            context = ChainContext()       # the chain's reusable work, as a fit's runner keeps it
            kept = []
            for t in range(SBC_BURN + SBC_DRAWS * SBC_THIN):
                state, _ = step(state, rng, problem, prior, config, context)
                if t >= SBC_BURN and (t - SBC_BURN) % SBC_THIN == SBC_THIN - 1:
                    z0 = state.layout.pixels.ravel()[0]
                    kept.append([state.layout.n_materials, state.theta[z0, 0], state.theta[z0, 2]])
            kept = np.array(kept)
            ties = (kept == truth).sum(axis=0)
            ranks[i] = (kept < truth).sum(axis=0) + np.array([rng.integers(n + 1) for n in ties])
    for k in range(3):
        counts = np.bincount(ranks[:, k] // 2, minlength=5)
        p_value = stats.chisquare(counts).pvalue
        print("SBC", k, counts, p_value)
        assert p_value > LEVEL, (k, counts, p_value)


def test_spatial_merges_of_pairs_that_are_not_halves_are_detected(square, monkeypatch):
    """Negative control: the spatial splits and merges alone, with every pair's merge taken as the reverse of a
    spatial split (q(X, Y) = 1/2 whether or not X and Y are the halves of their union). The right chain of this
    setting is the enumeration test's ``spatial`` case (same beta, rho and moves), which passes."""
    prior, problem, quad = square
    exact = exact_partition_posterior(quad, (2, 2), 1.0, 0.5)
    config = materials_config(max_materials=4, potts_beta=1.0, potts_rho=0.5, **JUMP_MOVES["spatial"])
    monkeypatch.setattr(merge_split, "_halves_log_prob", lambda members, in_first, width: -math.log(2.0))
    wrong, _ = run(problem, prior, config, CONTROL_ITERATIONS, 8)
    p_wrong, details_wrong = partition_test(wrong[CONTROL_BURN:], exact)
    print(p_wrong, details_wrong)
    assert p_wrong < 1e-6, details_wrong


def test_dissolves_without_their_reverse_allocation_are_detected(square, monkeypatch):
    """Negative control: the scatter moves alone, with the dissolve's reverse, the birth's allocation of the dying
    material's pixels, taken as certain (its log probability 0). The right chain of this setting is the enumeration
    test's first ``scatter`` case (same beta, rho and moves), which passes."""
    prior, problem, quad = square
    exact = exact_partition_posterior(quad, (2, 2), 1.0, 0.5)
    config = materials_config(max_materials=4, potts_beta=1.0, potts_rho=0.5, **JUMP_MOVES["scatter"])
    allocate = scatter_move.allocate_birth

    def certain_when_given(labels, own, new, power, beta, height, width, new_label, uniforms, forced):
        log_prob = allocate(labels, own, new, power, beta, height, width, new_label, uniforms, forced)
        return 0.0 if forced.size else log_prob

    monkeypatch.setattr(scatter_move, "allocate_birth", certain_when_given)
    wrong, _ = run(problem, prior, config, CONTROL_ITERATIONS, 8)
    p_wrong, details_wrong = partition_test(wrong[CONTROL_BURN:], exact)
    print(p_wrong, details_wrong)
    assert p_wrong < 1e-6, details_wrong
