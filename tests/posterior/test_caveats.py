"""Caveats of a fit's numbers, each triggered by a summary built to have it and absent from one without it;
R-hat's reasons where it cannot be computed."""
import numpy as np
import pytest

from rjfit.posterior.caveats import (
    CAP_MASS_MAX,
    PLAUSIBLE_MASS,
    acceptance_counts,
    chain_steep_warnings,
    empty_region_warnings,
    extra_materials,
    extra_materials_sentence,
    label_agreement_warnings,
    label_agreements,
    model_cap_warnings,
    nan_rejection_warnings,
    pooled_interval_warnings,
    prior_range_warnings,
    steep_view_shares,
    steep_view_warnings,
    support_bound_warnings,
)
from rjfit.posterior.summary import convergence_warnings, diagnostics, region_summaries
from rjfit.sampler.priors import ParamPrior, Prior

PRIOR = Prior(params=(ParamPrior("lognormal", np.log(100.0), 1.5), ParamPrior("uniform", 0.0, 1.0),
                      ParamPrior("lognormal", np.log(10.0), 1.5), ParamPrior("lognormal", np.log(0.01), 3.0)))
INSIDE = {"I0": 100.0, "kd": 0.5, "gamma": 10.0, "sigma2": 0.01}


def _region(index, **means):
    values = {**INSIDE, **means}
    return {"region": index, "pixels": 10,
            **{name: {"mean": v, "sd": 0.1 * abs(v), "q2.5": 0.9 * v, "q97.5": 1.1 * v} for name, v in values.items()}}


def test_a_mean_beyond_the_prior_s_central_99_9_percent_is_named_with_its_range():
    # I0 ~ LogNormal(log 100, 1.5): its central 99.9 % interval is 100 exp(+-3.29 x 1.5) = [0.72, 13918]
    regions = [_region(0), _region(1, I0=4.0e14), _region(2, gamma=0.008), _region(3, kd=1.0)]
    warnings = prior_range_warnings(regions, PRIOR)
    assert len(warnings) == 3
    assert warnings[0].startswith("region 1: I0 posterior mean 4e+14 lies at or above its prior's plausible range "
                                  "[0.7185, 1.392e+04] (the prior's central 99.9 % interval)")
    assert warnings[1].startswith("region 2: gamma posterior mean 0.008 lies at or below")
    assert warnings[2].startswith("region 3: kd posterior mean 1 lies at or above its prior's plausible range "
                                  "[0.0005, 0.9995]")          # a uniform prior's edge
    assert prior_range_warnings([_region(0)], PRIOR) == []
    low, high = PRIOR.params[0].central_interval(PLAUSIBLE_MASS)
    assert prior_range_warnings([_region(0, I0=0.999 * high)], PRIOR) == []


def test_an_interval_that_reaches_a_bound_of_the_prior_s_support_is_named():
    """kd ~ U(0, 1): an interval ending within 1 % of the width from 0 or 1 reaches the bound; the
    lognormal parameters have no finite bound to reach."""
    at_zero = _region(1, kd=0.04)
    at_zero["kd"].update({"q2.5": 0.0012, "q97.5": 0.12})
    at_one = _region(2)
    at_one["kd"].update({"q2.5": 0.97, "q97.5": 0.995, "mean": 0.985})
    near = _region(3)
    near["kd"].update({"q2.5": 0.011})                   # 1.1 % of the width from 0: not at it
    tiny_gamma = _region(4, gamma=1e-6)                  # far below its range, but lognormal: no bound
    warnings = support_bound_warnings([_region(0), at_zero, at_one, near, tiny_gamma], PRIOR)
    assert len(warnings) == 2, warnings
    assert warnings[0].startswith("region 1: kd's 95 % interval [0.0012, 0.12] reaches its prior's bound 0 (mean 0.04)")
    assert warnings[1].startswith("region 2: kd's 95 % interval [0.97, 0.995] reaches its prior's bound 1")


