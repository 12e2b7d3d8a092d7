"""The compiled passes (rjfit.sampler.passes) against their NumPy references (rjfit.sampler.reference).

Each pass is handed the problem's lobe terms (None here; ``test_effect_passes.py`` runs the
same tests on a problem with effects).
"""
import math

import numpy as np
import pytest
from numba import njit
from scipy.stats import chi2

from rjfit.data.synthetic import sphere_stack
from rjfit.sampler import reference
from rjfit.sampler.forward import Problem
from rjfit.sampler.likelihood import RegionData, b_terms, region_stats
from rjfit.sampler.regions.changepoints.birth_death_free import rank_transitions
from rjfit.sampler.moves.gamma import newton_log_gamma
from rjfit.sampler.passes import cells, shifts, special, sums
from rjfit.sampler.regions.changepoints.passes import paths
from rjfit.sampler.regions.changepoints.grid import obs_region_labels
from rjfit.sampler.runner import numba_threads


@pytest.fixture(scope="module")
def problem():
    obs, _, _ = sphere_stack(40, n_lights=6, seed=3)
    return Problem.from_observations(obs, likelihood_power=0.6)


def _labels(problem, rng, n_regions):
    return rng.integers(0, n_regions, problem.n_obs).astype(np.int8)


THETA = np.array([[100.0, 0.5, 5.0, 0.1], [90.0, 0.9, 10.0, 0.2], [110.0, 0.6, 2.0, 0.15], [95.0, 0.4, 1.0, 0.1],
                  [100.0, 0.3, 30.0, 0.3], [80.0, 0.7, 7.0, 0.05]])


def test_region_stats_equal_numpy_reference(problem):
    labels = _labels(problem, np.random.default_rng(0), 6)
    fast = region_stats(problem, labels, THETA[:, 2], 6)
    expected = reference.region_stats(problem, labels, THETA[:, 2], 6)
    np.testing.assert_allclose(fast, expected, rtol=1e-12)


def test_region_stats_reject_labels_outside_the_regions(problem):
    labels = np.full(problem.n_obs, 6, np.int8)
    with pytest.raises(ValueError, match="labels must lie"):
        region_stats(problem, labels, THETA[:, 2], 6)


@njit
def _fast_exp_of(x):
    out = np.empty_like(x)
    for i in range(x.size):
        out[i] = special.fast_exp(x[i])
    return out


def test_fast_exp_is_within_one_ulp_of_numpy():
    """The compiled passes' exp: within 1 ulp of np.exp wherever that is a normal number, 0 below e^-708."""
    rng = np.random.default_rng(8)
    x = np.concatenate([-rng.exponential(20.0, 200_000), rng.uniform(-708.0, 709.0, 100_000),
                        [0.0, -0.0, 1e-300, -1e-300, 0.5 * math.log(2.0), -0.5 * math.log(2.0), 709.0, -708.0]])
    ours, numpy_exp = _fast_exp_of(x), np.exp(x)
    normal = numpy_exp >= np.finfo(float).tiny
    assert np.all(np.abs(ours[normal] - numpy_exp[normal]) <= np.spacing(numpy_exp[normal]))
    np.testing.assert_array_equal(_fast_exp_of(np.array([-708.5, -745.0, -800.0, -np.inf])), 0.0)
    assert _fast_exp_of(np.array([0.0]))[0] == 1.0


def test_b_sums_equal_numpy_reference(problem):
    idx = np.arange(0, problem.n_obs, 3)
    data = RegionData.gather(problem, idx)
    for gamma in (0.3, 5.0, 80.0):
        np.testing.assert_allclose(data.b_sums(gamma), reference.b_sums(problem, idx, gamma), rtol=1e-12)
    gammas = np.array([0.3, 5.0, 80.0])
    np.testing.assert_array_equal(data.stats_at_many(gammas), np.stack([data.stats_at(g) for g in gammas]))


