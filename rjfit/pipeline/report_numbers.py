"""How the report writes a summary's numbers in words: shared by :mod:`rjfit.pipeline.report_text` and each
region model's report rows (:class:`rjfit.pipeline.regions.base.RegionFit`), which it imports."""
from __future__ import annotations

import math

__all__ = ["number", "probability", "finite"]


def number(value, spec=".4g") -> str:
    """``value`` formatted by ``spec`` if it is a number, else as text (a hand-edited summary)."""
    return format(value, spec) if isinstance(value, (int, float)) and not isinstance(value, bool) else str(value)


def probability(value):
    """A probability with three decimals (1.000, not 1: a rounded certainty is not a count), else as it is."""
    return f"{value:.3f}" if finite(value) else value


def finite(value) -> bool:
    """Whether ``value`` is a finite number (not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
