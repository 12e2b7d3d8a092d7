"""The segmentation a material fit reports: the kept label snapshot that least disagrees with the others, then whole
materials joined or set apart while the disagreement falls.

The case it was made for (docs/results/2026-11-28-steep-materials.md): chains that hold different small materials
at one K (a disc, another disc, a strip). Matched to one reference each is "the small material", so the per-pixel
mode at the most probable K gives none of them a pixel; counted as pixel pairs, the two discs that most draws set
apart from the body are set apart. The loss is checked against a direct count over every pixel pair.
"""
import numpy as np
import pytest

from rjfit.posterior.materials import central_snapshot, matched_draws, relabelled_draws, segmentation_estimate
from rjfit.sampler.runner import ChainRecord

SIZE = 12


def _patch(rows, cols):
    mask = np.zeros((SIZE, SIZE), bool)
    mask[rows, cols] = True
    return mask


DISC_A, DISC_B, STRIP = _patch(slice(1, 4), slice(1, 4)), _patch(slice(7, 10), slice(7, 10)), _patch(11, slice(2, 11))


def _labels(*parts):
    labels = np.zeros((SIZE, SIZE))
    for index, part in enumerate(parts, start=1):
        labels[part] = index
    return labels


def _record(snapshots, log_post):
    """A chain whose every iteration is a kept snapshot (``snapshots``: (S, H, W) labels)."""
    n = len(snapshots)
    k = np.array([int(s.max()) + 1 for s in snapshots])
    theta = np.full((n, 3, 4), np.nan)
    for t in range(n):
        theta[t, :k[t]] = [[1.0, 0.5, 10.0, 0.01]] * k[t]
    return ChainRecord(theta=theta, log_lik=np.zeros(n), log_post=np.asarray(log_post, float),
                       exact_truth=np.full(n, -1, np.int8), true_regions=np.full(n, -1, np.int8),
                       object_regions=k.astype(np.int16), cp_iteration=np.arange(n), accepted={}, proposed={},
                       seconds=0.0, iterations_done=n, n_materials=k,
                       material_labels=np.asarray(snapshots, np.float32), jumped=np.zeros(n, np.int8))


def _records():
    both, only_a, only_b, strip = _labels(DISC_A, DISC_B), _labels(DISC_A), _labels(DISC_B), _labels(STRIP)
    return [_record([both] * 20, np.zeros(20)), _record([only_a] * 10, np.zeros(10)),
            _record([only_b] * 10, np.zeros(10)), _record([strip] * 10, np.ones(10))]   # the strip: highest


def _pair_disagreements(a, b):
    """Pixel pairs grouped together in one labelling and apart in the other, counted pair by pair."""
    a, b = a.ravel(), b.ravel()
    together_a, together_b = a[:, None] == a[None, :], b[:, None] == b[None, :]
    return int(np.sum(np.triu(together_a != together_b, k=1)))


