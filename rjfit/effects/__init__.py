"""The library of effects: one module per effect, each holding its physics, its criticism form
(``rjfit diagnose``: an extension of eq. 2 with a Mitsuba-side change) and its fit form
(``rjfit fit --effects``: a column factor, data transform or lobe term); :mod:`~rjfit.effects.base`
states the protocol, :mod:`~rjfit.effects.scenes` renders a context's fitted model.

The registry: :data:`ALL_EFFECTS` (in the order a diagnosis tries them), :data:`EFFECTS` by
name, :func:`get_effect`, and :func:`effects_help` (the ``--effects`` help of both commands).
"""
from rjfit.effects.ambient import Ambient
from rjfit.effects.base import STAGES, CameraResponse, Columns, Effect, FitForm, Param
from rjfit.effects.camera_gamma import CameraGamma
from rjfit.effects.camera_srgb import CameraSRGB
from rjfit.effects.cast_shadows import CastShadows
from rjfit.effects.coating import Coating
from rjfit.effects.fresnel import Fresnel
from rjfit.effects.ggx import GGX
from rjfit.effects.interreflection import Interreflection
from rjfit.effects.light_calibration import LightCalibration
from rjfit.effects.masking import Masking
from rjfit.effects.rough_coating import RoughCoating
from rjfit.effects.second_lobe import SecondLobe

__all__ = ["Effect", "CameraResponse", "FitForm", "Columns", "Param", "STAGES", "ALL_EFFECTS", "EFFECTS", "get_effect",
           "effects_help", "Fresnel", "Masking", "GGX", "SecondLobe", "Coating", "RoughCoating", "Interreflection", "Ambient", "CastShadows",
           "CameraGamma", "CameraSRGB", "LightCalibration"]

ALL_EFFECTS = (Fresnel(), Masking(), GGX(), SecondLobe(), Coating(), RoughCoating(), Interreflection(), Ambient(), CastShadows(), CameraGamma(),
               CameraSRGB(), LightCalibration())
EFFECTS = {effect.name: effect for effect in ALL_EFFECTS}


def get_effect(name_or_effect):
    """The library's effect of that name (an :class:`Effect` is returned as it is).

    Raises
    ------
    ValueError
        For a name the library does not hold.
    """
    if isinstance(name_or_effect, Effect):
        return name_or_effect
    try:
        return EFFECTS[name_or_effect]
    except KeyError:
        raise ValueError(f"unknown effect {name_or_effect!r}; known: {sorted(EFFECTS)}") from None


def effects_help() -> str:
    """The library's effects for a command's help: each name with what it adds, in the order of :data:`ALL_EFFECTS`."""
    return " ".join(f"{effect.name}: {effect.description}." for effect in ALL_EFFECTS)
