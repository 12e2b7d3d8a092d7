"""At what scale do the measured default's rule residuals correlate? Lags, and the 8 x 8 blocks of a JPEG coder.

For each stack (the calibrated stack of ``validation/misfit_shares.py``'s cache), the residuals the likelihood power
rule reads (per-pixel Lambert + Blinn fits standardised by the normal-error scales,
:func:`rjfit.data.coarsen.suggest_likelihood_power`), raw and high-pass (each light's image less its 9 x 9 local
mean, :func:`normal_refinement.high_pass`): the neighbour correlation at lags 1, 2, 3, 4, 8 and 16 px (rows and
columns averaged), and the lag-1 correlation of pairs inside an 8 x 8 block of the original frame against pairs
that straddle a block boundary (a block coder's seams would lower the latter), with the horizontal pairs' at each
of the 8 phases. One JSON line per stack on stdout.

    python validation/residual_scales.py psm-horse psm-cat psm-rock diligent-ball --cache /tmp/hpaints/cache
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from rjfit.data.noise import weighted_observations
from rjfit.data.normal_error import normal_error_noise
from rjfit.data.pixelfit import per_pixel_residuals
from rjfit.render.datasets import load_dataset

sys.path.insert(0, str(Path(__file__).resolve().parent))
from misfit_shares import load_stack  # noqa: E402
from normal_refinement import high_pass, observations_of  # noqa: E402

LAGS = (1, 2, 3, 4, 8, 16)
BLOCK = 8


def _correlation(a, b) -> float:
    keep = np.isfinite(a) & np.isfinite(b)
    return float(np.corrcoef(a[keep], b[keep])[0, 1])


def scales(dense, origin) -> dict:
    """Lag correlations and the block split of ``dense`` (L, H, W), ``origin`` the crop's (row, col) in the frame."""
    lags = {lag: float(np.mean([_correlation(dense[:, :, :-lag], dense[:, :, lag:]),
                                _correlation(dense[:, :-lag, :], dense[:, lag:, :])])) for lag in LAGS}
    out = {"lags": lags}
    for axis, name in ((2, "h"), (1, "v")):
        first, second = (dense[:, :, :-1], dense[:, :, 1:]) if axis == 2 else (dense[:, :-1, :], dense[:, 1:, :])
        position = np.arange(dense.shape[axis] - 1) + origin[axis - 1]
        phases = []
        for phase in range(BLOCK):
            chosen = (position + 1 - phase) % BLOCK == 0
            index = (slice(None), slice(None), chosen) if axis == 2 else (slice(None), chosen, slice(None))
            phases.append(_correlation(first[index], second[index]))
        out[f"{name}_by_phase"] = phases        # phase 0: the pairs that straddle a block boundary
        out[f"{name}_inside_block"] = float(np.mean(phases[1:]))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("stacks", nargs="+", help="names under --data")
    parser.add_argument("--data", type=Path, default=Path("/work/shared/data"))
    parser.add_argument("--cache", type=Path, default=None, help="the calibrated stacks' cache (misfit_shares.py)")
    args = parser.parse_args(argv)
    for name in args.stacks:
        stack, _ = load_stack(args.data / name, 72.5, 1, args.cache)
        crop = load_dataset(args.data / name, crop=True).meta.get("crop") or {"row0": 0, "col0": 0}
        obs = observations_of(stack, stack.normals)
        residuals = per_pixel_residuals(weighted_observations(obs, normal_error_noise(obs)[0]))
        raw = obs.dense(residuals)
        origin = (crop["row0"], crop["col0"])
        print(json.dumps({"stack": name, "raw": scales(raw, origin),
                          "high_pass": scales(high_pass(raw - np.nanmean(raw), 9), origin)}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
