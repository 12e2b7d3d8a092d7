"""Closed-form reflectance models."""
from rjfit.model.blinn import blinn_normalisation, brdf, log_cos_power, radiance

__all__ = ["blinn_normalisation", "brdf", "log_cos_power", "radiance"]
