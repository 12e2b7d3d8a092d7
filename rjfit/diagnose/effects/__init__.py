"""The library of candidate missing effects (one module each); see ``base`` for the protocol."""
from rjfit.diagnose.effects.ambient import Ambient
from rjfit.diagnose.effects.base import STAGES, Effect, Param
from rjfit.diagnose.effects.calibration import LightCalibration
from rjfit.diagnose.effects.camera import CameraGamma, CameraSRGB
from rjfit.diagnose.effects.fresnel import Fresnel
from rjfit.diagnose.effects.interreflection import Interreflection
from rjfit.diagnose.effects.masking import Masking
from rjfit.diagnose.effects.shadows import CastShadows

__all__ = ["Effect", "Param", "STAGES", "ALL_EFFECTS", "EFFECTS", "get_effect",
           "Fresnel", "Masking", "Interreflection", "Ambient", "CastShadows", "CameraGamma", "CameraSRGB",
           "LightCalibration"]

ALL_EFFECTS = (Fresnel(), Masking(), Interreflection(), Ambient(), CastShadows(), CameraGamma(), CameraSRGB(),
               LightCalibration())
EFFECTS = {effect.name: effect for effect in ALL_EFFECTS}


def get_effect(name_or_effect):
    if isinstance(name_or_effect, Effect):
        return name_or_effect
    try:
        return EFFECTS[name_or_effect]
    except KeyError:
        raise ValueError(f"unknown effect {name_or_effect!r}; known: {sorted(EFFECTS)}") from None
