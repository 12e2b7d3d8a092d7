"""The composed sampler configuration: every flat option lands where FLAT_OPTIONS says, bad values are refused."""
import pytest

from rjfit.sampler.state import FLAT_OPTIONS, SamplerConfig

# a valid value different from the default, for every flat option
VALUES = {"max_u": 5, "max_v": 4, "cp_prior": "paper", "cp_smooth_sd": 1.5, "update_changepoints": False,
          "jumps": False, "cp_step": 1.0, "cp_uniform_prob": 0.1, "cp_neighbour_prob": 0.2, "cp_neighbour_sd": 0.7,
          "block_prob": 0.1, "block_max": 64, "block_shift_sd": 5.0, "vector_prob": 0.5, "jump_prob": 0.4,
          "free_jump_prob": 0.25, "split_map": "mean", "drop_jacobian": True, "split_scale": 0.3,
          "birth_straight_prob": 0.7, "birth_straight_sd": 2.0, "birth_gamma_inflation": 2.0,
          "min_obs_conditional": 10, "sampler": "paper", "gamma_move": "rw", "newton_scale": 0.5, "g_moves": 4,
          "target_accept": 0.3, "fallback_step": 0.2, "small_region_obs": 50, "full_recompute": True,
          "burn_in": 100, "anneal": 50, "anneal_start": 0.01, "refresh_every": 50, "effect_every": 3,
          "effect_target_accept": 0.4, "effect_curvature_every": 20, "effect_jitter": 0.1,
          "max_materials": 5, "potts_beta": 3.0, "potts_rho": 0.1, "update_labels": False, "label_sweeps": 2,
          "cluster_moves": 7, "cluster_new_prob": 0.2, "merge_split_moves": 3, "cluster_material_seed": 0.5,
          "segment_moves": 5, "edge_power": 0.5, "edge_gap": 5, "edge_gain_sd": 0.1, "edge_noise": "measured",
          "component_moves": 3, "spatial_split_moves": 2, "scatter_moves": 2}


def _at(config, path):
    node = config
    for part in path.split("."):
        node = getattr(node, part)
    return node


def test_every_flat_option_sets_its_places_and_nothing_else():
    """Each option on the region model it applies to (the materials' own on region_model='materials')."""
    assert set(VALUES) == set(FLAT_OPTIONS), "give every flat option a test value"
    for model in ("changepoints", "materials"):
        default = SamplerConfig.from_flat(region_model=model)
        every_path = [path for paths in FLAT_OPTIONS.values() for path in paths if _has(default, path)]
        for name, value in VALUES.items():
            if not any(_has(default, path) for path in FLAT_OPTIONS[name]):
                with pytest.raises(TypeError, match=f"{name} does not apply to the {model} region model"):
                    SamplerConfig.from_flat(region_model=model, **{name: value})
                continue
            options = {name: value, **({"burn_in": 100} if name == "anneal" else {})}   # anneal needs a burn-in
            config = SamplerConfig.from_flat(region_model=model, **options)
            changed = {path for option in options for path in FLAT_OPTIONS[option]}
            for path in every_path:
                expected = VALUES[_flat_name(path)] if path in changed else _at(default, path)
                assert _at(config, path) == expected, (model, name, path)
    assert _at(SamplerConfig(), "regions.birth_death.free_prob") != VALUES["free_jump_prob"]


def _has(config, path):
    try:
        _at(config, path)
    except AttributeError:
        return False
    return True


def _flat_name(path):
    return next(name for name, paths in FLAT_OPTIONS.items() if path in paths)


def test_min_obs_conditional_is_one_threshold_in_both_places():
    config = SamplerConfig.from_flat(min_obs_conditional=9)
    assert config.within.min_obs_conditional == config.regions.proposals.min_obs == 9


def test_unknown_option_is_refused_by_name():
    with pytest.raises(TypeError, match="max_w"):
        SamplerConfig.from_flat(max_w=2)


@pytest.mark.parametrize("options,match", [
    ({"sampler": "nuts"}, "sampler"), ({"gamma_move": "hmc"}, "gamma_move"), ({"newton_scale": 0.0}, "newton_scale"),
    ({"cp_prior": "wiggly"}, "cp_prior"), ({"split_map": "half"}, "split_map"), ({"max_u": -1}, "max_u"),
    ({"burn_in": 10, "anneal": 20}, "anneal"), ({"anneal_start": 0.0}, "anneal_start"),
    ({"free_jump_prob": 1.5}, "free_jump_prob"), ({"vector_prob": -0.1}, "vector_prob"),
    ({"jump_prob": 2.0}, "jump_prob"), ({"split_scale": 0.0}, "split_scale"), ({"cp_step": 0.0}, "cp_step"),
    ({"cp_uniform_prob": 0.6, "cp_neighbour_prob": 0.6}, "cp_uniform_prob")])
def test_bad_values_are_refused_naming_the_option(options, match):
    with pytest.raises(ValueError, match=match):
        SamplerConfig.from_flat(**options)