def test_a_colour_material_is_checked_per_channel_and_its_gamma_once():
    from rjfit.pipeline.regions.materials import material_number_warnings

    plain = _region(0)
    colour = {"region": 1, "material": 1, "pixels": 10, "gamma": {"mean": 0.008, "sd": 0.001, "q2.5": 0.007, "q97.5": 0.009},
              "channels": {c: {name: plain[name] for name in ("I0", "kd", "sigma2")} for c in "RGB"}}
    colour["channels"]["G"] = {**colour["channels"]["G"], "kd": {"mean": 0.03, "sd": 0.02, "q2.5": 0.001, "q97.5": 0.08}}
    warnings = material_number_warnings([plain, colour], PRIOR)
    assert len(warnings) == 2, warnings
    # a material the pooled MAP labels leave without pixels (seen on a 4-chain ball fit: [15791, 0])
    empty = material_number_warnings([plain, {**_region(1), "material": 1, "pixels": 0}], PRIOR)
    assert len(empty) == 1 and empty[0].startswith("material 1 of the MAP number of materials holds no pixel")
    assert warnings[0].startswith("region 1 (R): gamma posterior mean 0.008 lies at or below")      # once, not per channel
    assert warnings[1].startswith("region 1 (G): kd's 95 % interval [0.001, 0.08] reaches its prior's bound 0")


def test_a_region_without_observed_pixels_is_named():
    labels = np.array([[0, 0, 1], [1, 2, 2], [-1, 3, -1]])
    observed = np.array([[True, True, True], [True, False, False], [False, True, False]])
    warnings = empty_region_warnings(labels, observed, 4)
    # region 2 covers two object pixels, neither with an observation; region 3's pixel has one
    assert len(warnings) == 1 and warnings[0].startswith("region 2 of the MAP model holds no pixel with observations "
                                                         "(its pixels in the MAP labels: 2)")
    assert "among the model's 4 regions" in warnings[0]
    assert empty_region_warnings(labels, observed | (labels >= 0), 4) == []


