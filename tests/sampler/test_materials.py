"""The material region model's passes against their NumPy twins, and its incremental bookkeeping.

The passes are compared with :mod:`rjfit.sampler.reference` on a 9 x 11 problem of three
materials (tolerance 1e-9 relative: float64 sums of float32 data in another order). The
bookkeeping test runs long random move sequences (Gibbs sweeps, cluster and segment moves
with births and deaths, within-material moves) with no refresh, and compares every material's
statistics and log-likelihood with a full recompute (1e-9 relative, as the brief states).
"""
import dataclasses

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from rjfit.data.observations import Observations
from rjfit.model.blinn import radiance
from rjfit.sampler import reference
from rjfit.sampler.forward import Problem
from rjfit.sampler.kernel import ChainContext, initial_state, step
from rjfit.sampler.regions.materials.kmeans import lloyd, lloyd_numpy, standardised, two_means_labels
from rjfit.sampler.likelihood import log_likelihood_from_stats, oracle_log_likelihood, region_stats
from rjfit.sampler.regions.materials import merge_split
from rjfit.sampler.regions.materials.passes import labels as passes
from rjfit.sampler.pixel_sets import PixelSets
from rjfit.sampler.priors import make_prior
from rjfit.sampler.regions.materials import layout as material_labels
from rjfit.sampler.regions.materials.layout import PottsPrior, bond_probabilities, boundary_count, kmeans_labels
from rjfit.sampler.regions.materials import MaterialRegions
from rjfit.sampler.state import SamplerConfig

from builders import raises

TRUTH = np.array([[10.0, 0.8, 5.0, 0.02], [6.0, 0.4, 30.0, 0.02], [14.0, 0.6, 12.0, 0.02]])


