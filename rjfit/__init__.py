"""rjfit: a Mitsuba-validated reflectance fitter (Lenoch, Wilhelm and Woehler, VISAPP 2016).

Data flows one way: scene -> render -> observations -> validate -> fit -> diagnose, and the
packages import downwards only (docs/architecture.md). Mitsuba is imported only inside
``rjfit.render`` (and only when a function there needs it), so ``import rjfit`` stays light.
"""
from importlib.metadata import version as _installed_version

from rjfit.jit_cache import use_source_keyed_cache

use_source_keyed_cache()     # before any compiled function is defined: Numba's cache follows the source

from rjfit.data.dataset import Dataset  # noqa: E402
from rjfit.data.lights import Light, geometry_terms  # noqa: E402
from rjfit.data.observations import Observations, observations_from_stack, valid_observation_mask  # noqa: E402
from rjfit.model.blinn import blinn_normalisation, brdf, radiance  # noqa: E402
from rjfit.pipeline.load import LoadedFit, load_fit  # noqa: E402
from rjfit.render.datasets import load_dataset  # noqa: E402

__version__ = _installed_version("rjfit")   # pyproject.toml is the one place the version is written

__all__ = [
    "__version__",
    "Dataset",
    "Light",
    "LoadedFit",
    "Observations",
    "blinn_normalisation",
    "brdf",
    "geometry_terms",
    "load_dataset",
    "load_fit",
    "observations_from_stack",
    "radiance",
    "valid_observation_mask",
]
