"""The ``rjfit`` command line: render | validate | fit | diagnose | refine | compare | report | run."""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import click

__all__ = ["main"]

# every --seed: a non-negative integer (NumPy's SeedSequence and rjfit.render.mitsuba_scene.mitsuba_seed
# take any size; a negative one is refused here, naming the option)
SEED = click.IntRange(min=0)


def _echo_json(payload: dict, keys) -> None:
    for key in keys:
        if key in payload:
            value = payload[key]
            click.echo(f"  {key:<24} {value:.4g}" if isinstance(value, float) else f"  {key:<24} {value}")


def _likelihood_power(text: str | None):
    if text is None or text in ("auto", "area"):        # None: not given (the default, or the preset's)
        return text
    try:
        value = float(text)
    except ValueError:
        raise click.BadParameter(f"{text!r} is neither 'auto', 'area' nor a number",
                                 param_hint="--likelihood-power") from None
    if not 0.0 < value <= 1.0:
        raise click.BadParameter(f"{value} is not in (0, 1]", param_hint="--likelihood-power")
    return value


def _check_output(folder) -> None:
    """Refuse an output folder that cannot be written before any work (:func:`rjfit.io.check_writable`,
    imported here so that ``--help`` does not load NumPy)."""
    from rjfit.io import check_writable

    check_writable(folder)


class _Group(click.Group):
    """Turns the errors rjfit raises for bad input, and every ``OSError`` (an output that
    cannot be written, a file that cannot be read), into one clear line naming the path (no
    traceback; exit status 1); set RJFIT_DEBUG=1 to see the traceback."""

    def invoke(self, ctx):
        import os

        from rjfit.errors import DatasetError
        from rjfit.io import os_error_text
        from rjfit.render.gate import ValidationRequiredError

        try:
            return super().invoke(ctx)
        except (ValidationRequiredError, DatasetError, ValueError) as error:
            if os.environ.get("RJFIT_DEBUG"):
                raise
            raise click.ClickException(str(error)) from error
        except OSError as error:        # no permission, not a folder, a full disk: the path and why
            if os.environ.get("RJFIT_DEBUG"):
                raise
            raise click.ClickException(os_error_text(error)) from error


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="rjfit")
def main():
    """Segment a surface into regions of equal reflectance and sample each region's BRDF
    posterior (Lenoch, Wilhelm and Woehler, VISAPP 2016), with a forward model checked
    against Mitsuba.

    Data flows one way: render -> validate -> fit -> diagnose / refine / compare -> report.
    """


def _echo_cuda_fallback(variant_ran: str) -> None:
    """With RJFIT_DEBUG set, say why ``--variant auto`` did not take cuda_ad_rgb. Quiet
    otherwise: without a GPU that is the normal case, and with one resolve_variant warns."""
    import os

    from rjfit.render import mitsuba_scene

    reason = mitsuba_scene.CUDA_FALLBACK_REASON
    if os.environ.get("RJFIT_DEBUG") and reason and not variant_ran.startswith("cuda"):
        click.echo(f"  cuda_ad_rgb not used ({variant_ran} instead): {reason}", err=True)


@main.command()
@click.argument("scene")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Data set folder to write (replaced if it is a data set; any other non-empty folder is refused).")
@click.option("--resolution", type=click.IntRange(min=1), default=None,
              help="Square image size in pixels (default: the scene's).")
@click.option("--seed", type=SEED, default=None, help="Seed of path tracing and noise (default: the scene's).")
@click.option("--spp", type=click.IntRange(min=1), default=None,
              help="Samples per pixel, all along the pixel-centre ray (default: the scene's, 1 if it sets none).")
@click.option("--noise-variance", type=float, default=None, help="Gaussian noise variance (default: the scene's).")
@click.option("--variant", default="auto", show_default=True,
              help="Mitsuba variant; auto: cuda_ad_rgb when a GPU answers, else llvm_ad_rgb.")
def render(scene, out_dir, resolution, seed, spp, noise_variance, variant):
    """Render SCENE (a built-in name such as paper_sphere, or a scene JSON file) into a
    data set: one linear EXR per light, geometry, visibility, truth and dataset.json."""
    _check_output(out_dir.resolve().parent)       # the data set is staged beside it, then renamed
    from rjfit.render.render import render_dataset

    _echo_render(render_dataset(scene, out_dir, resolution=resolution, seed=seed, spp=spp,
                                noise_variance=noise_variance, variant=variant, progress=True))