def material_problem(height=9, width=11, lights=6, seed=0, likelihood_power=1.0):
    """Three materials (a disc, a stripe and the rest) on a gently curved patch, with some invalid observations."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:height, 0:width]
    truth = np.zeros((height, width), int)
    truth[(rows - height / 2) ** 2 + (cols - width / 3) ** 2 < (height / 3.5) ** 2] = 1
    truth[:, width - 3:] = 2
    pixel = np.repeat(np.arange(height * width), lights)
    light = np.tile(np.arange(lights), height * width)
    keep = rng.random(pixel.size) > 0.1          # some pixels miss some lights
    pixel, light = pixel[keep], light[keep]
    cos_ln = rng.uniform(0.2, 1.0, pixel.size)
    cos_hn = rng.uniform(0.5, 1.0, pixel.size)
    irradiance = rng.uniform(0.5, 1.5, pixel.size)
    theta = TRUTH[truth.ravel()[pixel]]
    y = radiance(theta[:, 0], theta[:, 1], theta[:, 2], cos_ln, cos_hn, irradiance)
    y = y + rng.normal(0.0, np.sqrt(theta[:, 3]))
    obs = Observations(image_shape=(height, width), n_lights=lights, pixel=pixel.astype(np.int64),
                       light=light.astype(np.int32), y=y, cos_ln=cos_ln, cos_hn=cos_hn, irradiance=irradiance,
                       object_mask=np.ones((height, width), bool))
    return Problem.from_observations(obs, likelihood_power=likelihood_power), truth


def test_pixel_log_lik_matches_reference():
    problem, _ = material_problem()
    got = passes.pixel_log_lik(problem.y, problem.C, problem.log_cos_hn, problem.pixel, TRUTH, 9 * 11)
    want = reference.pixel_log_lik(problem, TRUTH)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)


def test_gibbs_sweep_matches_reference_and_keeps_every_material():
    problem, truth = material_problem()
    log_lik = reference.pixel_log_lik(problem, TRUTH)
    rng = np.random.default_rng(3)
    start = rng.integers(0, 3, truth.size)
    start[:3] = [0, 1, 2]
    start[3:] = np.where(start[3:] == 2, 0, start[3:])     # material 2 has one pixel: it must keep it
    labelled = np.ones(truth.size, bool)
    labelled[50] = False
    for parity in (0, 1):
        uniforms = rng.random(truth.size)
        z_fast, z_ref = start.copy(), start.copy()
        n_fast, n_ref = (np.bincount(start[labelled], minlength=3) for _ in range(2))
        changed = passes.gibbs_sweep(z_fast, labelled, log_lik, 0.7, 1.3, 9, 11, n_fast, uniforms, parity)
        assert changed == reference.gibbs_sweep(z_ref, labelled, log_lik, 0.7, 1.3, (9, 11), n_ref, uniforms, parity)
        np.testing.assert_array_equal(z_fast, z_ref)
        assert changed > 0 and z_fast[2] == 2 and z_fast[50] == start[50]
        moved = np.flatnonzero(z_fast != start)
        assert np.all((moved // 11 + moved % 11) % 2 == parity)


def test_edge_uniforms_and_clusters_match_reference():
    problem, truth = material_problem()
    bonds = bond_probabilities(problem)
    flat = truth.ravel().astype(np.int8)
    labelled = np.ones(flat.size, bool)
    key = 2 ** 62 + 12345
    for edge in (0, 1, 77, 197):
        assert passes.edge_uniform(np.uint64(key), np.uint64(edge)) == reference.edge_uniform(key, edge)
    for seed in (0, 40, 98):
        got = passes.grow_cluster(flat, labelled, bonds.q, np.uint64(key), seed, 9, 11, 3)
        want = reference.grow_cluster(flat, labelled, bonds.q, key, seed, (9, 11), 3)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])
        np.testing.assert_allclose(got[2], want[2], rtol=1e-12)
        assert np.all(flat[got[0]] == flat[seed])


def test_bonds_are_weak_across_true_boundaries():
    """The data-driven bonds (default ceiling 1 - 1/e): high between pixels of one material, low across materials."""
    problem, truth = material_problem()
    q = bond_probabilities(problem).q.reshape(9, 11, 2)
    same_right = truth[:, :-1] == truth[:, 1:]
    across = q[:, :-1, 0][~same_right]
    inside = q[:, :-1, 0][same_right]
    assert np.median(inside) > 0.4 > 0.1 > np.median(across) and np.all(q <= 1 - np.exp(-1.0))


def test_seed_weights_favour_weak_bonds_and_only_labelled_pixels():
    """The cluster moves' seeds: a probability per pixel, 0 off the labelled pixels, more on the borders."""
    problem, truth = material_problem()
    bonds = bond_probabilities(problem)
    weights = np.diff(bonds.seed_cdf, prepend=0.0).reshape(9, 11)
    assert weights.sum() == pytest.approx(1.0) and np.all(weights > 0)
    border = np.zeros(truth.shape, bool)
    border[:, 1:] |= truth[:, 1:] != truth[:, :-1]
    border[:, :-1] |= truth[:, 1:] != truth[:, :-1]
    border[1:] |= truth[1:] != truth[:-1]
    border[:-1] |= truth[1:] != truth[:-1]
    assert weights[border].mean() > 2 * weights[~border].mean()
    seeds = [bonds.draw_seed(np.random.default_rng(k)) for k in range(2000)]
    assert np.mean(border.ravel()[seeds]) == pytest.approx(weights[border].sum(), abs=0.05)
    labelled = np.ones((3, 4), bool)
    labelled[1, 2] = False
    q = bond_probabilities(problem).q[:24]
    first, second, edges = material_labels._edge_pairs(labelled)
    seed_weights = material_labels.seed_weights(labelled, q, 0.5, first, second, edges)
    assert seed_weights[6] == 0 and seed_weights.sum() == pytest.approx(1.0)


