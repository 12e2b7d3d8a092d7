"""``rjfit run``: the main job, end to end on one scene, as a Python function.

render -> validate -> fit -> compare (with ground truth) -> diagnose and refine -> report,
each step with the defaults of its own command: refine diagnoses the fit (into
``fit/diagnosis``), fits again with what was named and diagnoses again until nothing more is
named (``fit/refine``). :func:`run` tells its caller what happens through two
callables: ``announce(text)`` before each step and ``done(step, result)`` after it (the
command line prints each step's result as that step's own command does).
"""
from __future__ import annotations

import time
from pathlib import Path

from rjfit.pipeline.compare import compare_dataset
from rjfit.pipeline.fit_dataset import fit_dataset
from rjfit.pipeline.options import FitOptions
from rjfit.pipeline.refine import refine
from rjfit.pipeline.report import build_report
from rjfit.render.gate import ValidationRequiredError, validate_dataset
from rjfit.render.render import render_dataset

__all__ = ["run", "STEPS"]

STEPS = ("render", "validate", "fit", "compare", "refine", "report")


def _quiet(*_):
    return None


def run(scene: str = "paper_sphere", out_dir=None, *, resolution=None, iterations: int = 4000, n_chains: int = 4,
        seed: int = 0, allow_unvalidated: bool = False, announce=print, done=_quiet) -> dict:
    """Run the main job on ``scene`` into ``out_dir`` (default ``runs/<scene name>``).

    Parameters
    ----------
    scene : str
        A built-in scene name or a scene JSON file.
    out_dir : path, optional
        The run folder: ``dataset/`` and ``fit/`` (with ``comparison/``, ``diagnosis/``,
        ``refine/`` and ``report.html``) inside it.
    resolution : int, optional
        Square image size (default: the scene's).
    iterations, n_chains : int
        The fit's iterations per chain and chains.
    seed : int
        Seed of validation, fit, baselines and diagnosis.
    allow_unvalidated : bool
        Go on after a failed cross-check (the fit's warnings then say so).
    announce, done : callable
        ``announce(text)`` before each step; ``done(step, result)`` after it, with ``step`` one
        of :data:`STEPS`.

    Returns
    -------
    dict
        ``{step: result}`` of the steps that ran, ``"report"`` the report's path, and ``seconds``.

    Raises
    ------
    ValidationRequiredError
        If the cross-check fails and ``allow_unvalidated`` is False (after the validation's
        results are written).
    """
    started = time.perf_counter()
    out_dir = Path(out_dir) if out_dir is not None else Path("runs") / Path(scene).stem
    dataset_dir, fit_dir = out_dir / "dataset", out_dir / "fit"
    results = {}

    def step(number, name, title, work):
        announce(f"== {number}/6 {title}")
        results[name] = work()
        done(name, results[name])

    step(1, "render", f"render {scene}", lambda: render_dataset(scene, dataset_dir, resolution=resolution,
                                                                   progress=True))
    step(2, "validate", "validate (closed form vs Mitsuba path tracer)",
         lambda: validate_dataset(dataset_dir, spp=4, seed=seed, progress=True))
    if not results["validate"]["passed"] and not allow_unvalidated:
        raise ValidationRequiredError(
            f"the closed-form model does not match Mitsuba on {dataset_dir} (see {dataset_dir / 'validation'}), so a "
            f"fit would not be trustworthy; stopped. Pass --allow-unvalidated to fit and diagnose it anyway.")
    options = FitOptions(n_chains=n_chains, iterations=iterations, seed=seed)
    step(3, "fit", "fit (RJMCMC)", lambda: fit_dataset(dataset_dir, fit_dir, options,
                                                       allow_unvalidated=allow_unvalidated))
    if (dataset_dir / "truth_labels.exr").is_file():
        step(4, "compare", "compare with baselines",
             lambda: compare_dataset(dataset_dir, fit_dir / "comparison", fit_dir=fit_dir, seed=seed,
                                     progress=announce))
    step(5, "refine", "diagnose (model criticism) and refine (fit again with what was named)",
         lambda: refine(fit_dir, fit_dir / "refine", first_diagnosis_dir=fit_dir / "diagnosis", seed=seed,
                        progress=True, say=announce))
    step(6, "report", "report", lambda: build_report(fit_dir))
    results["seconds"] = time.perf_counter() - started
    return results
