"""Data sets, EXR / PNG loaders, observations and masks."""
