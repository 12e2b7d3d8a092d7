"""Model criticism: simulate the fit, find where it disagrees with the data, name the missing
effect from a library of candidates by decisive evidence, add it and show the gap shrink.

Main entry points: :func:`rjfit.diagnose.workflow.diagnose` (data set + fixed labels),
:func:`rjfit.diagnose.workflow.diagnose_fit` (a fit folder), ``rjfit.diagnose.cli.diagnose_command``.
"""
__all__ = ["diagnose", "diagnose_fit"]


def diagnose(*args, **kwargs):
    from rjfit.diagnose.workflow import diagnose as run

    return run(*args, **kwargs)


def diagnose_fit(*args, **kwargs):
    from rjfit.diagnose.workflow import diagnose_fit as run

    return run(*args, **kwargs)
