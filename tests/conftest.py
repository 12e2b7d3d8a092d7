"""Shared fixtures: small data sets rendered once per test session with the real Mitsuba."""
from __future__ import annotations

import pytest

from builders import SHARED_DATA


@pytest.fixture(scope="session")
def paper_sphere_small(tmp_path_factory):
    """paper_sphere at 48 x 48 (10 lights, noise variance 0.1), rendered by Mitsuba."""
    from rjfit.render.render import render_dataset

    return render_dataset("paper_sphere", tmp_path_factory.mktemp("paper_sphere") / "dataset", resolution=48)


@pytest.fixture(scope="session")
def dented_plaster_small(tmp_path_factory):
    """The concave two-material object at 40 x 40, 16 spp, rendered by Mitsuba."""
    from rjfit.render.render import render_dataset

    return render_dataset("dented_plaster", tmp_path_factory.mktemp("dented") / "dataset", resolution=40, spp=16)


@pytest.fixture(scope="session")
def diligent_ball_dir():
    path = SHARED_DATA / "diligent-ball"
    if not path.is_dir():
        pytest.skip(f"measured data not found at {path} (it lives in ../shared beside the checkout)")
    return path
