"""Which observations carry the power-law stack's wrong camera (issue 44): the refits' log
evidence of four camera models on ``camera_gamma_sensor`` (truth labels), with the likelihood
plain (untruncated) and truncated at the declared dark threshold, the plain log-likelihood gain
of ambient + sRGB over the power law by the observations' noise-free linear value (the same
scene rendered noise-free: ``clean``), and the plain evidence again on the observations whose
noise-free value is at least K read-noise sd (a selection that does not look at the noise).

    .venv/bin/python validation/dark_truncation.py DATASET OUT [--cuts 3 5]

DATASET: a ``camera_gamma_sensor`` data set (rendered into it at 64 x 64 if missing); OUT: a
folder for the noise-free render.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path


sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rjfit.diagnose.context import build_context  # noqa: E402
from rjfit.diagnose.refit import refit  # noqa: E402
from rjfit.effects import EFFECTS  # noqa: E402
from rjfit.render.datasets import load_dataset  # noqa: E402
from rjfit.render.hidden import render_hidden  # noqa: E402

MODELS = {"camera_gamma": ["camera_gamma"], "ambient + camera_gamma": ["ambient", "camera_gamma"],
          "camera_srgb": ["camera_srgb"], "ambient + camera_srgb": ["ambient", "camera_srgb"]}
BINS_SD = (0, 1, 2, 3, 5, 10, 30, math.inf)


def _fits(ctx):
    return {name: refit(ctx, [EFFECTS[e] for e in effects], n_draws=2) for name, effects in MODELS.items()}


def _print_evidence(title, fits):
    base = fits["camera_gamma"].log_evidence
    print(f"\n{title}")
    for name, fit in fits.items():
        effect = {n: round(float(v), 4) for n, v in zip(fit.names, fit.constrained()) if "." in n}
        print(f"  {name:24s} log Z {fit.log_evidence:10.1f}   log BF vs camera_gamma {fit.log_evidence - base:8.1f}"
              f"   {effect}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--cuts", type=float, nargs="*", default=[3.0, 5.0],
                        help="noise-free linear values (in read-noise sd) below which the last refits leave observations out")
    args = parser.parse_args()
    if not (args.dataset / "dataset.json").is_file():
        render_hidden("camera_gamma_sensor", args.dataset, resolution=64)
    dataset = load_dataset(args.dataset)
    clean = args.out / "clean_noise_free"
    if not (clean / "dataset.json").is_file():
        render_hidden("clean", clean, resolution=dataset.image_shape[0], noise_variance=0.0)
    linear = load_dataset(clean).images.mean(axis=-1)
    sd = math.sqrt(float(dataset.meta["hidden_response"]["read_noise_variance"]))
    ctx = build_context(dataset, dataset.truth_labels)
    print(f"{ctx.n_obs} kept observations, declared dark {ctx.dark}")
    _print_evidence("truncated at the declared dark threshold (the refits' likelihood)", _fits(ctx))
    plain = _fits(dataclasses.replace(ctx, dark=None, features={}))
    _print_evidence("plain normal (untruncated)", plain)
    gain = (plain["ambient + camera_srgb"].objective.log_lik_pointwise(plain["ambient + camera_srgb"].z)
            - plain["camera_gamma"].objective.log_lik_pointwise(plain["camera_gamma"].z))
    width = dataset.image_shape[1]
    value = linear[ctx.light, ctx.pixel // width, ctx.pixel % width]      # each observation's noise-free value
    print("  plain log-likelihood gain of ambient + camera_srgb over camera_gamma by noise-free linear value:")
    for low, high in zip(BINS_SD[:-1], BINS_SD[1:]):
        part = (value >= low * sd) & (value < high * sd)
        print(f"    [{low:g}, {high:g}) sd: {int(part.sum()):6d} observations, {float(gain[part].sum()):8.1f}")
    for cut in args.cuts:
        kept = ctx.valid & (linear >= cut * sd)
        cut_ctx = dataclasses.replace(build_context(dataset, dataset.truth_labels, valid=kept), dark=None)
        _print_evidence(f"plain normal, noise-free linear value >= {cut:g} sd ({cut_ctx.n_obs} observations)",
                        _fits(cut_ctx))


if __name__ == "__main__":
    main()
