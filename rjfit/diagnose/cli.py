"""``rjfit diagnose FIT_DIR --out DIR`` (registered by rjfit.cli: main.add_command(diagnose_command, 'diagnose'))."""
from __future__ import annotations

from pathlib import Path

import click


def _effect_names():
    from rjfit.diagnose.effects import ALL_EFFECTS

    return [getattr(effect, "name", effect) for effect in ALL_EFFECTS]


@click.command("diagnose")
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
def diagnose_command(fit_dir, out_dir, max_steps, seed, effects, dataset_dir, no_simulate, likelihood_power, noise,
                     jobs):
    """Criticise a fit: find where simulation and data disagree, name the missing effect
    (only when the evidence is decisive), add it, refit and show the gap shrink."""
    from rjfit.diagnose.effects import ALL_EFFECTS
    from rjfit.diagnose.report import gap_text, named_text
    from rjfit.diagnose.workflow import diagnose_fit

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
