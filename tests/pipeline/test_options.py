"""FitOptions: every fit option declared once, its flag generated for ``rjfit fit``, its range checked."""
from __future__ import annotations

import json
from dataclasses import fields

import click
import pytest
from click.testing import CliRunner

from rjfit.cli import fit_options, main
from rjfit.pipeline.fit_folder import SUMMARY_FIELDS, write_summary
from rjfit.pipeline.options import FitOptions
from rjfit.pipeline.resolve import resolve_options


def test_every_command_line_option_of_fitoptions_is_a_flag_of_rjfit_fit():
    command = main.get_command(click.Context(main), "fit")
    flags = {opt for param in command.params for opt in getattr(param, "opts", [])}
    declared = FitOptions.cli_fields()
    assert len(declared) >= 15
    for name, default, spec in declared:
        assert spec.flag in flags, (name, spec.flag)
        param = next(p for p in command.params if spec.flag in p.opts)
        assert param.name == name          # the flag's value arrives under the field's name


def test_a_new_field_becomes_a_flag_without_touching_the_command():
    """What adding an option costs: a field. The decorator builds the command's options from the fields."""
    @click.command()
    @fit_options
    def probe(**options):
        click.echo(json.dumps(FitOptions(**options).n_chains))

    outcome = CliRunner().invoke(probe, ["--chains", "3"])
    assert outcome.exit_code == 0, outcome.output
    assert outcome.output.strip() == "3"
    assert {p.name for p in probe.params} == {name for name, _, _ in FitOptions.cli_fields()}


@pytest.mark.parametrize("changes, flag", [
    ({"burn_in": 1.5}, "--burn-in"), ({"n_chains": 0}, "--chains"), ({"iterations": 5}, "--iterations"),
    ({"prior": "flat"}, "--prior"), ({"noise": "poisson"}, "--noise"), ({"channel": "alpha"}, "--channel"),
    ({"likelihood_power": 1.5}, "--likelihood-power"), ({"likelihood_power": "often"}, "--likelihood-power"),
    ({"noise_floor": -0.1}, "--noise-floor"), ({"max_u": -1}, "--max-u"),
    # effects are of one channel: a joint colour fit takes none (the material model does, since 2026-11-27)
    ({"channel": "rgb", "regions": "materials", "effects": ("ambient",)}, "--effects"),
])
def test_an_option_out_of_range_names_its_flag(changes, flag):
    with pytest.raises(ValueError, match=flag):
        resolve_options(FitOptions(**changes))


def test_build_takes_keywords_and_refuses_what_is_not_an_option():
    options = FitOptions.build(None, seed=3, n_chains=2)
    assert (options.seed, options.n_chains, options.iterations) == (3, 2, None)       # None: not given
    assert resolve_options(options).iterations == FitOptions.default("iterations")
    assert FitOptions.build(options) is options
    assert FitOptions.build(options, likelihood_power="0.25").likelihood_power == 0.25
    with pytest.raises(TypeError):
        FitOptions.build(None, chains=2)


def test_options_that_the_command_line_does_not_offer_are_still_options():
    offered = {name for name, _, _ in FitOptions.cli_fields()}
    programmatic = {f.name for f in fields(FitOptions)} - offered
    assert {"anneal", "cp_thin", "processes", "figures", "progress", "jump_prob"} <= programmatic


def test_the_summary_writer_refuses_an_entry_the_schema_does_not_have(tmp_path):
    write_summary(tmp_path / "ok.json", {"seed": 1, "rhat_max": None, "regions": []})
    with pytest.raises(TypeError, match="SUMMARY_FIELDS"):
        write_summary(tmp_path / "bad.json", {"seed": 1, "made_up": 2})
    with pytest.raises(TypeError, match="'seed' is str"):
        write_summary(tmp_path / "bad.json", {"seed": "1"})
    assert not (tmp_path / "bad.json").exists()
    assert all(isinstance(meaning, str) and meaning for _, meaning in SUMMARY_FIELDS.values())


def test_options_round_trip_through_their_json_record(tmp_path):
    """summary.json "fit_options" gives back the options the fit ran with (what `rjfit refine` refits with)."""
    import json

    options = FitOptions(n_chains=2, iterations=50, effects=("ambient", "camera_srgb"), effects_from=tmp_path,
                         likelihood_power="auto", noise="relative", burn_in=0.3)
    record = json.loads(json.dumps(options.to_json()))
    assert FitOptions.from_json(record) == options
    assert FitOptions.from_json({**record, "a_newer_option": 1}) == options
    with pytest.raises(ValueError, match="--chains"):
        FitOptions.from_json({**record, "n_chains": 0})


def test_a_record_of_an_older_rjfit_gives_the_options_that_fit_ran_with():
    """Before 2026-11-28 a summary recorded every option filled (and no sources): its region model, preset and
    every value off its default come back as given, the other model's defaults do not (they would be refused)."""
    record = {**{name: FitOptions.default(name) for name in FitOptions.__dataclass_fields__ if name != "sources"},
              "regions": "materials", "preset": "measured", "noise": "normals", "potts_beta": 3.45, "burn_in": 0.2,
              "unset": ["noise"]}
    options = FitOptions.from_json(json.loads(json.dumps(record, default=list)))
    assert options.given() == {"regions": "materials", "preset": "measured", "noise": "normals", "potts_beta": 3.45,
                               "burn_in": 0.2}
    assert resolve_options(options).max_u == 3          # the change-point model's default, not given


def test_the_region_models_named_for_the_flag_are_the_registered_ones():
    """options.py names --regions' choices without importing the models (an import cycle): the names must be
    REGION_FITS' own, in its order, and each model's options fields of FitOptions."""
    from rjfit.pipeline.options import REGION_MODELS
    from rjfit.pipeline.regions import REGION_FITS

    assert REGION_MODELS == tuple(REGION_FITS)
    assert FitOptions.cli("regions").choices == REGION_MODELS
    for fit in REGION_FITS.values():
        assert fit.reads <= set(FitOptions.__dataclass_fields__), fit.name


def test_an_older_record_drops_what_its_region_model_did_not_read():
    """An rjfit before 2026-11-28 ignored another model's option: given the region models' own sets (what
    `rjfit refine` passes), such a value off its default is not brought back (it would be refused)."""
    from rjfit.pipeline.regions import REGION_FITS

    record = {**{name: FitOptions.default(name) for name in FitOptions.__dataclass_fields__ if name != "sources"},
              "regions": "materials", "max_u": 5, "potts_beta": 3.45}
    reads = {name: fit.reads for name, fit in REGION_FITS.items()}
    options = FitOptions.from_json(json.loads(json.dumps(record, default=list)), reads)
    assert options.given() == {"regions": "materials", "preset": "none", "potts_beta": 3.45}
    assert "max_u" in FitOptions.from_json(json.loads(json.dumps(record, default=list))).given()
