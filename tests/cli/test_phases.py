"""Every phase of a fit that can take long announces itself on stderr, and announcing it changes nothing.

The phases (issue 43): the calibration (camera response, per-light gains), the normal-error
estimate, the likelihood power, the edge term's power, the summary after the chains, the gate
and the diagnosis. Each test runs the real thing on the session's 48 x 48 paper_sphere render
and reads what it wrote to stderr (capfd: the chains and Mitsuba write from other threads).
Cost: about 50 s alone once Numba's cache is warm, 2 min beside a running fit on the 2-core machine.
"""
import dataclasses
import io
import re

import numpy as np

from rjfit.data.calibrate import calibrate_measured
from rjfit.pipeline.fit_dataset import fit_dataset
from rjfit.pipeline.options import FitOptions
from rjfit.progress import phase, tracked
from rjfit.render.datasets import load_dataset

DONE = r": done in (\d+ s|\d+\.\d min)$"


def _announced(text: str, desc: str) -> bool:
    """``desc ...`` then ``desc: done in N s`` among the lines of ``text``."""
    lines = text.splitlines()
    return f"{desc} ..." in lines and any(re.fullmatch(re.escape(desc) + DONE, line) for line in lines)


def test_a_phase_writes_its_start_and_its_duration_and_nothing_when_off():
    stream, now = io.StringIO(), [0.0]
    with phase("calibration: per-light gains", stream=stream, clock=lambda: now[0]):
        now[0] = 12.4
    assert stream.getvalue() == "calibration: per-light gains ...\ncalibration: per-light gains: done in 12 s\n"
    quiet = io.StringIO()
    with phase("anything", enabled=False, stream=quiet):
        pass
    assert quiet.getvalue() == ""
    assert list(tracked(range(3), "loop", enabled=False)) == [0, 1, 2]


def _raw_stack(path):
    """The render as an uncalibrated 8-bit-like stack: unknown response (power 1/1.3) and per-light gains."""
    dataset = load_dataset(path)
    gains = np.geomspace(0.85, 1.15, dataset.n_lights)
    linear = dataset.images * gains[:, None, None, None]
    return dataclasses.replace(dataset, images=np.clip(linear / linear.max(), 0.0, None) ** (1 / 1.3),
                               response="unknown", quantisation_variance=None)


def test_the_calibration_announces_each_step_and_gives_the_same_result(paper_sphere_small, capfd):
    raw = _raw_stack(paper_sphere_small)
    quiet_data, quiet_record = calibrate_measured(raw)
    assert capfd.readouterr().err == ""                       # off by default: library calls stay silent
    data, record = calibrate_measured(raw, progress=True)
    err = capfd.readouterr().err
    assert _announced(err, "calibration: camera response (kappa of raw = k linear^(1/kappa))"), err
    assert _announced(err, "calibration: per-light gains"), err
    assert re.search(r"^camera response: per-pixel fits: kappa 41 of 41, .*done$", err, re.M), err
    assert re.search(r"^camera response: bootstrap: replicate 200 of 200, .*done$", err, re.M), err
    assert re.search(r"^light gains: tile fits: round \d+ of 60, largest step .*", err, re.M), err
    # the same code run twice, with and without the lines: no draw added, the same numbers bit for bit
    np.testing.assert_array_equal(data.images, quiet_data.images)
    assert record == quiet_record


def test_a_measured_fit_announces_its_loading_estimates_and_summary(paper_sphere_small, tmp_path, capfd):
    options = FitOptions(preset="measured", regions="materials", n_chains=1, iterations=30, processes=1,
                         figures=False, seed=3)
    quiet = fit_dataset(paper_sphere_small, tmp_path / "quiet", options.replace(progress=False),
                        allow_unvalidated=True)
    assert capfd.readouterr().err == ""
    loud = fit_dataset(paper_sphere_small, tmp_path / "loud", options, allow_unvalidated=True)
    err = capfd.readouterr().err
    for desc in (f"loading the data set {paper_sphere_small}",
                 "noise model normals: estimating the normals' error (5 x 5 pixel tile fits)",
                 "likelihood power: spatial correlation of per-pixel fits' residuals",
                 "edge term: measuring its power (--edge-power auto), its local gain (--edge-gain-sd auto) and its "
                 "noise (--edge-noise measured)",
                 "summarising the chains (MAP labels, posterior mean prediction, checks)",
                 "writing the results and figures"):
        assert _announced(err, desc), (desc, err)
    assert re.search(r"^chain 0: iteration 30 of 30, .*done$", err, re.M), err
    for key in ("regions", "materials_posterior", "likelihood_power", "edge_power", "noise", "map_materials"):
        assert loud[key] == quiet[key], key



def test_a_diagnosis_announces_its_loading_and_its_simulations(paper_sphere_small, tmp_path, capfd):
    """The plain model's gap only (no candidate), with Mitsuba's posterior predictive of it (3 draws)."""
    from rjfit.pipeline.diagnose import diagnose_fit

    fit_dataset(paper_sphere_small, tmp_path / "fit", FitOptions(n_chains=1, iterations=30, processes=1,
                                                                 figures=False, progress=False),
                allow_unvalidated=True)
    capfd.readouterr()
    diagnose_fit(tmp_path / "fit", tmp_path / "diagnosis", max_steps=0, simulate=True, progress=True, jobs=1,
                 make_figures=False)
    err = capfd.readouterr().err
    assert _announced(err, "diagnosis: loading the data set (and replaying the fit's calibration)"), err
    assert _announced(err, "diagnosis: Mitsuba posterior predictive of the plain model (3 draws rendered)"), err


def test_the_gate_announces_its_geometry_and_counts_its_lights(paper_sphere_small, tmp_path, capfd):
    from rjfit.render.gate import validate_dataset

    validate_dataset(paper_sphere_small, tmp_path / "validation", spp=1, progress=True, variant="llvm_ad_rgb")
    err = capfd.readouterr().err
    assert _announced(err, "validate: building the scene's geometry and tracing the pixels (llvm_ad_rgb)"), err
    assert re.search(r"^validate: path tracing: light 10 of 10, .*done$", err, re.M), err
