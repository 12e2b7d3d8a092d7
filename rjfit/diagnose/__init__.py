"""Model criticism: simulate the fit, find where it disagrees with the data, name the missing
effect from a library of candidates by decisive evidence, add it and show the gap shrink.

Main entry points: :func:`rjfit.diagnose.workflow.diagnose` (data set + fixed labels),
:func:`rjfit.diagnose.workflow.diagnose_fit` (a fit folder), ``rjfit.diagnose.cli.diagnose_command``.
"""
__all__ = ["diagnose", "diagnose_fit"]


# Thin wrappers, so that ``import rjfit.diagnose`` stays light: the workflow (ArviZ, the
# refits, the effect library) is imported on the first call only. functools.wraps would
# import it here, so the docstrings below summarise the workflow's and point to it.

def diagnose(dataset, labels, out_dir, **options):
    """Run the criticism workflow on a data set with a FIXED segmentation.

    Same as :func:`rjfit.diagnose.workflow.diagnose` (see it for every option): refit the
    plain model, measure the gap, try each candidate effect, name one only when the evidence
    is decisive, add it and repeat.

    Parameters
    ----------
    dataset : path or Dataset
        The data set (loaded with :func:`rjfit.data.dataset.load_dataset` if a path).
    labels : ndarray (H, W)
        Region index per pixel (-1 off the object): a fit's MAP labels, or truth labels.
    out_dir : path
        Receives ``diagnosis.json``, ``diagnosis.md`` and the figures; the previous
        diagnosis there is replaced as a whole.
    **options
        Keyword-only options of :func:`rjfit.diagnose.workflow.diagnose`: ``candidates``,
        ``seed``, ``max_steps``, ``threshold``, ``loo_se_factor``, ``simulate``,
        ``n_sim_draws``, ``channel``, ``make_figures``, ``progress``, ``provenance``.

    Returns
    -------
    dict
        The contents of ``diagnosis.json``.

    Raises
    ------
    ValueError
        If ``max_steps`` is not an integer >= 0, a candidate name is unknown, ``labels`` does
        not have the images' shape, or ``channel`` is unknown.
    FileNotFoundError, DatasetError
        When ``dataset`` is a path: as :func:`rjfit.data.dataset.load_dataset`.
    """
    from rjfit.diagnose.workflow import diagnose as run

    return run(dataset, labels, out_dir, **options)


def diagnose_fit(fit_dir, out_dir, **options):
    """Run :func:`diagnose` on a fit folder, with its data set and MAP segmentation.

    Same as :func:`rjfit.diagnose.workflow.diagnose_fit`: the folder's ``summary.json``
    names the data set and the channel fitted; ``map_labels.exr`` (or ``labels.exr``)
    holds the MAP segmentation.

    Parameters
    ----------
    fit_dir : path
        The folder ``rjfit fit`` wrote.
    out_dir : path
        Where the diagnosis goes (see :func:`diagnose`).
    **options
        ``dataset`` (the fitted data set, when the one ``summary.json`` names has moved) and
        the options of :func:`diagnose`; ``channel`` defaults to the fit's.

    Returns
    -------
    dict
        The contents of ``diagnosis.json``.

    Raises
    ------
    FileNotFoundError
        If ``fit_dir`` is not a fit folder, has no MAP labels, or the data set it names is
        not there.
    ValueError
        If ``summary.json`` names no data set and none is given, or the data set's files
        differ from those the fit recorded; and as :func:`diagnose`.
    DatasetError
        If ``summary.json`` is not valid JSON; and as :func:`diagnose`.
    """
    from rjfit.diagnose.workflow import diagnose_fit as run

    return run(fit_dir, out_dir, **options)
