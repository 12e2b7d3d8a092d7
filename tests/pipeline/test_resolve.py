"""The options a fit runs with, resolved once (rjfit.pipeline.resolve): a given option the fit's models do
not read is refused in one line naming it; a measured stack gets the measured default without flags and says
so; a declared unknown camera response is calibrated under every preset or the fit refuses.

The refusals go through ``rjfit fit`` on a rendered paper_sphere (48 x 48): the data set is loaded and the
options refused before any chain runs (about a second each). The default line is checked on a real fit of a
four-light photometric-stereo folder (1 chain of 20 iterations, a few seconds).
"""
import json

import numpy as np
import pytest
from click.testing import CliRunner

from rjfit.cli import main
from rjfit.pipeline.fit_settings import assemble
from rjfit.pipeline.options import FitOptions
from rjfit.pipeline.resolve import DataFacts, default_lines, resolve_options

from builders import make_ps_folder

UNREAD = [
    # flags of the change-point model, under --regions materials (silently ignored until 2026-11-28)
    (["--regions", "materials", "--max-u", "2"], "--max-u"),
    (["--regions", "materials", "--max-v", "2"], "--max-v"),
    (["--regions", "materials", "--split-map", "mean"], "--split-map"),
    (["--regions", "materials", "--cp-prior", "paper"], "--cp-prior"),
    (["--regions", "materials", "--drop-jacobian"], "--drop-jacobian"),
    # the material model's, under change points
    (["--max-materials", "3"], "--max-materials"),
    (["--potts-beta", "2"], "--potts-beta"),
    (["--potts-rho", "0.5"], "--potts-rho"),
    (["--edge-power", "0"], "--edge-power"),
    # the shot and relative noise models', under the others
    (["--noise-floor", "0.1"], "--noise-floor"),
    (["--noise", "normals", "--noise-floor", "0.1"], "--noise-floor"),
    # the effects', without effects
    (["--effect-every", "5"], "--effect-every"),
    # the adaptive sampler's, under the paper's
    (["--sampler", "paper", "--gamma-moves", "3"], "--gamma-moves"),
]


@pytest.mark.parametrize("flags, flag", UNREAD, ids=[" ".join(f) for f, _ in UNREAD])
def test_a_flag_the_fit_does_not_read_is_refused_in_one_line(paper_sphere_small, tmp_path, flags, flag):
    result = CliRunner().invoke(main, ["fit", str(paper_sphere_small), "--out", str(tmp_path / "fit"),
                                       "--allow-unvalidated", "--iterations", "20", *flags])
    assert result.exit_code == 1, result.output
    message = result.output.strip()
    assert message.startswith("Error: ") and flag in message and "\n" not in message, message
    assert "Traceback" not in result.output and not (tmp_path / "fit" / "summary.json").exists()


def test_the_flags_are_read_where_they_apply():
    """The negative control: each refused flag is taken by the model that reads it."""
    for changes in ({"max_u": 2, "split_map": "mean", "cp_prior": "paper", "drop_jacobian": True},
                    {"regions": "materials", "max_materials": 3, "potts_beta": 2.0, "potts_rho": 0.5, "edge_power": 0},
                    {"noise": "shot", "noise_floor": 0.1}, {"noise": "relative", "noise_floor": 0.1},
                    {"effects": ("ambient",), "effect_every": 5}, {"sampler": "adaptive", "gamma_moves": 3}):
        resolved = resolve_options(FitOptions(**changes))
        assert all(resolved.source(name) == "given" for name in changes)


def test_a_measured_stack_gets_the_measured_default_without_flags_and_a_rendered_one_today_s():
    mask = np.ones((12, 12), bool)
    measured = DataFacts(kind="measured", layout="diligent", object_mask=mask)
    options = resolve_options(FitOptions(), measured)
    assert (options.regions, options.preset, options.noise, options.burn_in) == ("materials", "measured", "normals",
                                                                                  0.2)
    assert (options.source("regions"), options.source("preset")) == ("data", "data")
    # the preset's gamma moves reach the kernel's settings; a rendered stack keeps the plain 2
    assert (options.gamma_moves, options.source("gamma_moves")) == (8, "preset")
    assert (options.iterations, options.source("iterations")) == (500, "preset")
    assert resolve_options(FitOptions(iterations=40), measured).iterations == 40     # a given count is kept
    assert assemble(options, None, 0).within.g_moves == 8
    (line,) = default_lines(options, measured)
    assert "--regions materials --preset measured" in line and "--regions changepoints or --preset none" in line
    # opting out of one keeps the other, and the line names only what the data chose
    opted = resolve_options(FitOptions(regions="changepoints"), measured)
    assert (opted.regions, opted.preset) == ("changepoints", "measured")
    assert "--preset measured" in default_lines(opted, measured)[0] and "--regions" not in default_lines(
        opted, measured)[0].split(";")[0]
    rendered = resolve_options(FitOptions(), DataFacts(kind="rendered", object_mask=mask))
    assert (rendered.regions, rendered.preset, rendered.noise, rendered.burn_in) == ("changepoints", "none",
                                                                                      "constant", 0.5)
    assert assemble(rendered, None, 0).within.g_moves == 2 and rendered.iterations == 4000
    assert default_lines(rendered, DataFacts()) == []