def test_potts_prior_and_kmeans():
    pixels = np.array([[0, 0, 1], [2, 1, 1], [-1, 1, 1]])
    assert boundary_count(pixels) == 4
    potts = PottsPrior(beta=0.5, rho=0.1)
    assert potts.log_density(pixels, 3) == pytest.approx(3 * np.log(0.1) - 0.5 * 4 - np.log(6))
    labels = kmeans_labels(np.array([[0.0, 0], [0, 0.1], [5, 5], [5, 5.1], [np.nan, np.nan]]), 3,
                           np.random.default_rng(0))
    assert sorted(set(labels)) == [0, 1, 2]


def test_start_checks():
    problem, truth = material_problem()
    regions = MaterialRegions(max_materials=2)
    rng = np.random.default_rng(0)
    with raises(ValueError, "more than max_materials=2"):
        regions.initial_layout(problem, rng, pixel_labels=truth)
    with raises(ValueError, "without a pixel"):
        MaterialRegions().initial_layout(problem, rng, pixel_labels=np.where(truth == 1, 2, truth))
    with raises(TypeError, "split_map does not apply to the materials region model"):
        SamplerConfig.from_flat(region_model="materials", split_map="mean")
    layout = MaterialRegions(max_materials=8).initial_layout(problem, rng)
    assert 1 <= layout.n_materials <= 4 and np.all(layout.counts() > 0)


@pytest.mark.parametrize("power", [1.0, 0.3])
def test_incremental_statistics_match_full_recompute(power):
    """Six chains of 300 iterations (no refresh), every move accepted in one or another: stats and log-likelihood
    equal a full recompute to 1e-9 relative at the end.

    One starts with 5 materials for 3 (twins: cluster moves between them, and without
    merges and splits, so that cluster moves kill them); two under an annealed warm-up
    (likelihood power rising from 1e-3 over 200 iterations, statistics rescaled at every
    step; beta 2: compact materials), one from 4 materials with every move, one from 6, the
    cap, with merges and splits the only jumps; one from 1 with segment moves the only jumps; one from 1 with the
    spatial splits the only jumps (beta 1, so that they are accepted at both powers; the others without them; a
    spatial merge makes its state as a merge does); one from 5 with the scatter moves the only jumps (a dissolve
    moves pixels to several materials at once).
    """
    problem, truth = material_problem(likelihood_power=power)
    prior = make_prior("default", y=problem.y, diffuse_scale=problem.A)
    kinds = set()
    annealed = {"burn_in": 200, "anneal": 200, "potts_beta": 2.0}
    # the last: one material at the start, segment moves the only jumps (so that they are accepted)
    chains = ((5, {"merge_split_moves": 0, "potts_beta": 1.0}), (4, annealed), (6, {**annealed, "cluster_moves": 0}),
              (1, {"cluster_moves": 0, "merge_split_moves": 0, "segment_moves": 4}),
              (1, {"cluster_moves": 0, "merge_split_moves": 0, "segment_moves": 0, "spatial_split_moves": 2,
                   "potts_beta": 1.0}),
              (5, {"cluster_moves": 0, "merge_split_moves": 0, "segment_moves": 0, "scatter_moves": 2}))
    for start, flat in chains:
        config = SamplerConfig.from_flat(region_model="materials", max_materials=6, refresh_every=0,
                                         **{"burn_in": 0, "cluster_moves": 6, "spatial_split_moves": 0, **flat})
        rng = np.random.default_rng(11)
        state = initial_state(problem, prior, config, rng, n_materials=start)
        context = ChainContext()       # the chain's reusable work, as a fit's runner keeps it
        with threadpool_limits(1):
            for _ in range(300):
                state, info = step(state, rng, problem, prior, config, context)
                kinds |= {k for k, v in info.accepted.items() if v}
        labels = state.layout.labels(problem)
        np.testing.assert_array_equal(labels, state.labels)
        assert np.all(state.layout.counts() > 0)
        full = region_stats(problem, labels, state.theta[:, 2], state.n_regions)
        np.testing.assert_allclose(state.stats, full, rtol=1e-9, atol=1e-9 * np.abs(full).max())
        np.testing.assert_allclose(state.log_lik, log_likelihood_from_stats(full, state.theta), rtol=1e-9)
        assert state.total_log_lik == pytest.approx(oracle_log_likelihood(problem, labels, state.theta), rel=1e-9)
    assert {"label_gibbs", "cluster", "cluster_birth", "cluster_death", "split", "merge"} <= kinds, kinds
    assert {"segment", "segment_birth", "segment_death"} & kinds, kinds
    assert "spatial_split" in kinds, kinds
    assert "dissolve" in kinds, kinds


