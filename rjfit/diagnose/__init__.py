"""Model criticism: simulate the fit, find where it disagrees with the data, name the missing
effect from a library of candidates by decisive evidence, add it and show the gap shrink.

Entry point: :func:`rjfit.diagnose.workflow.diagnose` (a data set and a fixed segmentation);
``rjfit diagnose FIT`` runs it on a fit folder (:func:`rjfit.pipeline.diagnose.diagnose_fit`).
"""