def _echo_render(path: Path) -> None:
    meta = json.loads((path / "dataset.json").read_text())
    click.echo(f"wrote {path} ({meta['variant']}): {len(meta['images'])} images, {meta['resolution'][1]} x "
               f"{meta['resolution'][0]}, {meta['render_seconds']:.1f} s")
    _echo_cuda_fallback(meta["variant"])


@main.command()
@click.argument("dataset", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Where validation.json and the maps go (default: DATASET/validation).")
@click.option("--spp", type=click.IntRange(min=1), default=4, show_default=True, help="Path-traced samples per pixel.")
@click.option("--max-depth", type=click.IntRange(min=1), default=8, show_default=True,
              help="Path length of the path tracer.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the path tracer's samples.")
@click.option("--variant", default="auto", show_default=True,
              help="Mitsuba variant; auto: cuda_ad_rgb when a GPU answers, else llvm_ad_rgb.")
def validate(dataset, out_dir, spp, max_depth, seed, variant):
    """Cross-check the closed form against Mitsuba's path tracer on DATASET.

    Exits with status 1 when the gate fails (median rel. error > 1e-4 or p99 > 1e-3)."""
    _check_output(out_dir or dataset / "validation")
    from rjfit.render.gate import outlier_note, validate_dataset

    result = validate_dataset(dataset, out_dir, spp=spp, max_depth=max_depth, seed=seed, variant=variant,
                              progress=True)
    click.echo(f"validation of {dataset} ({result['settings']['variant']}): {'PASSED' if result['passed'] else 'FAILED'}")
    _echo_cuda_fallback(result["settings"]["variant"])
    _echo_json(result, ["median_rel_err", "p99_rel_err", "max_rel_err", "pixels_compared", "unexplained_fraction",
                        "max_normal_angle_deg", "max_view_angle_deg", "seconds"])
    if outlier_note(result):
        click.echo(f"  note: {outlier_note(result)}")
    out = Path(out_dir) if out_dir else Path(dataset) / "validation"
    click.echo(f"  report: {out / 'validation.json'}")
    if not result["passed"]:
        sys.exit(1)


@main.command()
@click.argument("scene", default="paper_sphere")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Run folder (default: runs/SCENE).")
@click.option("--resolution", type=click.IntRange(min=1), default=None, help="Square image size (default: the scene's).")
@click.option("--iterations", type=click.IntRange(min=10), default=4000, show_default=True, help="Iterations per chain.")
@click.option("--chains", "n_chains", type=click.IntRange(min=1), default=4, show_default=True,
              help="Chains from dispersed starts (run in parallel processes).")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of validation, fit, baselines and diagnosis.")
@click.option("--allow-unvalidated", is_flag=True,
              help="Go on to fit, compare and diagnose when the cross-check fails (the criticism workflow on data "
                   "with a hidden effect); the fit's warnings then say so.")
def run(scene, out_dir, resolution, iterations, n_chains, seed, allow_unvalidated):
    """The main job, end to end on SCENE (default: the paper's synthetic sphere):
    render -> validate -> fit -> compare -> diagnose and refine -> report.

    Stops with status 1 after a failed cross-check, unless --allow-unvalidated."""
    out_dir = out_dir or Path("runs") / Path(scene).stem
    _check_output(out_dir)
    from rjfit.pipeline.run import run as run_main_job

    echo = {"render": _echo_render,
            "validate": lambda result: click.echo(
                f"  {'PASSED' if result['passed'] else 'FAILED'}: median rel. err. {result['median_rel_err']:.3g}, "
                f"p99 {result['p99_rel_err']:.3g}, unexplained fraction {result['unexplained_fraction']:.3g}"),
            "fit": lambda summary: _echo_fit(out_dir / "fit", summary),
            "compare": lambda rows: _echo_comparison(rows, out_dir / "fit" / "comparison", out_dir / "fit"),
            "refine": lambda result: click.echo(
                f"  named effects: {', '.join(result['named_effects']) or 'none'}; {result['stopped']}; final fit "
                f"{result['final_fit']}"),
            "report": lambda path: None}
    results = run_main_job(scene, out_dir, resolution=resolution, iterations=iterations, n_chains=n_chains, seed=seed,
                           allow_unvalidated=allow_unvalidated, announce=click.echo,
                           done=lambda step, result: echo[step](result))
    click.echo(f"done in {results['seconds']:.0f} s. Open the report: {results['report'].resolve()}")


@main.command()
@click.argument("dataset", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder for comparison.json, comparison.md and segmentations.png (created).")
@click.option("--fit", "fit_dir", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="A folder written by `rjfit fit` of DATASET (summary.json, labels.exr): score rjfit's MAP "
                   "segmentation too. Without it rjfit's row is left out.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of every baseline's randomness.")
@click.option("--channel", default="mean", show_default=True,
              type=click.Choice(["mean", "R", "G", "B", "luminance"]), help="Colour channel of the grey values.")
def compare(dataset, out_dir, fit_dir, seed, channel):
    """Compare segmentations of DATASET (which needs ground truth) side by side: k-means
    (k = 4..8), a multichannel k-means, a Gaussian mixture with pixel positions (k = 4..8),
    normalized cuts on one image (k = 5..6, background included) and, with --fit, rjfit's
    MAP segmentation. Scores pixel accuracy, adjusted Rand index and boundary F1 (2 px)
    after Hungarian matching, and the runtime of each method."""
    _check_output(out_dir)
    from rjfit.pipeline.compare import compare_dataset

    click.echo(f"comparing segmentations of {dataset}")
    _echo_comparison(compare_dataset(dataset, out_dir, fit_dir=fit_dir, seed=seed, channel=channel,
                                     progress=click.echo), out_dir, fit_dir)


def _echo_comparison(rows, out_dir, fit_dir) -> None:
    click.echo("best k per method (by pixel accuracy):")
    click.echo(f"  {'method':<22} {'k':>2} {'acc':>6} {'ARI':>6} {'bF1':>6} {'seconds':>8}")
    best = {}
    for row in rows:
        if row["method"] not in best or row["pixel_accuracy"] > best[row["method"]]["pixel_accuracy"]:
            best[row["method"]] = row
    for row in best.values():
        seconds = "n/a" if row["seconds"] is None else f"{row['seconds']:.2f}"
        click.echo(f"  {row['method']:<22} {row['k']:>2} {row['pixel_accuracy']:6.3f} {row['ari']:6.3f} "
                   f"{row['boundary_f1']:6.3f} {seconds:>8}")
    if fit_dir is None:
        click.echo("  (rjfit MAP left out: no --fit FIT_DIR)")
    click.echo(f"  table: {Path(out_dir) / 'comparison.md'}  figure: {Path(out_dir) / 'segmentations.png'}")


def _click_option(name, default, spec):
    """The click option of one :class:`rjfit.pipeline.options.FitOptions` field."""
    if spec.kind == "flag":
        return click.option(spec.flag, name, is_flag=True, help=spec.help)
    types = {"int": click.IntRange(min=spec.low) if spec.low is not None else int, "float": float,
             "choice": click.Choice(spec.choices), "text": str,
             "power": click.STRING, "path": click.Path(dir_okay=False, path_type=Path),
             "dir": click.Path(file_okay=False, path_type=Path)}
    if spec.kind == "text" and isinstance(default, tuple):      # a list option's default, as it is typed
        default = ",".join(default)
    return click.option(spec.flag, name, type=types[spec.kind], default=default, help=spec.help,
                        show_default=spec.show_default and default is not None)


def _given(ctx, options: dict) -> dict:
    """The options given on the command line (or by an environment variable): one left at its default is
    not given, so that the data's kind, the preset or the plain default fills it (rjfit.pipeline.resolve)."""
    from click.core import ParameterSource

    return {name: value for name, value in options.items()
            if ctx.get_parameter_source(name) not in (ParameterSource.DEFAULT, None)}


def fit_options(command):
    """Add every command-line option of :class:`rjfit.pipeline.options.FitOptions` to ``command``."""
    from rjfit.pipeline.options import FitOptions

    for name, default, spec in reversed(FitOptions.cli_fields()):
        command = _click_option(name, default, spec)(command)
    return command


@main.command()
@click.argument("datasets", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Fit folder; with several data sets, one sub-folder per data set.")
@fit_options
@click.option("--validation", "validation_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="validation.json of the data set (default: DATASET/validation/validation.json).")
@click.option("--allow-unvalidated", is_flag=True,
              help="Fit even if the forward model has not passed the cross-check gate (not recommended).")
@click.option("--scheduler", default=None,
              help="Run chains on Dask: 'local' for a local cluster, or a scheduler address (tcp://host:8786).")
@click.option("--workers", type=int, default=2, show_default=True, help="Workers of a local Dask cluster.")
def fit(datasets, out_dir, validation_path, allow_unvalidated, scheduler, workers, **options):
    """Segment DATASET(S) and sample the region BRDF posteriors (RJMCMC).

    Refuses a data set whose forward model has not passed `rjfit validate` unless
    --allow-unvalidated is given. Writes summary.json, labels.exr (MAP labels), maps.exr,
    chains.nc, changepoints.npz and the paper's figures; an interrupted fit leaves the
    folder's previous results untouched and resumes from its checkpoints."""
    options["likelihood_power"] = _likelihood_power(options["likelihood_power"])
    _check_output(out_dir)
    from rjfit.pipeline.fit_dataset import fit_datasets
    from rjfit.pipeline.options import FitOptions

    options = _given(click.get_current_context(), options)
    if "likelihood_power" in options:
        options["likelihood_power"] = _likelihood_power(options["likelihood_power"])
    summaries = fit_datasets(datasets, out_dir, FitOptions(**options), validation_path=validation_path,
                             allow_unvalidated=allow_unvalidated, scheduler=scheduler, n_workers=workers)
    for folder, summary in summaries:
        _echo_fit(folder, summary)


def _finite(value) -> bool:
    return isinstance(value, (int, float)) and math.isfinite(value)


def _rhat_text(summary: dict) -> str:
    """``R-hat max 1.0042``, or ``R-hat: not computable (why)`` where the summary has none (NaN or null)."""
    if _finite(summary.get("rhat_max")):
        return f"R-hat max {summary['rhat_max']:.4f}"
    return f"R-hat: not computable ({summary.get('rhat_reason') or 'no reason recorded'})"


def _ess_text(summary: dict) -> str:
    return f"ESS min {summary['ess_min']:.0f}" if _finite(summary.get("ess_min")) else "ESS: not computable"


def _normal_error_text(normal_error: dict) -> str:
    """``normal error sd 0.42 deg, footprint c 0.52``; an estimate at its bound 0 says what that means."""
    text = f"normal error sd {normal_error['sigma_n_deg']:.3g} deg"
    if normal_error.get("k") == 0.0:        # the maximum-likelihood k at its bound: constant noise in effect
        text += " (at its bound 0: no excess variance along the shading gradient, so the noise is constant here)"
    return text + (f", footprint c {normal_error['c']:.3g}" if "c" in normal_error else "")


def _echo_fit(folder, summary: dict) -> None:
    """A fit's one-paragraph summary: model, regions, convergence, time, warnings."""
    click.echo(f"fit of {summary['dataset']} ({summary['channel']}) -> {folder}")
    for line in summary.get("data_defaults", []):
        click.echo(f"  {line}")
    response = (summary.get("calibration") or {}).get("response")
    if response:
        interval = response.get("kappa_interval")
        spread = f" (95 % {interval[0]:.3g} to {interval[1]:.3g})" if interval else ""
        click.echo(f"  camera response estimated: raw = k linear^(1/kappa), kappa {response['kappa']:.3g}{spread}; "
                   f"the images were linearised with it before the fit")
    from rjfit.data.light_field import field_extent

    calibration = summary.get("calibration") or {}
    field, common = (calibration.get("light_gains") or {}).get("field"), calibration.get("common_field")
    if field:
        low, high = field_extent(field)
        click.echo(f"  light field: each light's gain a degree-{field['degree']} field over the image, {low:.2f} to "
                   f"{high:.2f} of its mean over the object"
                   + (f", and the lights' common field {field_extent(common)[0]:.2f} to {field_extent(common)[1]:.2f} (read "
                      f"from the albedo of {100 * common['inlier_share']:.0f} % of the pixels, as one material's)"
                      if common else "") + "; divided out before the fit (--light-field)")
    noise_model = summary.get("noise", {}).get("model", "constant")
    if noise_model != "constant" or summary["likelihood_power"] != 1.0:
        normal_error = summary["noise"].get("normal_error")
        noise_text = ("" if noise_model == "constant" else
                      f"noise model {noise_model} ({_normal_error_text(normal_error)}), " if normal_error
                      else f"noise model {noise_model} (floor {summary['noise']['floor']:g} x mean), ")
        click.echo(f"  {noise_text}likelihood power (zeta) {summary['likelihood_power']:.4g}")
    if summary.get("rim_pixels"):
        click.echo(f"  the rim: {summary['rim_pixels']} object pixels seen more than {summary['max_view_angle']:g} "
                   f"deg from their normal gave no observation; their labels follow their neighbours' "
                   f"(--max-view-angle)")
    from rjfit.pipeline.regions import printed_line, printed_notes

    model = printed_line(summary)
    click.echo(f"  {model}; {_rhat_text(summary)}, {_ess_text(summary)}; "
               f"{summary['seconds']:.1f} s")
    for note in printed_notes(summary):
        click.echo(f"  {note}")
    if "label_accuracy" in summary:
        click.echo(f"  label accuracy {summary['label_accuracy']:.4f}")
    if summary.get("edge_power"):
        gain = summary.get("edge_gain_sd") or 0.0
        local = f", local gain sd {gain:.3g} integrated out of each pair (--edge-gain-sd)" if gain > 0 else ""
        if summary.get("edge_noise"):
            local += ", each pair on its own measured noise (--edge-noise)"
        click.echo(f"  edge term in the target (power {summary['edge_power']:.3g}{local}): a boundary earns where the "
                   f"data step as its materials do and costs where they do not (--edge-power)")
    if summary.get("edge_groups_posterior"):
        shares = ", ".join(f"{n}: {share:.2f}" for n, share in summary["edge_groups_posterior"].items())
        click.echo(f"  edge-supported material groups (materials that meet where the data show no step joined, "
                   f"{summary['edge_groups_snapshots']} snapshots): {shares}")
    for effect in summary.get("effects", []):
        values = ", ".join(f"{p['name']} {p['mean']:.4g} (95 % {p['q2.5']:.4g} to {p['q97.5']:.4g})"
                           for p in effect["parameters"])
        click.echo(f"  effect {effect['name']}: {values}")
    for warning in summary.get("warnings", []):
        click.echo(f"  WARNING: {warning}", err=True)


@main.command()
@click.argument("fit_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", "out_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="HTML file to write (default: FIT_DIR/report.html).")
@click.option("--diagnosis", "diagnosis_dir", type=click.Path(exists=True, file_okay=False, path_type=Path),
              default=None, help="Folder `rjfit diagnose --out` wrote (default: FIT_DIR/diagnosis).")
@click.option("--comparison", "comparison_dir", type=click.Path(exists=True, file_okay=False, path_type=Path),
              default=None, help="Folder `rjfit compare --out` wrote (default: FIT_DIR/comparison).")
def report(fit_dir, out_path, diagnosis_dir, comparison_dir):
    """Build one self-contained HTML report of a fit: figures, the paper's parameter table,
    validation, diagnosis and comparison results where present (those made from another
    fit are flagged as stale, not shown)."""
    _check_output((out_path or fit_dir / "report.html").parent)
    from rjfit.pipeline.report import build_report

    click.echo(f"report: {build_report(fit_dir, out_path, diagnosis_dir=diagnosis_dir, comparison_dir=comparison_dir)}")


def _effects_help():
    from rjfit.effects import effects_help

    return effects_help()


@main.command("diagnose")
@click.argument("fit_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", "out_dir", default=None, type=click.Path(file_okay=False, path_type=Path),
              help="Folder for diagnosis.json, diagnosis.md and the figures (default: FIT_DIR/diagnosis, where "
                   "`rjfit report` looks).")
@click.option("--max-steps", type=click.IntRange(min=0), default=3, show_default=True,
              help="Most effects to add; 0 measures the plain model's gap and tries no candidate.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True, help="Seed of the refits and the simulations.")
@click.option("--effects", default=None,
              help="Comma-separated candidate effects (default: all). " + _effects_help())
@click.option("--dataset", "dataset_dir", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="The fitted data set, if it has moved since the fit (default: the one summary.json names).")
@click.option("--no-simulate", is_flag=True, help="Skip the Mitsuba posterior predictive rendering.")
@click.option("--likelihood-power", type=click.FloatRange(min=0.0, max=1.0, min_open=True), default=None,
              help="The power zeta the refits raise the likelihood to, so that Bayes factors weigh the data as a "
                   "coarsened fit did (default: the fit's, 1 for a plain fit).")
@click.option("--noise", type=click.Choice(["constant", "shot", "relative", "normals"]), default=None,
              help="The noise model the refits weigh the observations by (see `rjfit fit --help`; default: the "
                   "fit's, with its --noise-floor).")
@click.option("--jobs", type=click.IntRange(min=1), default=None,
              help="Candidate effects refitted at once, on threads (default: the cores available). The result does "
                   "not depend on it; memory grows with it (each refit in flight holds arrays the size of the "
                   "observations).")
def diagnose(fit_dir, out_dir, max_steps, seed, effects, dataset_dir, no_simulate, likelihood_power, noise,
                     jobs):
    """Criticise a fit: find where simulation and data disagree, name the missing effect
    (only when the evidence is decisive), add it, refit and show the gap shrink."""
    out_dir = out_dir or fit_dir / "diagnosis"
    _check_output(out_dir)
    from rjfit.effects import ALL_EFFECTS
    from rjfit.pipeline.diagnose import diagnose_fit

    candidates = ALL_EFFECTS if not effects else [name.strip() for name in effects.split(",") if name.strip()]
    options = {} if likelihood_power is None else {"likelihood_power": likelihood_power}
    if noise is not None:
        options["noise"] = noise
    result = diagnose_fit(fit_dir, out_dir, dataset=dataset_dir, candidates=candidates, seed=seed, max_steps=max_steps,
                          simulate=False if no_simulate else None, progress=True, jobs=jobs, **options)
    _echo_diagnosis(result, out_dir)


@main.command("refine")
@click.argument("fit_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder for each round's fit and diagnosis (round<k>/), refine.json and segmentations.png.")
@click.option("--max-rounds", type=click.IntRange(min=1), default=6, show_default=True,
              help="Most diagnoses (the first fit's and those of the refits, trials included); a warning says when "
                   "the cap binds, and a run into the same --out with a larger cap goes on from there.")
@click.option("--max-steps", type=click.IntRange(min=0), default=3, show_default=True,
              help="Most effects each diagnosis names.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seed of the diagnoses' refits and simulations (the refits of the fit use the fit's own seed).")
@click.option("--no-simulate", is_flag=True, help="Skip the Mitsuba posterior predictive rendering of each diagnosis.")
def refine(fit_dir, out_dir, max_rounds, max_steps, seed, no_simulate):
    """Close the loop: diagnose FIT_DIR, fit its data set again with the named effects sampled
    jointly with the segmentation (the fit's own options plus --effects-from), diagnose that
    fit, and repeat until nothing more is named and a feature rendered from the fitted regions
    (interreflection's) was rendered on labels the fit keeps (agreeing on 99 % of the pixels).
    Where a diagnosis names nothing but offers a trial (an effect or pair short of the naming
    rule's gap share only; after those, one whose evidence is decisive but whose LOO gain is
    only positive where PSIS is reliable), fit once more with it and keep it only if the gap halves with no
    more regions; a trial offered on a gap within the naming floor (0.1), or the model less an
    effect a kept pair brought in, is kept only if its fit has fewer regions and a gap still
    within it. Run again into the same --out, it keeps each diagnosis and fit an earlier
    run finished for the same fit and options."""
    _check_output(out_dir)
    from rjfit.pipeline.refine import refine as refine_fit

    result = refine_fit(fit_dir, out_dir, max_rounds=max_rounds, max_steps=max_steps, seed=seed,
                        simulate=False if no_simulate else None, progress=True, say=click.echo)
    click.echo(f"named effects: {', '.join(result['named_effects']) or 'none'}; {result['stopped']}")
    click.echo(f"final fit: {result['final_fit']}  rounds: {Path(out_dir) / 'refine.json'}  "
               f"segmentations: {Path(out_dir) / result['segmentations']}")


def _echo_diagnosis(result: dict, out_dir) -> None:
    from rjfit.diagnose.document import gap_text, named_text

    click.echo(f"named effects: {named_text(result)}")
    if result["named_effects"] and result["search"]["stopped"].startswith("stopped after"):
        click.echo(f"  {result['search']['stopped']} (raise --max-steps to search on)")
    click.echo(f"gap: plain {gap_text(result['gap_plain'])} -> final {gap_text(result['gap_final'])}")
    click.echo(f"report: {Path(out_dir) / 'diagnosis.md'}")


if __name__ == "__main__":
    main()