def test_allocate_split_matches_reference_and_evaluates_its_own_draws():
    """The sequential allocation against its twin: draws, their log probability, and a forced allocation's."""
    problem, truth = material_problem()
    members = np.flatnonzero(truth.ravel() != 2)
    guide = reference.pixel_log_lik(problem, TRUTH[:2])[:, members]
    rng = np.random.default_rng(4)
    uniforms = rng.random(members.size)
    free = np.full(members.size, -1, np.int8)
    for power, beta in ((1.0, 1.0), (0.05, 2.0)):
        parts, log_p = passes.allocate_split(members, guide, power, beta, 9, 11, uniforms, free)
        want_parts, want_log_p = reference.allocate_split(members, guide, power, beta, (9, 11), uniforms, free)
        np.testing.assert_array_equal(parts, want_parts)
        assert log_p == pytest.approx(want_log_p, rel=1e-12)
        again = passes.allocate_split(members, guide, power, beta, 9, 11, np.empty(0), parts)
        np.testing.assert_array_equal(again[0], parts)
        assert again[1] == pytest.approx(log_p, rel=1e-12)
        forced = (rng.random(members.size) < 0.5).astype(np.int8)
        got = passes.allocate_split(members, guide, power, beta, 9, 11, np.empty(0), forced)[1]
        assert got == pytest.approx(reference.allocate_split(members, guide, power, beta, (9, 11), np.empty(0),
                                                             forced)[1], rel=1e-12)
    # at power 1 the guides are the disc's and the background's truth: the draw separates them
    parts, _ = passes.allocate_split(members, guide, 1.0, 1.0, 9, 11, uniforms, free)
    assert np.array_equal(parts, (truth.ravel()[members] == 1).astype(np.int8))


def test_split_guide_is_a_function_of_the_pixel_set_and_finds_the_two_paints():
    """The guide from the disc and background pixels together: deterministic, and it tells the two apart."""
    problem, truth = material_problem()
    prior = make_prior("default", y=problem.y, diffuse_scale=problem.A)
    features = bond_probabilities(problem).features
    members = np.flatnonzero(truth.ravel() != 2)
    guide = merge_split.split_guide(problem, prior, members, features)
    np.testing.assert_array_equal(guide, merge_split.split_guide(problem, prior, members, features))
    prefers = np.argmax(guide, axis=0)
    disc = truth.ravel()[members] == 1
    assert len(set(prefers[disc])) == 1 and len(set(prefers[~disc])) == 1 and prefers[disc][0] != prefers[~disc][0]
    assert two_means_labels(np.ones((5, 2))) is None


