"""Validation scripts on arrays built here: painted_details' hue discs, paint_share's and rock_pebbles' shares."""
from __future__ import annotations

import numpy as np
import pytest

from builders import validation_script


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