def test_b_sums_newton_equal_numpy_reference(problem):
    idx = np.arange(1, problem.n_obs, 2)
    data = RegionData.gather(problem, idx)
    for gamma in (0.3, 5.0, 80.0):
        expected = reference.b_sums_newton(problem, idx, gamma)
        np.testing.assert_allclose(data.b_sums_newton(gamma), expected, rtol=1e-11, atol=1e-9 * abs(expected).max())
        assert data.b_sums_newton(gamma) is data.b_sums_newton(gamma)      # memoised: no second pass


def test_newton_rule_matches_finite_differences_of_the_profile(problem):
    """The Newton proposal's mean and sd from the closed-form derivatives of -SSR_min / (2 sigma^2)."""
    data = RegionData.gather(problem, np.arange(problem.n_obs))
    s2 = 0.3

    def profile(ell):
        stats = data.stats_at(math.exp(ell))
        P = np.array([[stats[3], stats[5]], [stats[5], stats[6]]])
        s = np.array([stats[2], stats[4]])
        return -(stats[1] - s @ np.linalg.solve(P, s)) / (2 * s2)

    for gamma in (3.0, 8.0, 20.0):
        ell, step = math.log(gamma), 1e-3
        h0, hp, hm = profile(ell), profile(ell + step), profile(ell - step)
        d1, d2 = (hp - hm) / (2 * step), (hp - 2 * h0 + hm) / step ** 2
        mean, sd = newton_log_gamma(data.stats_at(gamma), data.b_sums_newton(gamma), gamma, s2, 1.0)
        # central differences: error O(step^2) relative, far below the 1e-4 asked
        assert mean == pytest.approx(ell - d1 / d2, rel=1e-4, abs=1e-6)
        assert sd == pytest.approx(1.0 / math.sqrt(-d2), rel=1e-4)


def test_newton_rule_follows_the_profile_over_nonnegative_amplitudes():
    """Where the least-squares diffuse amplitude a is negative (a lobe that takes up the diffuse light, kd near 0),
    the Newton proposal's mean and sd come from the profile on the face a = 0, -(Syy - SyB^2 / SBB) / (2 sigma^2),
    which is the posterior's side of the bound (finite differences, as above)."""
    from rjfit.data.observations import Observations
    from rjfit.model.blinn import blinn_normalisation

    rng = np.random.default_rng(4)
    n = 400
    cos_ln, cos_hn = rng.uniform(0.2, 1.0, n), rng.uniform(0.5, 1.0, n)
    # a pure lobe of exponent 6 less a little diffuse light: the unbounded fit wants a < 0
    y = cos_ln * (10.0 * blinn_normalisation(6.0) * cos_hn ** 6.0 - 1.5 / np.pi) + rng.normal(0, 0.01, n)
    obs = Observations(image_shape=(20, 20), n_lights=1, pixel=np.arange(n), light=np.zeros(n, np.int32), y=y,
                       cos_ln=cos_ln, cos_hn=cos_hn, irradiance=np.ones(n), object_mask=np.ones((20, 20), bool))
    data = RegionData.gather(Problem.from_observations(obs), np.arange(n))
    s2 = 0.3

    def face_profile(ell):
        stats = data.stats_at(math.exp(ell))
        return -(stats[1] - max(stats[4], 0.0) ** 2 / stats[6]) / (2 * s2)

    for gamma in (5.0, 6.0, 7.5):
        stats = data.stats_at(gamma)
        P = np.array([[stats[3], stats[5]], [stats[5], stats[6]]])
        assert np.linalg.solve(P, [stats[2], stats[4]])[0] < 0       # the case: a < 0 without the bound
        ell, step = math.log(gamma), 1e-3
        h0, hp, hm = face_profile(ell), face_profile(ell + step), face_profile(ell - step)
        d1, d2 = (hp - hm) / (2 * step), (hp - 2 * h0 + hm) / step ** 2
        mean, sd = newton_log_gamma(stats, data.b_sums_newton(gamma), gamma, s2, 1.0)
        assert mean == pytest.approx(ell - d1 / d2, rel=1e-4, abs=1e-6)
        assert sd == pytest.approx(1.0 / math.sqrt(-d2), rel=1e-4)