def _sphere_view_angles(size=61):
    """(H, W) the view angle of an orthographic sphere filling a square (NaN outside), and its mask."""
    rows, cols = np.mgrid[0:size, 0:size]
    x, y = (cols - size // 2) / (size // 2 + 0.5), (rows - size // 2) / (size // 2 + 0.5)
    inside = x ** 2 + y ** 2 < 1.0
    angle = np.degrees(np.arccos(np.sqrt(np.clip(1.0 - x ** 2 - y ** 2, 0.0, 1.0))))
    return np.where(inside, angle, np.nan), inside


def test_a_material_on_the_steepest_tenth_is_named_and_a_central_paint_is_not():
    """A ring at the sphere's limb (all in the steepest tenth) is warned of; a disc at its centre and the body
    are not; the shares are the counted ones and the tail's angle is the 0.9 quantile of the labelled pixels'."""
    angle, inside = _sphere_view_angles()
    labels = np.where(inside, 0, -1)
    limit = np.quantile(angle[inside], 0.9)
    ring = inside & (angle >= np.quantile(angle[inside], 0.95))
    disc = inside & (angle < 15.0)
    labels[ring], labels[disc] = 1, 2
    shares, tail_angle = steep_view_shares(labels, angle, 3)
    assert tail_angle == pytest.approx(limit)
    assert shares[1] == 1.0 and shares[2] == 0.0
    body = (labels == 0)
    assert shares[0] == pytest.approx(np.mean(angle[body] >= limit))
    regions = [{"material": k, "pixels": int(np.sum(labels == k))} for k in range(3)]
    warnings = steep_view_warnings(regions, shares, tail_angle)
    assert len(warnings) == 1 and warnings[0].startswith(f"material 1 ({int(ring.sum())} px): 100% of its pixels")
    # the largest material is never warned of, however steep; a share at the bound is not above it
    assert steep_view_warnings(regions[:1], np.array([0.9]), tail_angle) == []
    assert steep_view_warnings(regions[1:2], np.array([0.5]), tail_angle) == []


def test_the_chains_steep_materials_are_named_in_one_warning_and_a_given_angle_is_kept():
    angle, inside = _sphere_view_angles()
    labels = np.where(inside, 0, -1)
    labels[inside & (angle > 80.0)] = 1
    limit = 70.0
    shares, kept = steep_view_shares(labels, angle, 2, angle_of=limit)
    assert kept == limit and shares[1] == 1.0
    assert shares[0] == pytest.approx(np.mean(angle[labels == 0] >= limit))
    per_chain = [[], [{"pixels": 40, "steep_view_share": 0.8}, {"pixels": 12, "steep_view_share": 0.2}],
                 [{"pixels": 9, "steep_view_share": 0.6}]]
    warnings = chain_steep_warnings(per_chain, 61.2)
    assert len(warnings) == 1 and "more than 61 deg" in warnings[0]
    assert "(chain 1: 40 px, 80% of them there; chain 2: 9 px, 60%)" in warnings[0] and "12 px" not in warnings[0]
    assert chain_steep_warnings([[], [{"pixels": 12, "steep_view_share": 0.5}]], 61.2) == []


def test_steep_shares_refuse_mismatched_maps_and_a_tail_outside_the_unit_interval():
    angle, inside = _sphere_view_angles(11)
    labels = np.where(inside, 0, -1)
    with pytest.raises(ValueError, match="labels' shape"):
        steep_view_shares(labels, angle[:-1], 1)
    with pytest.raises(ValueError, match="tail must lie in"):
        steep_view_shares(labels, angle, 1, tail=1.0)
    shares, tail_angle = steep_view_shares(labels, np.full(angle.shape, np.nan), 2)    # no angle known
    assert np.isnan(tail_angle) and np.all(np.isnan(shares))


def test_a_binding_model_cap_is_named_above_its_threshold():
    caps = {"n_u": (3, "--max-u"), "n_v": (2, "--max-v")}
    posterior = {"(3,1)": 0.30, "(2,1)": 0.66, "(1,2)": 0.04}
    warnings = model_cap_warnings(posterior, caps)
    assert warnings == [f"the model cap binds: 30% of the posterior has n_u = 3, the most allowed (warned above "
                        f"{CAP_MASS_MAX:.0%}): the posterior over models is cut there and the data may support more; "
                        "rerun with --max-u 4 to see"]
    # 4 % on n_v = 2 is under the threshold
    assert model_cap_warnings({"(1,1)": 0.96, "(1,2)": 0.04}, caps) == []


def test_a_pooled_mean_outside_its_own_interval_is_named():
    rng = np.random.default_rng(0)
    # two chains in two modes of I0 (20 and 1e6, one draw in a hundred in the far mode): the pooled mean
    # (about 1e4) is in neither mode and outside the pooled 95 % interval [about 20, about 20]
    near = np.tile([20.0, 0.5, 10.0, 0.01], (990, 1, 1)) * rng.uniform(0.99, 1.01, (990, 1, 4))
    far = np.tile([1e6, 0.5, 10.0, 0.01], (10, 1, 1))
    regions = region_summaries([near, far])
    warnings = pooled_interval_warnings(regions)
    assert len(warnings) == 1 and warnings[0].startswith("region 0: the pooled mean of I0, ")
    assert "outside its own 95 % interval" in warnings[0]
    assert pooled_interval_warnings(region_summaries([near])) == []


def test_nan_rejections_reach_the_counts_and_a_warning():
    class Record:
        def __init__(self, proposed, accepted, nan_rejected):
            self.proposed, self.accepted, self.nan_rejected = proposed, accepted, nan_rejected

    records = [Record({"vector_u": 10, "ab": 5}, {"vector_u": 2, "ab": 5}, {"vector_u": 1}),
               Record({"vector_u": 10}, {"vector_u": 3}, {})]
    counts = acceptance_counts(records)
    assert counts == {"ab": {"proposed": 5, "accepted": 5, "nan_rejected": 0},
                      "vector_u": {"proposed": 20, "accepted": 5, "nan_rejected": 1}}
    warnings = nan_rejection_warnings(counts)
    assert len(warnings) == 1 and warnings[0].startswith("1 of 20 'vector_u' proposals were rejected because their "
                                                         "acceptance ratio was NaN")


@pytest.mark.parametrize("case, reason", [
    ("one chain", "one chain: R-hat compares chains"),
    ("different models", "only 1 of 3 chains have 4 or more kept draws in the MAP model: the chains sit in different "
                         "models"),
    ("all constant", "every parameter of the MAP model is constant within a chain"),
])
def test_rhat_says_why_it_cannot_be_computed(case, reason):
    rng = np.random.default_rng(1)
    chains = {"one chain": [rng.normal(size=(100, 1, 4))],
              "different models": [rng.normal(size=(100, 1, 4)), np.empty((2, 1, 4)), np.empty((0, 1, 4))],
              "all constant": [np.ones((100, 1, 4)), np.ones((100, 1, 4))]}[case]
    diag = diagnostics(chains)
    assert np.isnan(diag["rhat_max"]) and diag["rhat_reason"].startswith(reason)


def test_a_parameter_constant_in_one_chain_has_no_rhat_and_is_named():
    rng = np.random.default_rng(2)
    chains = [rng.normal(size=(200, 2, 4)) for _ in range(3)]
    chains[1][:, 1, 2] = 7.0               # region 1's gamma never moves in chain 1
    diag = diagnostics(chains)
    assert diag["rhat_reason"] is None and np.isfinite(diag["rhat_max"])
    assert np.isnan(diag["rhat"][1][2]) and np.isfinite(diag["rhat"][1][1])
    assert diag["rhat_missing"] == [{"region": 1, "parameter": "gamma", "reason": "constant within chain 1"}]
    warnings = convergence_warnings(diag, [{"(1,0)": 1.0}] * 3, 3)
    assert any(w.startswith("R-hat not computable for 1 of the MAP model's parameters: region 1 gamma (constant "
                            "within chain 1)") for w in warnings), warnings


def test_rhat_and_ess_of_varying_parameters_are_arviz_s_own():
    """Leaving constant parameters out does not change the others' R-hat and ESS (ArviZ computes each alone)."""
    import arviz as az

    rng = np.random.default_rng(3)
    chains = [rng.normal(size=(300, 2, 4)) for _ in range(2)]
    stacked = np.stack(chains)
    data = az.convert_to_dataset({"theta": stacked}, dims={"theta": ["region", "parameter"]})
    diag = diagnostics(chains)
    assert diag["rhat"] == az.rhat(data)["theta"].values.tolist()
    assert diag["ess_bulk"] == az.ess(data, method="bulk")["theta"].values.tolist()


def test_a_material_the_draws_do_not_hold_is_named_and_the_agreements_are_the_pixels_means():
    """label_agreements is each material's mean of the agreement map over its pixels with a finite value (NaN
    without one); a material below half is warned of with its share, one at half is not."""
    labels = np.array([[0, 0, 1, 1], [0, 2, 2, -1], [3, 3, 3, -1]])
    agreement = np.array([[1.0, 0.8, 0.1, 0.3], [0.9, 0.5, 0.5, 0.0], [np.nan, np.nan, np.nan, 1.0]])
    shares = label_agreements(labels, agreement, 4)
    assert shares[:3] == pytest.approx([0.9, 0.2, 0.5]) and np.isnan(shares[3])
    regions = [{"material": k, "pixels": int(np.sum(labels == k))} for k in range(4)]
    warnings = label_agreement_warnings(regions, shares, 4)
    assert len(warnings) == 1 and warnings[0].startswith("material 1 (2 px): the draws with K = 4 give its pixels "
                                                         "this material in 20.0% of them")
    with pytest.raises(ValueError, match="labels' shape"):
        label_agreements(labels, agreement[:, :-1], 4)
    # summarised afresh over the draws that hold it: the warning says over which, and R-hat above RHAT_MAX among them
    regions[1]["parameters_from"] = {"draws": 120, "chains": [0, 2], "match_min": 0.5, "rhat_max": 1.8}
    (own,) = label_agreement_warnings(regions, shares, 4)
    assert "summarised over the 120 kept draws (of any K; chain 0, 2)" in own and "R-hat 1.80 over them" in own
    assert "belong to other pixels" not in own
    regions[1]["parameters_from"]["rhat_max"] = float("nan")
    assert "R-hat" not in label_agreement_warnings(regions, shares, 4)[0]


def _label_record(snapshots, iterations):
    """A material chain's record as the summaries read it: label snapshots (NaN off the object) at ``iterations``."""
    from types import SimpleNamespace

    return SimpleNamespace(cp_iteration=np.asarray(iterations), material_labels=np.asarray(snapshots, np.float32))


def test_the_extra_materials_of_snapshots_with_more_than_the_segmentation_are_counted_after_burn_in():
    """Two chains on a 6 x 6 object with one unlabelled corner: chain 0 at one material; chain 1's snapshots after
    burn-in hold a 3-px speck, then specks of 2 and 4 px (its third material the smaller two: 6 px in all; pixel
    (1, 2) in the speck both times), then one material; its snapshot before burn-in (half the object apart) is not
    counted."""
    one = np.zeros((6, 6))
    one[0, 0] = np.nan
    speck, two_specks, half = one.copy(), one.copy(), one.copy()
    speck[1, 2:5] = 1
    two_specks[1, 1:3], two_specks[4, 1:5] = 2, 1
    half[3:] = 1
    records = [_label_record([one, one, one, one], [0, 10, 20, 30]),
               _label_record([half, speck, two_specks, one], [0, 10, 20, 30])]
    entry, share = extra_materials(records, 10, 1)
    assert entry["snapshots"] == 6 and entry["share"] == pytest.approx(2 / 6)
    assert entry["chain_shares"] == [0.0, pytest.approx(2 / 3)]
    assert entry["pixels"] == {"min": 3, "median": 4.5, "max": 6}
    assert entry["most_often"] == {"row": 1, "column": 2, "share": pytest.approx(2 / 6)}
    assert extra_materials_sentence(entry) == (
        "33% of the kept label snapshots hold more materials than the segmentation's 1, their extra materials 3 to "
        "6 px (median 4) in all, most often at row 1, column 2 of the maps (33% of the snapshots; maps.exr's "
        "extra_material_share shows where)")
    expected = np.zeros((6, 6))
    expected[1, 2:5] += 1
    expected[1, 1:3] += 1
    expected[4, 1:5] += 1
    expected[0, 0] = np.nan
    np.testing.assert_array_equal(share, expected / 6)
    # against a segmentation of two materials the speck's snapshot adds nothing, the two specks' its 2 px
    two, _ = extra_materials(records, 10, 2)
    assert two["share"] == pytest.approx(1 / 6) and two["pixels"] == {"min": 2, "median": 2.0, "max": 2}
    assert two["most_often"] == {"row": 1, "column": 1, "share": pytest.approx(1 / 6)}       # the 2-px speck's first
    assert "their extra materials 2 px in all, most often at row 1, column 1" in extra_materials_sentence(two)
    placed = {**entry, "most_often": {**entry["most_often"], "contrast": {
        "lights": 12, "min": 1.18, "lower_quartile": 1.41, "median": 1.5, "upper_quartile": 1.8, "max": 2.63,
        "spread": 2.63 / 1.18, "middle_spread": 1.8 / 1.41, "pixels": 3, "border_pixels": 3, "ring_pixels": 20,
        "ring": [2, 4]}}}
    assert extra_materials_sentence(placed).endswith(
        "extra_material_share shows where), a place of 3 px: its Lambertian albedo is 1.18 to 2.63 times that of the "
        "pixels 2 to 4 px outside it under its 12 lights, 1.41 to 1.80 under the middle half of them (1.28-fold)")
    unseen = {**entry, "most_often": {**entry["most_often"], "contrast": None}}
    assert extra_materials_sentence(unseen).endswith(", a place whose observations cannot be compared with its "
                                                     "surroundings' (none there, or none around)")
    assert extra_materials_sentence(extra_materials(records[:1], 0, 1)[0]) is None      # never more: no sentence
    assert extra_materials([_label_record(np.zeros((0, 6, 6)), [])], 0, 1) == (None, None)    # no kept snapshot