def test_the_discs_most_draws_set_apart_are_the_segmentation_where_the_mode_at_the_likeliest_k_loses_them():
    records = _records()
    chain, iteration, labels = central_snapshot(records, 0)
    every = [s for r in records for s in r.material_labels]
    losses = [sum(_pair_disagreements(a, b) for b in every) for a in every]
    assert every[int(np.argmin(losses))].tolist() == labels.tolist()        # the direct count's choice
    assert (chain, iteration) == (0, 0)
    assert set(np.unique(labels[DISC_A])) == {1} and set(np.unique(labels[DISC_B])) == {2}
    assert np.all(labels[~(DISC_A | DISC_B)] == 0)
    # the most probable K is 2 (30 of 50 snapshots); there the per-pixel mode (the summary until 2026-11-28), matched
    # to the highest snapshot (the strip), sets no disc apart
    matched = np.concatenate(relabelled_draws(records, 0, 2).labels)
    mode = np.argmax(np.stack([(matched == m).sum(axis=0) for m in range(2)]), axis=0)
    body = mode[SIZE // 2, 0]
    assert np.all(mode[DISC_A | DISC_B] == body)
    # the share of the segmentation's K draws that agree with it, pixel by pixel
    draws = relabelled_draws(records, 0, 3, reference=labels)
    np.testing.assert_array_equal(draws.agreement(labels), np.ones((SIZE, SIZE)))


def test_thinned_snapshots_and_pixels_still_choose_a_kept_snapshot_and_none_after_burn_in_is_refused():
    records = _records()
    _, _, labels = central_snapshot(records, 0, max_snapshots=7, max_pixels=50)
    assert any(labels.tolist() == s.tolist() for r in records for s in r.material_labels)
    _, iteration, _ = central_snapshot(records, 15)                      # only chain 0 keeps snapshots 15 to 19
    assert iteration >= 15
    with pytest.raises(ValueError, match="no label snapshot after burn-in"):
        central_snapshot(records, 20)


def _loss(labels, records):
    return sum(_pair_disagreements(labels, b) for r in records for b in r.material_labels)


def _same_partition(a, b):
    return _pair_disagreements(a, b) == 0


def test_a_speck_that_the_central_snapshot_holds_is_joined_to_the_body():
    """The snapshot with the typical disc also holds a 1-px material; the ones without it have the disc 2 px larger or
    smaller. The central snapshot is the speck's; joining the speck lowers the direct count to its least."""
    speck, larger = _patch(6, 0), DISC_A | _patch(4, slice(1, 3))
    smaller = DISC_A & ~_patch(3, slice(2, 4))
    records = [_record([_labels(DISC_A, speck)] * 10, np.zeros(10)), _record([_labels(larger)] * 10, np.zeros(10)),
               _record([_labels(smaller)] * 10, np.zeros(10))]
    _, _, central = central_snapshot(records, 0)
    assert _same_partition(central, _labels(DISC_A, speck))
    labels, origin = segmentation_estimate(records, 0)
    assert _same_partition(labels, _labels(DISC_A)) and len(origin["changes"]) == 1
    assert _loss(labels, records) < _loss(central, records)
    assert sorted(np.unique(labels).tolist()) == [0, 1]                       # numbered 0 .. K - 1


@pytest.mark.parametrize("n_typical,n_with_b,offset", [(14, 9, 3), (12, 10, 5)])
def test_a_disc_most_draws_hold_is_set_apart_though_no_snapshot_has_it_with_the_typical_rest(n_typical, n_with_b,
                                                                                               offset):
    """Disc B is in the snapshots of two chains of three, whose disc A is a few px too large (4 or 5) or too small (3);
    the third chain holds A exactly, without B. The estimate holds A and B exactly: B set apart from a chain's last
    labels, or A's exact outline from them; the direct count agrees that it is the least of all."""
    larger = DISC_A | _patch(4, slice(0, 4)) | _patch(5, slice(0, max(offset - 4, 0)))     # 4 or 5 px more
    smaller = DISC_A & ~_patch(3, slice(1, 1 + min(offset, 3)))
    records = [_record([_labels(DISC_A)] * n_typical, np.zeros(n_typical)),
               _record([_labels(larger, DISC_B)] * n_with_b, np.zeros(n_with_b)),
               _record([_labels(smaller, DISC_B)] * n_with_b, np.zeros(n_with_b))]
    _, _, central = central_snapshot(records, 0)
    labels, origin = segmentation_estimate(records, 0)
    assert not _same_partition(central, _labels(DISC_A, DISC_B))
    assert _same_partition(labels, _labels(DISC_A, DISC_B)), origin
    assert _loss(labels, records) < _loss(central, records)


def _chain(snapshots, theta):
    """A chain whose every iteration is a kept snapshot, with its own parameters ``theta`` (S, rows, 4)."""
    n = len(snapshots)
    k = np.array([int(s.max()) + 1 for s in snapshots])
    return ChainRecord(theta=np.asarray(theta, float), log_lik=np.zeros(n), log_post=np.zeros(n),
                       exact_truth=np.full(n, -1, np.int8), true_regions=np.full(n, -1, np.int8),
                       object_regions=k.astype(np.int16), cp_iteration=np.arange(n), accepted={}, proposed={},
                       seconds=0.0, iterations_done=n, n_materials=k,
                       material_labels=np.asarray(snapshots, np.float32), jumped=np.zeros(n, np.int8))


def test_a_materials_own_draws_are_those_of_any_k_whose_material_matches_its_pixels_more_than_half():
    """Disc A is held by chain 0 at K = 2 (material 1) and by chain 2 at K = 3 (material 2, after the strip); chain 1
    holds the strip alone, and chain 3 a patch of A plus as many other pixels (Jaccard index exactly 1/2: not a
    match). The own draws are chains 0's and 2's rows of disc A, each draw's own numbers; relabelling at K = 2
    (the Hungarian matching) would give chain 1's strip to it."""
    body, disc, strip, other = [1.0, 0.5, 10.0, 0.01], [3.0, 0.9, 20.0, 0.01], [7.0, 0.2, 5.0, 0.01], [9.0] * 4
    half = DISC_A | _patch(slice(5, 8), slice(5, 8))                        # 9 + 9 px: Jaccard 9 / 18 with A
    records = [_chain([_labels(DISC_A)] * 4, [[body, disc, other]] * 4),
               _chain([_labels(STRIP)] * 3, [[body, strip, other]] * 3),
               _chain([_labels(STRIP, DISC_A)] * 5, [[body, strip, disc]] * 5),
               _chain([_labels(half)] * 2, [[body, other, other]] * 2)]
    own = matched_draws(records, 0, DISC_A)
    assert [len(theta) for theta in own.theta] == [4, 0, 5, 0]
    for chain in (0, 2):
        np.testing.assert_array_equal(own.theta[chain][:, 0], np.tile(disc, (len(own.theta[chain]), 1)))
        np.testing.assert_array_equal(own.labels[chain][0] == 0, DISC_A)
    np.testing.assert_array_equal(own.reference, np.where(DISC_A, 0, -1))
    at_two = relabelled_draws(records, 0, 2, reference=_labels(DISC_A).astype(int))
    assert np.any(at_two.theta[1][:, 1] == strip[0])                       # what the K = 2 summary would mix in
    # one pixel fewer on the other side of the half patch: 9 / 17, a match
    closer = _labels(DISC_A | _patch(slice(5, 8), slice(5, 8)) & ~_patch(7, 7))
    assert len(matched_draws([_chain([closer], [[body, other, other]])], 0, DISC_A).theta[0]) == 1
    # a joint colour fit: each material's C rows, numbered material-major
    colour = np.array([[body, body, disc, strip, other, other]] * 4)        # material 1's channels: disc, strip
    own_colour = matched_draws([_chain([_labels(DISC_A)] * 4, colour)], 0, DISC_A, n_channels=2)
    assert own_colour.theta[0].shape == (4, 1, 2, 4)
    np.testing.assert_array_equal(own_colour.theta[0][0, 0], [disc, strip])
    with pytest.raises(ValueError, match="holds no pixel"):
        matched_draws(records, 0, np.zeros((SIZE, SIZE), bool))
    with pytest.raises(ValueError, match=r"least must be in \[0.5, 1\)"):
        matched_draws(records, 0, DISC_A, least=0.4)


def test_a_remnant_that_no_draw_holds_is_joined_though_the_loss_would_keep_it():
    """Chain 0 holds F (12 px); chains 1 and 2 hold G (12 px, 4 of them F's), chain 2 also a patch S; chain 3 holds
    F's other 8 px with S. Setting chain 3's material apart from the central snapshot (F's) leaves F's 4 px inside G
    as a material that no snapshot holds (Jaccard index 4/12 with F and with G); Binder's loss would keep it, the
    estimate joins it to the material of least loss instead, so that every material has draws to summarise."""
    f, g, s = _patch(slice(5, 7), slice(1, 7)), _patch(slice(5, 7), slice(5, 11)), _patch(slice(8, 10), slice(1, 3))
    records = [_record([_labels(f)] * 6, np.zeros(6)), _record([_labels(g)] * 4, np.zeros(4)),
               _record([_labels(g, s)] * 4, np.zeros(4)), _record([_labels((f & ~g) | s)] * 6, np.zeros(6))]
    labels, origin = segmentation_estimate(records, 0)
    assert origin["changes"][-1].startswith("material 1 (4 px, which no kept draw holds) joined to")
    remnant_kept = _labels((f & ~g) | s, f & g)                  # the estimate before the join
    assert _loss(remnant_kept, records) < _loss(labels, records)
    assert _same_partition(labels, _labels((f & ~g) | s | (f & g)))
    every = [snapshot.astype(int) for r in records for snapshot in r.material_labels]
    for m in range(int(labels.max()) + 1):
        mask = labels == m
        assert max(np.sum(mask & (snap == k)) / np.sum(mask | (snap == k)) for snap in every
                   for k in range(int(snap.max()) + 1)) > 0.5