def test_a_declared_unknown_response_is_calibrated_under_every_preset_or_refused():
    """``{"response": "unknown"}`` (psm-horse): raw codes are not radiances. Under --preset none the fit
    calibrates them and says so; a fit told not to calibrate refuses in one line."""
    unknown = DataFacts(kind="measured", response_unknown=True)
    for preset in ("none", "measured"):
        options = resolve_options(FitOptions(preset=preset), unknown)
        assert options.calibrate is True
    plain = resolve_options(FitOptions(preset="none"), unknown)
    assert plain.source("calibrate") == "data" and any("camera response" in line
                                                       for line in default_lines(plain, unknown))
    with pytest.raises(ValueError, match="unknown camera response"):
        resolve_options(FitOptions(calibrate=False), unknown)
    assert resolve_options(FitOptions(preset="none"), DataFacts(kind="measured")).calibrate is False


def test_a_fit_of_a_measured_folder_prints_the_default_it_used(tmp_path):
    folder = make_ps_folder(tmp_path / "ps")
    out = tmp_path / "fit"
    result = CliRunner().invoke(main, ["fit", str(folder), "--out", str(out), "--allow-unvalidated", "--preset",
                                       "none", "--chains", "1", "--iterations", "20"])
    assert result.exit_code == 0, result.output
    assert ("measured data (a photometric-stereo folder): fitted with the measured default --regions materials; "
            "give --regions changepoints to fit otherwise") in result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["region_model"] == "materials" and summary["fit_options"]["sources"]["regions"] == "data"
    assert summary["data_defaults"] == [line.strip() for line in result.output.splitlines()
                                        if line.strip().startswith("measured data")]


def test_the_light_field_is_estimated_where_the_gains_are():
    """--light-field shapes the per-light gains, which only a declared unknown response gets: the measured preset
    sets degree 2 there and 0 on a calibrated stack (the DiLiGenT ball); given where no gains are estimated, or
    out of range, it is refused in one line."""
    unknown, known = DataFacts(kind="measured", response_unknown=True), DataFacts(kind="measured")
    preset = resolve_options(FitOptions(), unknown)
    assert preset.light_field == 2 and preset.source("light_field") == "preset"
    assert resolve_options(FitOptions(), known).light_field == 0
    assert resolve_options(FitOptions(preset="none"), unknown).light_field == 0
    assert resolve_options(FitOptions(light_field=1), unknown).light_field == 1
    with pytest.raises(ValueError, match="--light-field is estimated with the per-light gains"):
        resolve_options(FitOptions(light_field=2), known)
    with pytest.raises(ValueError, match="--light-field is a polynomial's degree"):
        FitOptions(light_field=7)


def test_a_fit_of_an_uncalibrated_folder_divides_out_its_light_field(tmp_path):
    """A photometric-stereo folder declaring an unknown response, fitted with the measured default: the fit says
    it estimated the lights' fields, and its summary holds them (each light's and the common one)."""
    folder = make_ps_folder(tmp_path / "ps")
    (folder / "rjfit.json").write_text('{"response": "unknown"}')
    (folder / "light_intensities.txt").write_text("1 1 1\n" * 4)     # uncalibrated: declared equal
    out = tmp_path / "fit"
    result = CliRunner().invoke(main, ["fit", str(folder), "--out", str(out), "--allow-unvalidated", "--chains", "1",
                                       "--iterations", "20"])
    assert result.exit_code == 0, result.output
    assert "light field: each light's gain a degree-2 field over the image" in result.output
    calibration = json.loads((out / "summary.json").read_text())["calibration"]
    assert calibration["light_gains"]["field"]["degree"] == 2
    assert calibration["common_field"]["degree"] == 2 and len(calibration["common_field"]["coefficients"]) == 6
