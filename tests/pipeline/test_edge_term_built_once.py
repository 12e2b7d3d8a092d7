"""A fit under ``--preset measured`` builds the material model's edge term once.

The term (its pairs, their matched observations, the reference fit, the no-step sums) is the largest part of a
measured fit's set-up: minutes and gigabytes at 2048 x 2048 (docs/results/2026-11-28-scale.md). The fit measures its
power, local gain and noise on one build (``rjfit.pipeline.fit_power.edge_settings``); the chains' shared start and
the summary's resolution take that build instead of building it twice more. Why that changes nothing: a term built
again from the settings the measured one reports is the same term, array for array (checked here on a real render,
in one channel and in colour). Cost: two 1-chain x 30-iteration fits of the 48 x 48 sphere, about 10 s.
"""
import dataclasses

import numpy as np
import pytest

import rjfit.pipeline.fit_power
import rjfit.pipeline.regions.material_resolution
import rjfit.sampler.regions.materials.model
from rjfit.pipeline.fit_dataset import fit_dataset
from rjfit.pipeline.options import FitOptions
from rjfit.sampler.regions.materials.edges import edge_term
from rjfit.sampler.regions.materials.model import MaterialRegions

BUILDERS = (rjfit.pipeline.fit_power, rjfit.sampler.regions.materials.model,
            rjfit.pipeline.regions.material_resolution)


@pytest.fixture
def builds(monkeypatch):
    """Every edge term a fit builds: ``(problem, labelled, term)``, by the real :func:`edge_term`."""
    made = []

    def counted(problem, labelled, *args, **kwargs):
        term = edge_term(problem, labelled, *args, **kwargs)
        made.append((problem, labelled, term))
        return term

    for module in BUILDERS:
        monkeypatch.setattr(module, "edge_term", counted)
    return made


def assert_same_term(a, b):
    for field in a._fields:
        x, y = getattr(a, field), getattr(b, field)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and np.array_equal(x, y), field
        else:
            assert x == y, field


@pytest.mark.parametrize("channel", ["mean", "rgb"])
def test_a_measured_fit_builds_its_edge_term_once_and_a_term_built_again_is_the_same(paper_sphere_small, tmp_path,
                                                                                    builds, channel):
    summary = fit_dataset(paper_sphere_small, tmp_path / "fit", FitOptions(
        preset="measured", regions="materials", channel=channel, n_chains=1, iterations=30, processes=1,
        progress=False, figures=False), allow_unvalidated=True)
    assert len(builds) == 1             # before: three (the settings, the chains' start, the resolution)
    problem, labelled, term = builds[0]
    assert (term.power, term.gain_sd) == (summary["edge_power"], summary["edge_gain_sd"])
    assert summary["material_resolution"]["edge_evidence_per_pair"] > 0
    again = edge_term(problem, labelled, term.power, gain_sd=term.gain_sd, noise=term.noise)
    assert_same_term(term, again)
    # the chains' model takes it: its settings are the term's
    model = dataclasses.replace(MaterialRegions(), edge_power=term.power, edge_gain_sd=term.gain_sd,
                                edge_noise=term.noise)
    assert model.built_with(term) and model.data_bonds(problem, term).edges is term
    with pytest.raises(ValueError, match="edge term given was built with power"):
        dataclasses.replace(model, edge_power=2 * term.power).data_bonds(problem, term)
    assert not dataclasses.replace(model, edge_gap=term.gap + 2).built_with(term)
