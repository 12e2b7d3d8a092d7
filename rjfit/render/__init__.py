"""Mitsuba plugins, scene building and geometry from AOVs.

Nothing here imports Mitsuba at package import time; import the submodules
(e.g. ``rjfit.render.plugin``) where they are needed.
"""
