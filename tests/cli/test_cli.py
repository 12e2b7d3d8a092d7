"""The command line: every command documented, the gate enforced, the main job end to end."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from rjfit.cli import main
from rjfit.data.noise import NOISE_MODELS

COMMANDS = ("render", "validate", "fit", "diagnose", "refine", "compare", "report", "run")


def test_every_command_has_help():
    runner = CliRunner()
    listing = runner.invoke(main, ["--help"])
    assert listing.exit_code == 0
    for command in COMMANDS:
        assert command in listing.output
        result = runner.invoke(main, [command, "--help"])
        assert result.exit_code == 0 and "--help" in result.output, command
    assert "--seed" in runner.invoke(main, ["fit", "--help"]).output


def test_refine_defaults_to_the_loops_own_cap():
    # the command line states its defaults without importing the loop (--help stays light); they must agree
    from rjfit.pipeline.refine import MAX_ROUNDS

    (option,) = [param for param in main.commands["refine"].params if param.name == "max_rounds"]
    assert option.default == MAX_ROUNDS


def test_fit_help_states_the_noise_models_and_their_floor():
    text = " ".join(CliRunner().invoke(main, ["fit", "--help"], terminal_width=200).output.split())
    assert "--noise [constant|shot|relative|normals|footprint]" in text and "--noise-floor" in text
    # the help says what each model does and points at the page that holds the formulas and measurements
    assert "docs/options.md" in text and all(f"{model} (" in text for model in NOISE_MODELS)
    page = (Path(__file__).parents[2] / "docs" / "options.md").read_text()
    for formula in ("s_i = 1", "s_i^2 = (m_i + c) / ybar", "s_i = (m_i + c) / ybar", "c = `--noise-floor` x ybar",
                    "s_i^2 = 1 + k g_i^2", "s_i^2 = 1 + k g_i^2 + t f_i^2", "f_i^2 = |grad_x y_i|^2 / 12"):
        assert formula in page, formula
    result = CliRunner().invoke(main, ["fit", ".", "--out", "x", "--noise", "poisson"])
    assert result.exit_code != 0 and "poisson" in result.output
    assert "--preset [none|measured]" in text and "'area'" in text


def test_a_normal_error_estimated_at_its_bound_says_so():
    """`rjfit fit`'s summary line: a normals' noise k at 0 (psm-horse's) is read as constant noise, not as a measured 0 deg."""
    from rjfit.cli import _normal_error_text

    at_bound = _normal_error_text({"k": 0.0, "sigma_n_deg": 0.0})
    assert at_bound.startswith("normal error sd 0 deg (at its bound 0") and "constant" in at_bound
    inside = _normal_error_text({"k": 2e-5, "sigma_n_deg": 0.42, "c": 0.52})
    assert inside == "normal error sd 0.42 deg, footprint c 0.52"


def test_python_dash_m_works():
    result = subprocess.run([sys.executable, "-m", "rjfit", "--help"], capture_output=True, text=True, check=False)
    assert result.returncode == 0 and "validate" in result.stdout


def test_fit_refuses_an_unvalidated_data_set_with_one_clear_line(paper_sphere_small, tmp_path):
    import shutil

    dataset = tmp_path / "copy"
    shutil.copytree(paper_sphere_small, dataset)
    shutil.rmtree(dataset / "validation", ignore_errors=True)
    result = CliRunner().invoke(main, ["fit", str(dataset), "--out", str(tmp_path / "fit")])
    assert result.exit_code == 1
    assert "has not been cross-checked" in result.output and "--allow-unvalidated" in result.output
    assert "Traceback" not in result.output
    assert not (tmp_path / "fit" / "summary.json").exists()
    # forced, the fit runs, and its summary, its warnings and the command's output say so
    result = CliRunner().invoke(main, ["fit", str(dataset), "--out", str(tmp_path / "fit"), "--allow-unvalidated",
                                       "--iterations", "20", "--chains", "1", "--threads", "2"])
    assert result.exit_code == 0, result.output
    summary = json.loads((tmp_path / "fit" / "summary.json").read_text())
    import numba

    assert summary["chain_threads"] == [min(2, numba.config.NUMBA_NUM_THREADS)]     # --threads reaches the chain
    assert summary["validation"]["passed"] is None
    assert summary["warnings"][0].startswith("the forward model was not cross-checked")
    assert f"WARNING: {summary['warnings'][0]}" in result.output
    # one chain: the one-line summary says why there is no R-hat instead of printing nan
    assert "R-hat: not computable (one chain: R-hat compares chains" in result.output and "nan" not in result.output


def test_bad_input_is_one_line_naming_the_file(tmp_path):
    folder = tmp_path / "broken"
    folder.mkdir()
    (folder / "filenames.txt").write_text("001.png\n")
    result = CliRunner().invoke(main, ["validate", str(folder)])
    assert result.exit_code == 1 and str(folder) in result.output and "Traceback" not in result.output


def test_fit_names_what_is_wrong_before_it_runs(paper_sphere_small, tmp_path):
    """A folder that is not a data set, a --validation file that does not exist and a
    truncated dataset.json each give one line naming the file, before any chain runs."""
    import shutil

    runner = CliRunner()
    empty = tmp_path / "empty"
    empty.mkdir()
    result = runner.invoke(main, ["fit", str(empty), "--out", str(tmp_path / "f1")])
    assert result.exit_code == 1 and "not a data set" in result.output and "rjfit validate" not in result.output
    result = runner.invoke(main, ["fit", str(paper_sphere_small), "--out", str(tmp_path / "f2"),
                                  "--validation", str(tmp_path / "nothere.json")])
    assert result.exit_code == 1 and "nothere.json: no such validation file" in result.output
    broken = tmp_path / "broken"
    shutil.copytree(paper_sphere_small, broken)
    text = (broken / "dataset.json").read_text()
    (broken / "dataset.json").write_text(text[: len(text) // 2])
    result = runner.invoke(main, ["validate", str(broken)])
    assert result.exit_code == 1 and "dataset.json: not valid JSON" in result.output
    assert "Traceback" not in result.output
    assert not any((tmp_path / name).exists() for name in ("f1", "f2"))


def test_diagnose_names_a_folder_that_is_not_a_fit(paper_sphere_small, tmp_path):
    result = CliRunner().invoke(main, ["diagnose", str(paper_sphere_small)])
    assert result.exit_code == 1 and "not a fit folder (no summary.json)" in result.output
    assert "Traceback" not in result.output


def test_run_stops_after_a_failed_cross_check(tmp_path):
    """The dented plaster's interreflections are missing from the closed form: the gate fails,
    and the main job must stop there rather than fit data it cannot trust."""
    result = CliRunner().invoke(main, ["run", "dented_plaster", "--out", str(tmp_path / "run"), "--resolution", "24",
                                       "--iterations", "20", "--chains", "1"])
    assert result.exit_code == 1 and "FAILED" in result.output and "--allow-unvalidated" in result.output
    assert not (tmp_path / "run" / "fit").exists()


def test_main_job_runs_end_to_end_and_points_at_the_report(tmp_path, paper_sphere_small):
    result = CliRunner().invoke(main, ["run", "--out", str(tmp_path / "run"), "--resolution", "32",
                                       "--iterations", "200", "--chains", "2"])
    assert result.exit_code == 0, result.output
    report = tmp_path / "run" / "fit" / "report.html"
    assert str(report.resolve()) in result.output
    html = report.read_text()
    assert html.count("data:image/png;base64,") >= 5 and "passed" in html
    # the baselines' markdown table is rendered as an HTML table, not shown as source
    assert "<th>method</th>" in html and "|---" not in html
    summary = json.loads((tmp_path / "run" / "fit" / "summary.json").read_text())
    assert summary["validation"]["passed"] is True
    # the two chains share the cores: each gets the cores the other leaves free
    import numba

    from rjfit.sampler.runner import available_cores

    cores = available_cores()
    assert summary["chain_threads"] == [min(max(1, cores // min(2, cores)), numba.config.NUMBA_NUM_THREADS)] * 2
    # convergence warnings (a 200-iteration run may have some) reach the report verbatim
    import html as html_module

    assert all(html_module.escape(w) in html for w in summary["warnings"])
    assert ("Warnings (convergence, model misfit and the numbers themselves)" in html) == bool(summary["warnings"])
    assert ("Convergence checks passed" in html) != bool(summary["warnings"])
    # rjfit run ends with refine: its first diagnosis is the fit's, and the report shows its rounds
    assert (tmp_path / "run" / "fit" / "refine" / "refine.json").is_file() and "Refinement (rjfit refine" in html
    for produced in ("fit/comparison/comparison.json", "fit/diagnosis/diagnosis.json", "fit/chains.nc",
                     "fit/labels.exr", "fit/maps.exr", "dataset/validation/validation.json"):
        assert (tmp_path / "run" / produced).is_file(), produced
    # the parameter maps hold each region's posterior means and sds where its label is
    # (their residual map is checked against known parameters in test_fit.py)
    from rjfit.data.exr import read_exr

    maps = read_exr(tmp_path / "run" / "fit" / "maps.exr")
    for index, region in enumerate(summary["regions"]):
        where = maps["label"] == region.get("region", index)
        assert where.any()
        np.testing.assert_allclose(maps["I0"][where], region["I0"]["mean"], rtol=1e-6)
        np.testing.assert_allclose(maps["kd_sd"][where], region["kd"]["sd"], rtol=1e-6)
    # the valid-images map (paper, Fig. 8) with the rules that left observations out, as a
    # figure in the report; its counts are those of the maps' valid_images channel
    assert summary["figures"]["valid_images"] == "figures/valid_images.png"
    assert (tmp_path / "run" / "fit" / "figures" / "valid_images.png").is_file() and 'alt="valid images"' in html
    from rjfit.render.datasets import load_dataset

    counts = load_dataset(tmp_path / "run" / "dataset").exclusion_counts(summary["channel"])
    np.testing.assert_array_equal(counts["valid"], maps["valid_images"])
    comparison = json.loads((tmp_path / "run" / "fit" / "comparison" / "comparison.json").read_text())
    diagnosis = json.loads((tmp_path / "run" / "fit" / "diagnosis" / "diagnosis.json").read_text())
    assert comparison["fit_id"] == diagnosis["fit_id"] == summary["fit_id"]
    assert diagnosis["channel"] == summary["channel"] == "mean"

    # diagnose refuses data other than those fitted (the summary records their fingerprint)
    result = CliRunner().invoke(main, ["diagnose", str(tmp_path / "run" / "fit"), "--dataset", str(paper_sphere_small),
                                       "--out", str(tmp_path / "other_diagnosis")])
    assert result.exit_code == 1 and "not the data this fit was made from" in result.output

    # a new fit into the same folder: the old comparison no longer describes it, and the
    # report says so instead of showing it as this fit's
    fit_dir = tmp_path / "run" / "fit"
    result = CliRunner().invoke(main, ["fit", str(tmp_path / "run" / "dataset"), "--out", str(fit_dir),
                                       "--iterations", "20", "--chains", "1", "--seed", "5"])
    assert result.exit_code == 0, result.output
    assert not (fit_dir / "report.html").exists()
    result = CliRunner().invoke(main, ["report", str(fit_dir)])
    assert result.exit_code == 0, result.output
    html = (fit_dir / "report.html").read_text()
    assert "The comparison in" in html and "The diagnosis in" in html and "<th>method</th>" not in html
    assert html.count("was made from another fit") == 2


def test_a_fit_killed_by_sigkill_resumes_to_the_uninterrupted_results(paper_sphere_small, tmp_path):
    """`rjfit fit` killed (SIGKILL, the whole process group) once a checkpoint exists, then run
    again with the same command, ends with the summary of a run never interrupted. The kill
    lands at the first checkpoint (iteration 25 of 200, inside the burn-in), so the resumed run
    crosses the burn-in's end and the whole sampling phase."""
    import os
    import shutil
    import signal
    import time

    dataset = tmp_path / "dataset"
    shutil.copytree(paper_sphere_small, dataset)
    assert CliRunner().invoke(main, ["validate", str(dataset)]).exit_code == 0

    def command(out):
        return [sys.executable, "-m", "rjfit", "fit", str(dataset), "--out", str(out), "--chains", "2",
                "--iterations", "200", "--checkpoint-every", "25", "--seed", "4"]

    subprocess.run(command(tmp_path / "whole"), check=True, capture_output=True)
    killed = subprocess.Popen(command(tmp_path / "killed"), start_new_session=True, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    checkpoint = tmp_path / "killed" / "checkpoints" / "chain_0.pkl"
    deadline = time.monotonic() + 300
    while not checkpoint.exists() and killed.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    os.killpg(killed.pid, signal.SIGKILL)
    killed.wait()
    assert checkpoint.exists() and not (tmp_path / "killed" / "summary.json").exists(), "not killed mid-run"
    rerun = subprocess.run(command(tmp_path / "killed"), check=True, capture_output=True, text=True)
    assert "chain 0: resumed from its checkpoint at iteration" in rerun.stderr, "restarted instead of resuming"
    whole, resumed = (json.loads((tmp_path / name / "summary.json").read_text()) for name in ("whole", "killed"))
    assert whole["chain_resumed_from"][0] == [] and len(resumed["chain_resumed_from"][0]) == 1, "not recorded as resumed"
    timings = {"seconds", "chain_seconds", "chain_resumed_from"}
    assert {key: value for key, value in resumed.items() if key not in timings} == \
        {key: value for key, value in whole.items() if key not in timings}


def test_a_fit_whose_main_process_alone_is_killed_leaves_no_chain_worker_running(paper_sphere_small, tmp_path):
    """SIGKILL to `rjfit fit`'s main process only (not its group; what a job scheduler or `kill -9 PID`
    does): its chain workers end within seconds instead of running their chains on, orphaned, and
    writing the checkpoints a resumed fit writes too. Before the fix they ran to the chain's end."""
    import os
    import signal
    import time

    from rjfit.sampler.runner import PARENT_CHECK_SECONDS

    fit = subprocess.Popen([sys.executable, "-m", "rjfit", "fit", str(paper_sphere_small), "--out",
                            str(tmp_path / "fit"), "--chains", "2", "--iterations", "100000", "--checkpoint-every",
                            "25", "--allow-unvalidated"], start_new_session=True, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)
    checkpoint = tmp_path / "fit" / "checkpoints" / "chain_0.pkl"
    deadline = time.monotonic() + 300
    while not checkpoint.exists() and fit.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert checkpoint.exists(), "the workers never wrote a checkpoint"
    os.kill(fit.pid, signal.SIGKILL)
    fit.wait()
    deadline = time.monotonic() + 10 * PARENT_CHECK_SECONDS + 5
    while time.monotonic() < deadline:
        try:
            os.killpg(fit.pid, 0)           # the session's group: the workers, while any is alive
        except ProcessLookupError:
            return
        time.sleep(0.1)
    os.killpg(fit.pid, signal.SIGKILL)      # clean up before failing
    raise AssertionError("chain workers still ran 15 s after their fit's main process was killed")


def test_fit_each_channel_fits_r_g_and_b_into_their_own_folders(paper_sphere_small, tmp_path):
    """--channel each: one fit per colour channel, each of its own channel's values."""
    import math
    import shutil

    from rjfit.data.exr import read_exr, write_exr

    dataset = tmp_path / "tinted"
    shutil.copytree(paper_sphere_small, dataset)
    scale = {"R": 1.0, "G": 0.5, "B": 0.25}          # a tinted material: G and B reflect less than R
    for image in sorted((dataset / "images").glob("*.exr")):
        channels = read_exr(image)
        write_exr(image, {name: values * scale[name] for name, values in channels.items()})
    result = CliRunner().invoke(main, ["fit", str(dataset), "--out", str(tmp_path / "fit"), "--channel", "each",
                                       "--chains", "1", "--iterations", "20", "--allow-unvalidated"])
    assert result.exit_code == 0, result.output
    summaries = {name: json.loads((tmp_path / "fit" / name / "summary.json").read_text()) for name in scale}
    for name, summary in summaries.items():
        assert summary["channel"] == name
        assert f"({name}) -> {tmp_path / 'fit' / name}" in result.output
    # the default prior centres I0 on the median of y / (E <l.n> / pi): it scales with the channel's values
    centre = {name: summary["prior"]["I0"]["a"] for name, summary in summaries.items()}
    assert abs(centre["G"] - centre["R"] - math.log(0.5)) < 1e-6
    assert abs(centre["B"] - centre["R"] - math.log(0.25)) < 1e-6
    assert not (tmp_path / "fit" / "summary.json").exists()


def test_arviz_s_refactor_notice_never_reaches_the_output(tmp_path):
    """ArviZ 0.x prints a FutureWarning about its 1.0 refactor once a day (a stamp in the user's
    cache): with a fresh cache, importing every rjfit module and computing the diagnostics and the
    InferenceData (every use of ArviZ in a fit) prints nothing of it."""
    script = ("import importlib, pkgutil, numpy as np, rjfit\n"
              "for module in pkgutil.walk_packages(rjfit.__path__, 'rjfit.'):\n"
              "    if not module.name.endswith('__main__'):\n"
              "        importlib.import_module(module.name)\n"
              "from rjfit.posterior.summary import diagnostics\n"
              "print(diagnostics([np.random.default_rng(0).normal(size=(50, 1, 4)) for _ in range(2)])['rhat_max'])\n")
    import os

    environment = {**os.environ, "XDG_CACHE_HOME": str(tmp_path)}
    result = subprocess.run([sys.executable, "-W", "default", "-c", script], capture_output=True, text=True,
                            env=environment, check=False)
    assert result.returncode == 0, result.stderr
    assert "major refactor" not in result.stderr and "FutureWarning" not in result.stderr, result.stderr


def test_validate_says_how_many_observations_are_over_the_tolerance(dented_plaster_small, tmp_path):
    """The largest error alone hides how many observations differ: a line gives the count (here interreflection
    in the dents, so the gate fails and the count is over 1 %)."""
    result = CliRunner().invoke(main, ["validate", str(dented_plaster_small), "--out", str(tmp_path / "v"),
                                       "--spp", "4"])
    assert result.exit_code == 1 and "FAILED" in result.output
    written = json.loads((tmp_path / "v" / "validation.json").read_text())
    assert written["observations_over_p99_tolerance"] > 0.01 * written["observations_compared"]
    assert (f"note: {written['observations_over_p99_tolerance']} of {written['observations_compared']} "
            f"observations") in result.output