@pytest.mark.parametrize("axis", ["u", "v"])
def test_element_move_delta_and_shift_equal_reference(problem, axis):
    rng = np.random.default_rng(1)
    height, width = problem.image_shape
    size = width if axis == "u" else height
    labels = (rng.integers(1, 5, problem.n_obs)).astype(np.int8)
    lines = np.arange(0, width if axis == "v" else height, 3)
    lo = rng.integers(0, size // 2, lines.size)
    hi = lo + rng.integers(0, size // 2, lines.size)
    delta = np.where(rng.random(lines.size) < 0.5, -1, 1).astype(np.int64)
    offsets = problem.pixel_start if axis == "u" else problem.colmajor_start
    starts, ends = offsets[lines * size + lo], offsets[lines * size + hi]
    use_order = axis == "v"
    d_ll = shifts.obs_log_density_delta(problem.y, problem.C, problem.log_cos_hn, problem.colmajor_order, use_order,
                                        starts, ends, labels, delta, THETA, problem.lobe)
    for j in range(lines.size):
        span = np.arange(starts[j], ends[j])
        idx = problem.colmajor_order[span] if use_order else span
        expected = np.sum(reference.obs_log_density(problem, idx, THETA[labels[idx] + delta[j]])
                          - reference.obs_log_density(problem, idx, THETA[labels[idx]]))
        assert d_ll[j] == pytest.approx(expected, rel=1e-10, abs=1e-9)
    stats = region_stats(problem, labels, THETA[:, 2], 6)
    moved = labels.copy()
    shifts.shift_stats(problem.y, problem.C, problem.log_cos_hn, problem.colmajor_order, use_order, starts, ends, moved,
                       delta, THETA[:, 2].copy(), stats, problem.likelihood_power, problem.lobe)
    expected_labels = labels.copy()
    for j in range(lines.size):
        span = np.arange(starts[j], ends[j])
        idx = problem.colmajor_order[span] if use_order else span
        expected_labels[idx] += delta[j]
    np.testing.assert_array_equal(moved, expected_labels)
    np.testing.assert_allclose(stats, reference.region_stats(problem, expected_labels, THETA[:, 2], 6),
                               rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("axis", ["u", "v"])
def test_element_shift_equals_reference(problem, axis):
    """The observations that change side when elements move: the pixels t with min < t + 0.5 <= max."""
    rng = np.random.default_rng(6)
    height, width = problem.image_shape
    size, n_lines = (width, height) if axis == "u" else (height, width)
    offsets = problem.pixel_start if axis == "u" else problem.colmajor_start
    lines = np.arange(1, n_lines, 2)
    x_old = rng.uniform(-1.0, size + 1.0, lines.size)
    x_new = np.where(rng.random(lines.size) < 0.3, x_old, rng.uniform(-3.0, size + 3.0, lines.size))
    x_new[:3] = [-1.0, size + 1.0, np.floor(x_old[2]) + 0.5]             # the edges and a pixel centre
    starts, ends, delta = shifts.element_shift(x_old, x_new, lines, size, offsets, 3)
    for j, line in enumerate(lines):
        changed = [t for t in range(size) if min(x_old[j], x_new[j]) < t + 0.5 <= max(x_old[j], x_new[j])]
        expected = np.arange(offsets[line * size + changed[0]], offsets[line * size + changed[-1] + 1]) if changed \
            else np.zeros(0, np.int64)
        np.testing.assert_array_equal(np.arange(starts[j], ends[j]), expected)
        assert delta[j] == (-3 if x_new[j] > x_old[j] else 3)


def _changepoint_labels(problem, rng, n_u, n_v):
    """Labels of a random (n_u, n_v) model whose vectors wander across the image."""
    height, width = problem.image_shape
    u = np.sort(rng.uniform(-1.0, width + 1.0, (height, n_u)), axis=1)
    v = np.sort(rng.uniform(-1.0, height + 1.0, (width, n_v)), axis=1)
    return u, v, obs_region_labels(u, v, problem.row, problem.col, pixel_start=problem.pixel_start)


@pytest.mark.parametrize("axis", ["u", "v"])
def test_per_pixel_two_cases_equal_reference(problem, axis):
    """The vector redraw's per-pixel sums: every observation's density in its base region and in base + step."""
    rng = np.random.default_rng(4)
    height, width = problem.image_shape
    u, v, labels = _changepoint_labels(problem, rng, 2, 1)       # 6 regions, as THETA
    size, step = (width, v.shape[1] + 1) if axis == "u" else (height, 1)
    cps, k = (u, 1) if axis == "u" else (v, 0)
    line_of, along_of = (problem.row, problem.col) if axis == "u" else (problem.col, problem.row)
    x_old = np.ascontiguousarray(cps[:, k])
    right, left = np.zeros(cps.shape[0] * size), np.zeros(cps.shape[0] * size)
    cells.per_pixel_two_cases(problem.y, problem.C, problem.log_cos_hn, line_of, along_of, labels, x_old, step, THETA,
                              size, right, left, problem.lobe)
    idx = np.arange(problem.n_obs)
    base = labels.astype(np.int64) - np.where(x_old[line_of] < along_of + 0.5, step, 0)
    key = line_of.astype(np.int64) * size + along_of
    expected_right = np.bincount(key, reference.obs_log_density(problem, idx, THETA[base]), minlength=right.size)
    expected_left = np.bincount(key, reference.obs_log_density(problem, idx, THETA[base + step]), minlength=left.size)
    np.testing.assert_allclose(right, expected_right, rtol=1e-11, atol=1e-8)
    np.testing.assert_allclose(left, expected_left, rtol=1e-11, atol=1e-8)
    # line r's log-likelihood with the element in cell j: pixels t < j in the base case, t >= j in the other
    by_cell = cells.cell_log_lik(right, left, cps.shape[0], size, 0.6)
    right_2d, left_2d = right.reshape(-1, size), left.reshape(-1, size)
    for j in (0, 1, size // 2, size):
        expected = 0.6 * (right_2d[:, :j].sum(axis=1) + left_2d[:, j:].sum(axis=1))
        np.testing.assert_allclose(by_cell[:, j], expected, rtol=1e-11, atol=1e-8)


@pytest.mark.parametrize("axis", ["u", "v"])
def test_removal_sums_equal_reference(problem, axis):
    """Per (line, column) sums with the observations as labelled, moved one column down and one up."""
    rng = np.random.default_rng(5)
    u, v, labels = _changepoint_labels(problem, rng, 2, 1)
    n, n_v = (u.shape[1], v.shape[1])
    n_axis = n if axis == "u" else n_v
    step = (n_v + 1) if axis == "u" else 1
    n_lines = problem.height if axis == "u" else problem.width
    line_of = problem.row if axis == "u" else problem.col
    totals = np.zeros((3, n_lines * (n_axis + 1)))
    cells.removal_sums(problem.y, problem.C, problem.log_cos_hn, line_of, labels, THETA, n_axis, n_v, step, axis == "u",
                       totals, problem.lobe)
    lab = labels.astype(np.int64)
    column = lab // (n_v + 1) if axis == "u" else lab % (n_v + 1)
    key = line_of.astype(np.int64) * (n_axis + 1) + column
    idx = np.arange(problem.n_obs)
    for case, region in enumerate([lab, np.where(column > 0, lab - step, lab), np.where(column < n_axis, lab + step, lab)]):
        expected = np.bincount(key, reference.obs_log_density(problem, idx, THETA[region]), minlength=totals.shape[1])
        np.testing.assert_allclose(totals[case], expected, rtol=1e-11, atol=1e-8)


def test_forward_filter_equals_fft_reference():
    rng = np.random.default_rng(2)
    size = 30
    log_emit = rng.normal(0.0, 3.0, (12, size + 1))
    offsets = np.arange(-size, size + 1)
    log_kernel = -0.5 * offsets ** 2 / (2.0 ** 2 + 1.0 / 12.0)
    alpha, ok = paths.forward_filter(log_emit, np.exp(log_kernel), size)
    assert ok
    np.testing.assert_allclose(alpha, reference.forward_filter(log_emit, log_kernel), atol=1e-9)
    independent, ok = paths.forward_filter(log_emit, np.zeros(0), 0)
    np.testing.assert_allclose(independent, log_emit - np.logaddexp.reduce(log_emit, axis=1, keepdims=True), atol=1e-12)


def test_backward_sampler_draws_paths_with_the_probability_it_reports():
    """Chi-square of path frequencies against exp(cell_path_log_prob) on a 3-line, 4-cell chain (level 0.001)."""
    rng = np.random.default_rng(3)
    n_lines, n_cells = 3, 4
    log_emit = rng.normal(0.0, 1.0, (n_lines, n_cells))
    offsets = np.arange(-(n_cells - 1), n_cells)
    log_kernel = -0.5 * offsets ** 2 / 1.5
    alpha, _ = paths.forward_filter(log_emit, np.exp(log_kernel), n_cells - 1)
    every_path = [np.array(p) for p in np.ndindex(*(n_cells,) * n_lines)]
    probs = np.exp([paths.cell_path_log_prob(alpha, p, log_kernel) for p in every_path])
    assert probs.sum() == pytest.approx(1.0, abs=1e-12)
    python_logits = reference.cell_step_logits(log_kernel)
    for p in every_path[::7]:
        assert paths.cell_path_log_prob(alpha, p, log_kernel) == pytest.approx(
            reference.path_log_prob(alpha, p, python_logits), abs=1e-12)
    n_draws = 20000
    counts = np.zeros(len(every_path))
    for _ in range(n_draws):
        path = paths.cell_backward_sample(alpha, log_kernel, rng.random(n_lines))
        counts[np.ravel_multi_index(tuple(path), (n_cells,) * n_lines)] += 1
    expected = n_draws * probs
    keep = expected >= 5                     # paths expected fewer than 5 times are pooled into one bin
    observed = np.append(counts[keep], counts[~keep].sum())
    expected = np.append(expected[keep], expected[~keep].sum())
    statistic = np.sum((observed - expected) ** 2 / np.maximum(expected, 1e-300))
    assert chi2.sf(statistic, observed.size - 1) > 1e-3


def test_split_into_runs_equals_one_gather_per_region(problem):
    # split's regions are runs of the problem's arrays: the same observations, and the same
    # sums (to float64 rounding: the runs are summed in another order) as a gather
    labels = _labels(problem, np.random.default_rng(5), 6)
    labels[labels == 4] = 3                      # an empty region too
    for r, data in enumerate(RegionData.split(problem, labels, 6)):
        whole = RegionData.gather(problem, np.flatnonzero(labels == r))
        np.testing.assert_array_equal(data.idx, whole.idx, err_msg=f"region {r}")
        for every in (2, 7):
            np.testing.assert_array_equal(sums.run_indices(*data.runs, every), whole.idx[::every])
        assert data.n == whole.n and data.weight == whole.weight
        gathered = data.thinned(1)
        for name in ("y", "C", "log_cos_hn"):
            np.testing.assert_array_equal(getattr(gathered, name), getattr(whole, name), err_msg=f"region {r} {name}")
        np.testing.assert_allclose(data.fixed, whole.fixed, rtol=1e-12, err_msg=f"region {r}")
        for gamma in (0.5, 10.0, 300.0):
            np.testing.assert_allclose(data.b_sums(gamma), whole.b_sums(gamma), rtol=1e-12, atol=0)
            np.testing.assert_allclose(data.b_sums_newton(gamma), whole.b_sums_newton(gamma), rtol=1e-12, atol=0)
    with pytest.raises(ValueError, match="labels must lie"):
        RegionData.split(problem, labels, 3)


def test_normal_cdf_and_quantile_equal_scipy():
    from scipy.special import ndtr, ndtri

    # quantile over both tails and the centre; the CDF down to 1e-300 (erfc's own accuracy there)
    p = np.concatenate([np.geomspace(1e-300, 0.5, 500), 1.0 - np.geomspace(1e-16, 0.5, 500),
                        np.random.default_rng(0).random(500)])
    mine = np.array([special.ndtri(v) for v in p])
    np.testing.assert_allclose(mine, ndtri(p), rtol=1e-12, atol=1e-15)
    x = np.linspace(-37.0, 9.0, 2001)
    np.testing.assert_allclose([special.ndtr(v) for v in x], ndtr(x), rtol=1e-12)
    assert special.ndtri(0.0) == -np.inf and special.ndtri(1.0) == np.inf


@pytest.mark.parametrize("sd", [None, 0.3, 2.0])
def test_within_cell_draw_and_density_equal_the_reference(sd):
    rng = np.random.default_rng(11)
    n_lines = 300
    # cells of width 0.2-1 that wander along the lines, with jumps far beyond the step sd
    # (the reference's uniform fallback) and cells wholly above or below the next line
    lo = np.cumsum(rng.normal(0.0, 0.7, n_lines)) + np.where(rng.random(n_lines) < 0.05, 25.0, 0.0)
    hi = lo + rng.uniform(0.2, 1.0, n_lines)
    expected = reference.draw_within_cells(lo, hi, sd, np.random.default_rng(5))
    step_sd = -1.0 if sd is None else sd
    compiled = paths.within_cells_draw(lo, hi, step_sd, np.random.default_rng(5).random(n_lines)[::-1].copy())
    np.testing.assert_allclose(compiled, expected, rtol=0, atol=1e-9)
    assert np.all((compiled >= lo) & (compiled < hi))
    for x in (compiled, lo + 0.5 * (hi - lo)):
        density = float(np.sum(reference.within_cell_log_density(x, x[1:], lo, hi, sd)))
        assert abs(paths.within_cells_log_density(x, lo, hi, step_sd) - density) < 1e-9 * max(1.0, abs(density))


def test_rank_chain_compiled_twins_equal_the_reference():
    """Forward alphas, path probabilities and backward draws of the removed-rank chain against
    reference.rank_chain / path_log_prob / backward_sample (the same uniforms, last line first)."""
    rng = np.random.default_rng(11)
    for n in (1, 2, 3):
        log_emit = rng.normal(0.0, 3.0, (40, n))
        log_emit[5, 0] = -np.inf if n > 1 else log_emit[5, 0]      # a rank that cannot be removed there
        log_t = rank_transitions(*log_emit.shape)
        alpha_ref, logits = reference.rank_chain(log_emit, log_t)
        alpha = paths.rank_forward(log_emit, log_t)
        np.testing.assert_allclose(alpha, alpha_ref, atol=1e-12)
        for seed in range(20):
            expected = reference.backward_sample(alpha_ref, logits, np.random.default_rng(seed))
            path = paths.rank_backward_sample(alpha, log_t, np.random.default_rng(seed).random(40))
            np.testing.assert_array_equal(path, expected)
            assert paths.rank_path_log_prob(alpha, path, log_t) == pytest.approx(reference.path_log_prob(alpha_ref, path, logits),
                                                                               abs=1e-10)


# -- threads within one chain ---------------------------------------------------------------

def _two_threads():
    import numba

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("Numba has one thread here: nothing to compare")


@pytest.fixture(scope="module")
def large_problem():
    """40,326 observations: over sums.PARALLEL_MIN_OBS, so the passes run in pieces."""
    obs, _, _ = sphere_stack(96, n_lights=10, seed=3)
    problem = Problem.from_observations(obs, likelihood_power=0.6)
    assert problem.n_obs >= sums.PARALLEL_MIN_OBS
    return problem


def test_split_runs_cuts_the_runs_into_equal_parts_in_order():
    rng = np.random.default_rng(7)
    lengths = rng.integers(0, 900, 200)
    starts = np.cumsum(np.r_[0, lengths[:-1] + rng.integers(0, 50, 199)])
    ends = starts + lengths
    pieces_start, pieces_end, offsets = sums.split_runs(starts, ends)
    total = int(lengths.sum())
    assert total >= sums.PARALLEL_MIN_OBS and offsets.size == sums.PARTS + 1 and offsets[-1] == pieces_start.size
    # the pieces are the runs' observations, in order, each once
    indices = np.concatenate([np.arange(a, b) for a, b in zip(starts, ends)])
    np.testing.assert_array_equal(np.concatenate([np.arange(a, b) for a, b in zip(pieces_start, pieces_end)]), indices)
    part_sizes = [int(np.sum(pieces_end[a:b] - pieces_start[a:b])) for a, b in zip(offsets[:-1], offsets[1:])]
    assert max(part_sizes) - min(part_sizes) <= 1 and sum(part_sizes) == total
    # below the threshold: one part, the runs themselves
    small_start, small_end, small_offsets = sums.split_runs(starts[:10], ends[:10])
    assert list(small_offsets) == [0, 10]
    np.testing.assert_array_equal(small_start, starts[:10])


def test_pixel_cuts_keep_each_pixel_whole_in_one_piece():
    """The per-pixel pass's pieces run at once and add into their pixels' entries: every cut
    must fall on a pixel's first observation (a pixel in two pieces would be a race), and the
    pieces stay near-equal (no piece more than one pixel's observations above n / PARTS)."""
    rng = np.random.default_rng(11)
    per_pixel = rng.integers(1, 12, 9000)         # 1 to 11 observations per pixel, ~54,000 in all
    pixel = np.repeat(np.arange(per_pixel.size), per_pixel)
    line_of, along_of = pixel // 97, pixel % 97
    n = pixel.size
    bounds = cells.pixel_cuts(line_of, along_of)
    assert bounds.size == sums.PARTS + 1 and bounds[0] == 0 and bounds[-1] == n
    assert np.all(np.diff(bounds) >= 0)
    inner = bounds[1:-1]
    assert np.all(pixel[inner] != pixel[inner - 1]), "a cut splits a pixel between two pieces"
    assert np.all(np.diff(bounds) <= n // sums.PARTS + per_pixel.max())


def test_passes_in_pieces_equal_the_reference_and_do_not_depend_on_the_threads(large_problem):
    """b_sums, b_sums_newton and the per-pixel sums over more than PARALLEL_MIN_OBS observations:
    the NumPy reference's values, and the same bits on one thread and on two."""
    _two_threads()
    problem = large_problem
    idx = np.arange(problem.n_obs)
    data = RegionData.gather(problem, idx)
    y, A = problem.y.astype(float), problem.C.astype(float) / math.pi
    lh = problem.log_cos_hn.astype(float)
    rng = np.random.default_rng(4)
    height, width = problem.image_shape
    u, v, labels = _changepoint_labels(problem, rng, 2, 1)
    x_old = np.ascontiguousarray(u[:, 1])

    def passes():
        right, left = np.zeros(height * width), np.zeros(height * width)
        cells.per_pixel_two_cases(problem.y, problem.C, problem.log_cos_hn, problem.row, problem.col, labels, x_old,
                                2, THETA, width, right, left)
        return ([sums.b_sums(data.y, data.C, data.log_cos_hn, *data.runs, g) for g in (0.3, 80.0)]
                + [sums.b_sums_newton(data.y, data.C, data.log_cos_hn, *data.runs, g) for g in (0.3, 80.0)]
                + [right, left])

    with numba_threads(1):
        one = passes()
    with numba_threads(2):
        two = passes()
    for a, b in zip(one, two):
        np.testing.assert_array_equal(a, b)
    for k, gamma in enumerate((0.3, 80.0)):
        B = b_terms(problem.C.astype(float), problem.log_cos_hn, gamma)
        terms = (y * B, A * B, B * B)
        np.testing.assert_allclose(one[k], [math.fsum(t) for t in terms], rtol=1e-12)
        newton = [math.fsum(t * w) for w in (1.0, lh, lh * lh) for t in terms]
        np.testing.assert_allclose(one[2 + k], newton, rtol=1e-11, atol=1e-9 * abs(np.array(newton)).max())
    base = labels.astype(np.int64) - np.where(x_old[problem.row] < problem.col + 0.5, 2, 0)
    key = problem.row.astype(np.int64) * width + problem.col
    for case, shift in ((one[4], 0), (one[5], 2)):       # right of the element, left of it
        expected = np.bincount(key, reference.obs_log_density(problem, idx, THETA[base + shift]), minlength=height * width)
        np.testing.assert_allclose(case, expected, rtol=1e-11, atol=1e-8)
