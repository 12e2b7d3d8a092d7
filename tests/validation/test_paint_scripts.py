"""Validation scripts on arrays built here: painted_details' hue discs, paint_share's and rock_pebbles' shares,
chain_labels' pieces and edge_pairs' boundary rows."""
from __future__ import annotations

import numpy as np
import pytest

from builders import tiny_problem, validation_script


def test_a_hue_disc_keeps_each_pixels_channel_sum_and_moves_red_and_green():
    """R gains hue x G (at most to 255), G loses as much: R + G + B is kept exactly, so the channel mean a
    one-channel fit reads does not change; B is untouched."""
    hue_shift = validation_script("painted_details").hue_shift
    rgb = np.array([[100.0, 120.0, 90.0], [240.0, 200.0, 210.0], [0.0, 0.0, 0.0], [10.0, 255.0, 3.0]])
    out = hue_shift(rgb, 0.5)
    np.testing.assert_array_equal(out.sum(axis=1), rgb.sum(axis=1))
    np.testing.assert_array_equal(out[:, 2], rgb[:, 2])
    np.testing.assert_array_equal(out[:, 0], [160.0, 255.0, 0.0, 138.0])       # 100 + 60; 240 + 15 (capped); 10 + 128
    assert np.all(out >= 0) and np.all(out <= 255)


def test_paint_share_counts_snapshots_that_hold_the_paint_in_one_non_body_material(tmp_path):
    """A 6 x 6 body with a 2 x 2 paint; one chain's snapshots: paint held (counted), paint split 3:1 (under
    90 %: not counted), paint in the body's material (not counted), held again; the first snapshot is burn-in;
    a second chain holds them in reverse order."""
    chain_shares = validation_script("paint_share").chain_shares
    paint = np.zeros((6, 6), bool)
    paint[2:4, 2:4] = True
    held = np.where(paint, 1.0, 0.0)
    split = held.copy()
    split[2, 2] = 2.0
    merged = np.zeros((6, 6))
    snapshots = np.stack([merged, held, split, merged, held])
    np.savez(tmp_path / "materials.npz", chain0_material_labels=snapshots, chain1_material_labels=snapshots[::-1])
    shares = chain_shares(tmp_path, paint, burn_in=0.2)
    assert shares == [0.5, 0.25]        # chain 1: reversed, its kept ones merged, split, held, merged


def test_rock_pebbles_counts_a_pebble_held_by_the_largest_pebbles_material(tmp_path):
    """An 8 x 8 matrix (material 0) with a 3 x 3 pebble 1 and a 2 x 2 pebble 2. Snapshots: both pebbles in
    material 1 (each held); pebble 2 split 2:2 between material 1 and material 2 (half: held); pebble 2 split 1:3
    (under half: not held); everything one material (the pebble material is the matrix's: neither held); the
    first is burn-in."""
    chain_shares = validation_script("rock_pebbles").chain_shares
    pebbles = np.zeros((8, 8), int)
    pebbles[1:4, 1:4] = 1
    pebbles[5:7, 5:7] = 2
    both = np.where(pebbles > 0, 1.0, 0.0)
    half, quarter = both.copy(), both.copy()
    half[5, 5:7] = 2.0
    quarter[5, 5:7], quarter[6, 5] = 2.0, 2.0
    whole = np.zeros((8, 8))
    snapshots = np.stack([whole, both, half, quarter, whole])
    np.savez(tmp_path / "materials.npz", chain0_material_labels=snapshots)
    (shares,) = chain_shares(tmp_path, pebbles, burn_in=0.2)
    np.testing.assert_allclose(shares, [0.75, 0.5])


def test_rock_pebbles_refuses_snapshots_of_another_frame(tmp_path):
    chain_shares = validation_script("rock_pebbles").chain_shares
    np.savez(tmp_path / "materials.npz", chain0_material_labels=np.zeros((2, 4, 4)))
    with pytest.raises(ValueError, match=r"label snapshots of \(4, 4\) px, the stack's \(5, 5\)"):
        chain_shares(tmp_path, np.zeros((5, 5), int), burn_in=0.0)


def test_chain_labels_reads_a_pieces_contrast_to_its_ring_per_light(tmp_path):
    """A 40 x 40 object of one material with a 2 x 2 piece of a second: under light 1 the piece is twice as bright
    as everything else, under light 2 as bright (a factor under one light only); a 1-px piece elsewhere is not read
    (under 2 px), and a chain without a second material has no piece. Moved at random, the piece sees no contrast
    but where its ring or itself overlaps the bright pixels (the median: none)."""
    from PIL import Image

    script = validation_script("chain_labels")
    labels = np.zeros((40, 40))
    labels[20:22, 20:22] = 1.0
    labels[0, 39] = 1.0
    np.savez(tmp_path / "materials.npz", chain0_material_labels=labels[None],
             chain1_material_labels=np.zeros((1, 40, 40)))
    stack = tmp_path / "stack"
    stack.mkdir()
    first = np.full((40, 40), 50, np.uint8)
    first[20:22, 20:22] = 100
    Image.fromarray(first).save(stack / "001.png")
    Image.fromarray(np.full((40, 40), 80, np.uint8)).save(stack / "002.png")
    (row,) = script.piece_contrasts(tmp_path, stack)
    chain, pixels, centre, ratios = row
    assert (chain, pixels, centre) == (0, 4, (20, 20))      # (20.5, 20.5) rounds half to even
    np.testing.assert_allclose(ratios, [2.0, 1.0])
    ((chain, count, held, moved),) = script.placement_control(tmp_path, stack, seed=1)
    assert (chain, count) == (0, 1)
    assert held == pytest.approx(np.log(2.0)) and moved == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError, match="no numbered PNG"):
        script.piece_contrasts(tmp_path, tmp_path)


def test_edge_pairs_rows_add_up_to_the_edge_terms_total():
    """On a 2 x 6 image of two materials under 3 lights, pairs 1 px apart: the boundaries' values from their pairs'
    rows add up to the term's own total (a second labelling, three materials, too), and a cap above every pair's
    earning changes nothing while a cap of 0 leaves no boundary earning."""
    from rjfit.sampler.forward import Problem
    from rjfit.sampler.regions.materials.edges import edge_term

    script = validation_script("edge_pairs")
    observations, prior = tiny_problem(seed=2, width=6)
    problem = Problem.from_observations(observations)
    edges = edge_term(problem, np.ones((2, 6), bool), power=1.0, gap=1)
    two, three = np.array([[0, 0, 0, 1, 1, 1]] * 2), np.array([[0, 0, 1, 1, 2, 2], [0, 0, 1, 2, 2, 2]])
    for labels in (two, three):
        theta = script.least_squares_theta(problem, labels, int(labels.max()) + 1, prior)
        rows = script.boundary_rows(edges, labels, theta)
        values = [script.boundary_value(r, edges.scale) for r in rows.values()]
        assert sum(values) == pytest.approx(edges.total(labels, theta), rel=1e-9, abs=1e-9)
        largest = max(float(np.max(edges.scale * (r[:, 3] - r[:, 0]))) for r in rows.values())
        assert [script.boundary_value(r, edges.scale, largest + 1.0) for r in rows.values()] == pytest.approx(values)
        assert all(script.boundary_value(r, edges.scale, 0.0) <= 1e-9 for r in rows.values())
