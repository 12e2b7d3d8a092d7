"""rjfit: a Mitsuba-validated reflectance fitter (Lenoch, Wilhelm and Woehler, VISAPP 2016).

Data flows one way: scene -> render -> observations -> validate -> fit -> diagnose.
Mitsuba is imported only by the modules that render (``rjfit.render``, ``rjfit.validate``).
"""
from rjfit.data.dataset import Dataset, load_dataset
from rjfit.data.lights import Light, geometry_terms
from rjfit.data.observations import Observations, observations_from_stack, valid_observation_mask
from rjfit.model.blinn import blinn_normalisation, brdf, radiance

__version__ = "0.1.0"

__all__ = [
    "__version__",
    "Dataset",
    "Light",
    "Observations",
    "blinn_normalisation",
    "brdf",
    "geometry_terms",
    "load_dataset",
    "observations_from_stack",
    "radiance",
    "valid_observation_mask",
]
