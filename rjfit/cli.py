"""The ``rjfit`` command line: render | validate | fit | diagnose | compare | report | run."""
from __future__ import annotations

import json
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


def _likelihood_power(text: str):
    if text == "auto":
        return "auto"
    try:
        value = float(text)
    except ValueError:
        raise click.BadParameter(f"{text!r} is neither 'auto' nor a number", param_hint="--likelihood-power") from None
    if not 0.0 < value <= 1.0:
        raise click.BadParameter(f"{value} is not in (0, 1]", param_hint="--likelihood-power")
    return value


class _Group(click.Group):
    """Turns the errors rjfit raises for bad input into one clear line (no traceback);
    set RJFIT_DEBUG=1 to see the traceback."""

    def invoke(self, ctx):
        import os

        from rjfit.errors import DatasetError
        from rjfit.render.gate import ValidationRequiredError

        try:
            return super().invoke(ctx)
        except (ValidationRequiredError, DatasetError, FileNotFoundError, ValueError) as error:
            if os.environ.get("RJFIT_DEBUG"):
                raise
            raise click.ClickException(str(error)) from error


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="rjfit")
def main():
    """Segment a surface into regions of equal reflectance and sample each region's BRDF
    posterior (Lenoch, Wilhelm and Woehler, VISAPP 2016), with a forward model checked
    against Mitsuba.

    Data flows one way: render -> validate -> fit -> diagnose / compare -> report.
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
    from rjfit.render.render import render_dataset

    path = render_dataset(scene, out_dir, resolution=resolution, seed=seed, spp=spp, noise_variance=noise_variance,
                          variant=variant, progress=True)
    meta = json.loads((path / "dataset.json").read_text())
    click.echo(f"wrote {path} ({meta['variant']}): {len(meta['images'])} images, {meta['resolution'][1]} x {meta['resolution'][0]}, "
               f"{meta['render_seconds']:.1f} s")
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
    from rjfit.render.gate import validate_dataset

    result = validate_dataset(dataset, out_dir, spp=spp, max_depth=max_depth, seed=seed, variant=variant,
                              progress=True)
    click.echo(f"validation of {dataset} ({result['settings']['variant']}): {'PASSED' if result['passed'] else 'FAILED'}")
    _echo_cuda_fallback(result["settings"]["variant"])
    _echo_json(result, ["median_rel_err", "p99_rel_err", "max_rel_err", "pixels_compared", "unexplained_fraction",
                        "max_normal_angle_deg", "max_view_angle_deg", "seconds"])
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
@click.pass_context
def run(ctx, scene, out_dir, resolution, iterations, n_chains, seed, allow_unvalidated):
    """The main job, end to end on SCENE (default: the paper's synthetic sphere):
    render -> validate -> fit -> compare -> diagnose -> report.

    Stops with status 1 after a failed cross-check, unless --allow-unvalidated."""
    import time

    started = time.perf_counter()
    name = Path(scene).stem
    out_dir = out_dir or Path("runs") / name
    dataset_dir, fit_dir = out_dir / "dataset", out_dir / "fit"
    click.echo(f"== 1/6 render {scene}")
    ctx.invoke(render, scene=scene, out_dir=dataset_dir, resolution=resolution, seed=None, spp=None,
               noise_variance=None, variant="auto")
    click.echo("== 2/6 validate (closed form vs Mitsuba path tracer)")
    from rjfit.render.gate import validate_dataset

    validation = validate_dataset(dataset_dir, spp=4, seed=seed, progress=True)
    click.echo(f"  {'PASSED' if validation['passed'] else 'FAILED'}: median rel. err. {validation['median_rel_err']:.3g}, "
               f"p99 {validation['p99_rel_err']:.3g}, unexplained fraction {validation['unexplained_fraction']:.3g}")
    if not validation["passed"] and not allow_unvalidated:
        raise click.ClickException(
            f"the closed-form model does not match Mitsuba on {dataset_dir} (see {dataset_dir / 'validation'}), so a "
            f"fit would not be trustworthy; stopped. Pass --allow-unvalidated to fit and diagnose it anyway.")
    click.echo("== 3/6 fit (RJMCMC)")
    ctx.invoke(fit, datasets=(dataset_dir,), out_dir=fit_dir, n_chains=n_chains, iterations=iterations, burn_in=None,
               max_u=3, max_v=3, sampler="adaptive", prior="default", split_map="conditional", cp_prior="smooth",
               drop_jacobian=False, channel="mean", seed=seed,
               validation_path=None, allow_unvalidated=allow_unvalidated, scheduler=None, workers=2)
    truth = (dataset_dir / "truth_labels.exr").is_file()
    if truth:
        click.echo("== 4/6 compare with baselines")
        ctx.invoke(compare, dataset=dataset_dir, out_dir=fit_dir / "comparison", fit_dir=fit_dir, seed=seed,
                   channel="mean")
    click.echo("== 5/6 diagnose (model criticism)")
    ctx.invoke(diagnose, fit_dir=fit_dir, out_dir=fit_dir / "diagnosis")
    click.echo("== 6/6 report")
    from rjfit.pipeline.report import build_report

    report_path = build_report(fit_dir)
    click.echo(f"done in {time.perf_counter() - started:.0f} s. Open the report: {report_path.resolve()}")


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
    from rjfit.pipeline.compare import compare_dataset

    click.echo(f"comparing segmentations of {dataset}")
    rows = compare_dataset(dataset, out_dir, fit_dir=fit_dir, seed=seed, channel=channel, progress=click.echo)
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


@main.command()
@click.argument("datasets", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Fit folder; with several data sets, one sub-folder per data set.")
@click.option("--chains", "n_chains", type=click.IntRange(min=1), default=4, show_default=True,
              help="Chains from dispersed starts.")
@click.option("--iterations", type=click.IntRange(min=10), default=4000, show_default=True, help="Iterations per chain.")
@click.option("--burn-in", type=float, default=None,
              help="Discarded fraction (default: 0.5 for synthetic data, 0.2 for measured, as in the paper).")
@click.option("--max-u", type=int, default=3, show_default=True, help="Most u change-point vectors.")
@click.option("--max-v", type=int, default=3, show_default=True, help="Most v change-point vectors.")
@click.option("--sampler", type=click.Choice(["adaptive", "paper"]), default="adaptive", show_default=True,
              help="Within-model moves: adaptive blocks (default) or the paper's component-wise MH.")
@click.option("--prior", type=click.Choice(["default", "paper-synthetic", "paper-real"]), default="default",
              show_default=True, help="Prior preset (paper: Table 1 synthetic, Table 3 real).")
@click.option("--split-map", type=click.Choice(["conditional", "mean", "paper"]), default="conditional",
              show_default=True,
              help="Parameters of regions born by a split: drawn from a data-driven proposal (conditional), "
                   "or a bijective map: mean (|det| 2) or the paper's eq. 10 (|det| 3), Jacobian included.")
@click.option("--cp-prior", type=click.Choice(["smooth", "paper"]), default="smooth", show_default=True,
              help="Change-point prior: random walk along the vector (smooth) or independent uniform per row.")
@click.option("--drop-jacobian", is_flag=True,
              help="Reproduce the paper's acceptance ratio without the split/merge Jacobian (wrong; for study).")
@click.option("--channel", type=click.Choice(["mean", "R", "G", "B", "luminance", "each"]), default="mean",
              show_default=True,
              help="Colour channel fitted (luminance: CIE Y, sRGB primaries); each: R, G and B fitted separately, "
                   "into OUT/R, OUT/G and OUT/B (OUT/NAME/R, ... for several data sets).")
@click.option("--likelihood-power", default="1", show_default=True,
              help="zeta in (0, 1] of the coarsened posterior (likelihood ** zeta, Miller and Dunson 2019): each "
                   "observation counts as zeta observations, so a BRDF misfit shared by neighbouring pixels of "
                   "measured data does not split a uniform material into regions. 'auto': zeta = ((1-rho)/(1+rho))^2 "
                   "from the lag-1 spatial correlation rho of per-pixel-fit residuals (about 1 for white noise). "
                   "1: the plain posterior.")
@click.option("--noise", type=click.Choice(["constant", "shot", "relative"]), default="constant", show_default=True,
              help="Noise model y_i ~ N(mu_i, sigma_r^2 s_i^2), s_i known per observation: constant: s_i = 1 "
                   "(homoscedastic per region, the paper's); shot: s_i^2 = (m_i + c) / ybar (variance grows with "
                   "the signal: photon plus read noise); relative: s_i = (m_i + c) / ybar (sd grows with the signal: "
                   "a multiplicative error). m_i: the prediction of a separate Lambert + Blinn fit of each pixel; "
                   "ybar: the mean observed value; c = NOISE_FLOOR * ybar. Weighted least squares: the sampler is "
                   "unchanged. A model the noise does not follow splits regions: keep constant unless the noise is "
                   "known to grow with the signal.")
@click.option("--noise-floor", type=float, default=0.05, show_default=True,
              help="c / ybar of the shot and relative noise models: the floor (read noise) added to the signal, "
                   "as a fraction of the mean observed value. Unused for --noise constant.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of every random draw.")
@click.option("--validation", "validation_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="validation.json of the data set (default: DATASET/validation/validation.json).")
@click.option("--allow-unvalidated", is_flag=True,
              help="Fit even if the forward model has not passed the cross-check gate (not recommended).")
@click.option("--scheduler", default=None,
              help="Run chains on Dask: 'local' for a local cluster, or a scheduler address (tcp://host:8786).")
@click.option("--workers", type=int, default=2, show_default=True, help="Workers of a local Dask cluster.")
@click.option("--threads", type=click.IntRange(min=1), default=None,
              help="Threads per chain for its large passes over the observations (default: the cores left to "
                   "each chain that runs at once, e.g. 2 for one chain on 2 cores, 1 for 4 chains; 1 on Dask). "
                   "The samples are the same for any number.")
@click.option("--checkpoint-every", type=click.IntRange(min=1), default=2000, show_default=True,
              help="Iterations between a chain's checkpoints (OUT/checkpoints): a fit stopped by Ctrl-C, a crash or "
                   "SIGKILL and run again with the same command resumes there and gives the samples of an "
                   "uninterrupted run.")
def fit(datasets, out_dir, n_chains, iterations, burn_in, max_u, max_v, sampler, prior, split_map, cp_prior,
        drop_jacobian, channel, likelihood_power, noise, noise_floor, seed, validation_path, allow_unvalidated,
        scheduler, workers, threads, checkpoint_every):
    """Segment DATASET(S) and sample the region BRDF posteriors (RJMCMC).

    Refuses a data set whose forward model has not passed `rjfit validate` unless
    --allow-unvalidated is given. Writes summary.json, labels.exr (MAP labels), maps.exr,
    chains.nc, changepoints.npz and the paper's figures; an interrupted fit leaves the
    folder's previous results untouched and resumes from its checkpoints."""
    from rjfit.pipeline.fit_dataset import fit_datasets

    summaries = fit_datasets(datasets, out_dir, n_chains=n_chains, iterations=iterations, burn_in=burn_in,
                             max_u=max_u, max_v=max_v, sampler=sampler, prior=prior, split_map=split_map,
                             cp_prior=cp_prior, drop_jacobian=drop_jacobian, channel=channel,
                             likelihood_power=_likelihood_power(likelihood_power), noise=noise,
                             noise_floor=noise_floor, seed=seed,
                             validation_path=validation_path,
                             allow_unvalidated=allow_unvalidated, scheduler=scheduler, n_workers=workers,
                             threads=threads, checkpoint_every=checkpoint_every)
    for folder, summary in summaries:
        map_model = summary["map_model"]
        click.echo(f"fit of {summary['dataset']} ({summary['channel']}) -> {folder}")
        noise_model = summary.get("noise", {}).get("model", "constant")
        if noise_model != "constant" or summary["likelihood_power"] != 1.0:
            noise_text = (f"noise model {noise_model} (floor {summary['noise']['floor']:g} x mean), "
                          if noise_model != "constant" else "")
            click.echo(f"  {noise_text}likelihood power (zeta) {summary['likelihood_power']:.4g}")
        click.echo(f"  MAP model (n_u, n_v) = ({map_model['n_u']}, {map_model['n_v']}), m = {map_model['m']}, "
                   f"{len(summary['regions'])} regions; R-hat max {summary['rhat_max']:.4f}, "
                   f"ESS min {summary['ess_min']:.0f}; {summary['seconds']:.1f} s")
        if "label_accuracy" in summary:
            click.echo(f"  label accuracy {summary['label_accuracy']:.4f}")
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
    from rjfit.pipeline.report import build_report

    click.echo(f"report: {build_report(fit_dir, out_path, diagnosis_dir=diagnosis_dir, comparison_dir=comparison_dir)}")


def _effect_names():
    from rjfit.diagnose.effects import ALL_EFFECTS

    return [getattr(effect, "name", effect) for effect in ALL_EFFECTS]


@main.command("diagnose")
@click.argument("fit_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", "out_dir", default=None, type=click.Path(file_okay=False, path_type=Path),
              help="Folder for diagnosis.json, diagnosis.md and the figures (default: FIT_DIR/diagnosis, where "
                   "`rjfit report` looks).")
@click.option("--max-steps", type=click.IntRange(min=0), default=3, show_default=True,
              help="Most effects to add; 0 measures the plain model's gap and tries no candidate.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True, help="Seed of the refits and the simulations.")
@click.option("--effects", default=None,
              help="Comma-separated candidate names (default: all): " + ", ".join(_effect_names()) + ".")
@click.option("--dataset", "dataset_dir", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="The fitted data set, if it has moved since the fit (default: the one summary.json names).")
@click.option("--no-simulate", is_flag=True, help="Skip the Mitsuba posterior predictive rendering.")
@click.option("--likelihood-power", type=click.FloatRange(min=0.0, max=1.0, min_open=True), default=None,
              help="The power zeta the refits raise the likelihood to, so that Bayes factors weigh the data as a "
                   "coarsened fit did (default: the fit's, 1 for a plain fit).")
@click.option("--noise", type=click.Choice(["constant", "shot", "relative"]), default=None,
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
    from rjfit.diagnose.effects import ALL_EFFECTS
    from rjfit.diagnose.document import gap_text, named_text
    from rjfit.pipeline.diagnose import diagnose_fit

    out_dir = out_dir or fit_dir / "diagnosis"
    candidates = ALL_EFFECTS if not effects else [name.strip() for name in effects.split(",") if name.strip()]
    options = {} if likelihood_power is None else {"likelihood_power": likelihood_power}
    if noise is not None:
        options["noise"] = noise
    result = diagnose_fit(fit_dir, out_dir, dataset=dataset_dir, candidates=candidates, seed=seed, max_steps=max_steps,
                          simulate=False if no_simulate else None, progress=True, jobs=jobs, **options)
    click.echo(f"named effects: {named_text(result)}")
    if result["named_effects"] and result["search"]["stopped"].startswith("stopped after"):
        click.echo(f"  {result['search']['stopped']} (raise --max-steps to search on)")
    click.echo(f"gap: plain {gap_text(result['gap_plain'])} -> final {gap_text(result['gap_final'])}")
    click.echo(f"report: {Path(out_dir) / 'diagnosis.md'}")


if __name__ == "__main__":
    main()
