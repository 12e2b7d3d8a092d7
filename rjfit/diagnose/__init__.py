"""Model criticism: simulate the fit, find where it disagrees with the data, name the missing
effect from a library of candidates by decisive evidence, add it and show the gap shrink.

Main entry points: :func:`rjfit.diagnose.workflow.diagnose` (data set + fixed labels),
:func:`rjfit.diagnose.workflow.diagnose_fit` (a fit folder), ``rjfit.diagnose.cli.diagnose_command``.
"""
__all__ = ["diagnose", "diagnose_fit"]


# Thin wrappers, so that ``import rjfit.diagnose`` stays light: the workflow (ArviZ, the
# refits, the effect library) is imported on the first call only. functools.wraps would
# import it here, so the docstrings below summarise the workflow's and point to it
# (help(rjfit.diagnose.workflow.diagnose) has every option).

def diagnose(dataset, labels, out_dir, **options):
    """Run the criticism workflow on a data set with a FIXED segmentation (``labels``, (H, W)).

    Refit the plain model, measure the gap, try each candidate effect, name one only when
    the evidence is decisive, add it and repeat; returns the contents of ``diagnosis.json``
    written to ``out_dir``. Parameters, options and Raises: :func:`rjfit.diagnose.workflow.diagnose`.
    """
    from rjfit.diagnose.workflow import diagnose as run

    return run(dataset, labels, out_dir, **options)


def diagnose_fit(fit_dir, out_dir, **options):
    """Run :func:`diagnose` on a fit folder, with the data set and MAP segmentation it records.

    Returns the contents of ``diagnosis.json`` written to ``out_dir``. Parameters, options
    (``dataset`` when the fitted data set has moved) and Raises:
    :func:`rjfit.diagnose.workflow.diagnose_fit`.
    """
    from rjfit.diagnose.workflow import diagnose_fit as run

    return run(fit_dir, out_dir, **options)