@pytest.mark.parametrize("n_features", [2, 3, 6])
def test_compiled_lloyd_gives_numpys_labels_and_centres_to_the_last_bit(n_features):
    """The split guide's 2-means is compiled: the same numbers, or a chain's draws would change."""
    rng = np.random.default_rng(n_features)
    for trial in range(60):
        n, k = int(rng.integers(3, 300)), int(rng.integers(2, 4))
        x = rng.normal(size=(n, n_features)) * rng.exponential(size=n_features)
        if trial % 3 == 1:
            x = np.round(x, 1)          # ties between distances
        if trial % 3 == 2:
            x[: n // 2] = x[0]          # repeated rows: clusters left empty
        x = standardised(x)
        start = x[rng.choice(n, k, replace=False)]
        compiled, plain = start.copy(), start.copy()
        np.testing.assert_array_equal(lloyd(x, compiled), lloyd_numpy(x, plain))
        np.testing.assert_array_equal(compiled, plain)


def test_pixel_sets_hand_out_one_data_object_per_set_and_its_values_are_those_computed_afresh():
    """The chain's memo of pixel sets: the same set, the same object (its Laplace fit and split guide kept);
    another problem (likelihood power) empties it; the pixels it holds are bounded."""
    problem, truth = material_problem()
    prior = make_prior("default", y=problem.y, diffuse_scale=problem.A)
    features = bond_probabilities(problem).features
    members = np.flatnonzero(truth.ravel() != 2)
    sets = PixelSets(capacity=3).valid_for(problem)      # the set and its guide's two clusters
    guide = merge_split.split_guide(problem, prior, members, features, sets)
    np.testing.assert_array_equal(guide, merge_split.split_guide(problem, prior, members, features))
    assert merge_split.split_guide(problem, prior, members, features, sets) is guide
    assert sets.data(problem, members.copy()) is sets.data(problem, members)
    for first in (0, 5, 10):
        sets.data(problem, np.arange(first, first + 5))     # three other sets: the least recently used go
    assert sets.data(problem, members).memo == {}
    weaker = dataclasses.replace(problem, likelihood_power=0.5)
    assert sets.valid_for(weaker).data(weaker, members).weight == 0.5
    # a bound on the pixels held: at one image's worth, a whole-image set pushes out every other
    bounded = PixelSets(capacity=32, images=1.0).valid_for(problem)
    small = bounded.data(problem, np.arange(5))
    bounded.data(problem, np.arange(problem.height * problem.width))
    assert bounded.data(problem, np.arange(5)) is not small


def test_slab_material_map_assigns_faces_by_texel():
    """geometry.material_map: each face of the slab takes the texel under its centroid (a 2 x 2 map of 3 materials)."""
    from rjfit.data.descriptions import check_scene_definition
    from rjfit.data.meshes import dented_slab
    from rjfit.errors import DatasetError
    from rjfit.render.render import load_scene_definition

    parts = dented_slab(size=2.0, resolution=20, material_map=[[0, 1], [2, 0]], materials=(0, 1, 2))
    for mesh, material in parts:
        centre = mesh.triangles_center
        quadrant = np.where(centre[:, 1] > 0, np.where(centre[:, 0] < 0, 0, 1), np.where(centre[:, 0] < 0, 2, 0))
        assert np.all(quadrant == material)
    definition = load_scene_definition("dented_plaster")
    definition["geometry"].update(material_map=[[0, 1], [2, 0]], materials=[0, 1])
    with pytest.raises(DatasetError, match="material"):
        check_scene_definition(definition)


def test_the_start_majority_filter_makes_a_scattered_labelling_compact_and_keeps_the_labels_dense():
    """A chain's start (majority_labels over its k-means labels): two halves whose labels are
    20 % scattered come back as the two halves (a 5 x 5 majority of 80 % is wrong with
    probability P(Bin(25, 0.2) >= 13) = 4e-4 per pixel away from the boundary: 0.99 allows 25
    times that); a label with no window majority goes and the others are
    renumbered 0 .. K' - 1; unlabelled pixels stay -1."""
    from rjfit.sampler.regions.materials.layout import boundary_count, majority_labels

    rng = np.random.default_rng(0)
    truth = np.zeros((30, 40), np.int8)
    truth[:, 20:] = 1
    noisy = np.where(rng.random(truth.shape) < 0.2, 1 - truth, truth).astype(np.int8)
    noisy[0, 0] = 2                               # a third label on one pixel: no window's majority
    noisy[:, 39] = -1                             # unlabelled
    out, k = majority_labels(noisy, 3)
    assert k == 2 and set(np.unique(out)) == {-1, 0, 1}
    assert np.all(out[:, 39] == -1)
    inside = (np.abs(np.arange(40) - 19.5) > 3)[None, :] & (noisy >= 0)
    assert np.mean(out[inside] == truth[inside]) >= 0.99
    assert boundary_count(out) < boundary_count(noisy) / 10
