"""Traces beside rank plots of a fit's chains, read from its ``chains.nc`` (ArviZ InferenceData).

Overplotted traces hide all but the last chain; a rank plot does not (Vehtari et al. 2021,
"Rank-normalization, folding, and localization"): every kept draw is ranked among all chains'
draws pooled, and each chain's ranks are histogrammed. Chains that sample one distribution give
flat histograms of equal height; a chain stuck in a mode of its own gives a histogram piled at
one end. :func:`chain_figure` shows, for the log posterior and each parameter of the first
regions (materials), the traces (one colour and line style per chain, a legend) and the rank
histograms side by side.

The reader takes either layout of ``chains.nc``: the log posterior as ``sample_stats.lp``,
``sample_stats.log_post`` or ``posterior.log_post``; the region parameters as one variable
``theta`` with a ``parameter`` dimension (NaN where a region is not in a draw's model) or as
one variable per parameter, each with a region or material dimension.
"""
from __future__ import annotations

import numpy as np

from rjfit.plotting import pyplot

__all__ = ["chain_series", "rank_counts", "chain_figure", "PARAMETER_UNITS"]

#: what each region parameter is (a panel's title) and its unit (the panel's y label)
PARAMETER_UNITS = {"I0": ("I0, light intensity x albedo", "image units"), "kd": ("kd, diffuse fraction", "fraction"),
                   "gamma": ("gamma, Blinn-Phong exponent", "exponent"),
                   "sigma2": ("sigma2, noise variance", "image units^2")}
_REGION_DIMS = ("material", "region")
_LP_NAMES = (("sample_stats", "lp"), ("sample_stats", "log_post"), ("posterior", "lp"), ("posterior", "log_post"))


def _log_posterior(idata):
    for group, name in _LP_NAMES:
        dataset = getattr(idata, group, None) if group in idata.groups() else None
        if dataset is not None and name in dataset:
            return np.asarray(dataset[name].values, float)
    return None


def _parameter_arrays(posterior):
    """``{parameter: array (chain, draw, region)}`` of the region parameters, in either layout."""
    out = {}
    for name, variable in posterior.data_vars.items():
        dims = variable.dims
        region_dim = next((d for d in dims if d in _REGION_DIMS), None)
        if region_dim is None or "chain" not in dims:
            continue
        if "parameter" in dims:
            for parameter in variable.coords["parameter"].values:
                out[str(parameter)] = variable.sel(parameter=parameter)
        elif name in PARAMETER_UNITS:
            out[name] = variable
    arrays = {}
    for parameter, variable in out.items():
        extra = [d for d in variable.dims if d not in ("chain", "draw") and d not in _REGION_DIMS]
        if extra:       # a joint colour fit: the first channel stands for the others in the figure
            variable = variable.isel({d: 0 for d in extra})
        region_dim = next(d for d in variable.dims if d in _REGION_DIMS)
        arrays[parameter] = np.asarray(variable.transpose("chain", "draw", region_dim).values, float)
    return arrays


def chain_series(idata, max_regions: int = 2) -> list:
    """``[(title, unit, array (chain, draw))]``: the log posterior, then each parameter of the first
    ``max_regions`` regions (materials) that hold draws; NaN where a chain is in a model without that region."""
    series = []
    lp = _log_posterior(idata)
    if lp is not None and lp.ndim == 2:
        series.append(("log posterior (up to a constant)", "log density", lp))
    posterior = idata.posterior if "posterior" in idata.groups() else None
    arrays = _parameter_arrays(posterior) if posterior is not None else {}
    kind = "material" if posterior is not None and "material" in posterior.dims else "region"
    shown = 0
    regions = next(iter(arrays.values())).shape[2] if arrays else 0
    for region in range(regions):
        if shown == max_regions:
            break
        if not any(np.isfinite(a[:, :, region]).any() for a in arrays.values()):
            continue            # a padded slot no kept draw uses
        shown += 1
        for parameter, values in arrays.items():
            title, unit = PARAMETER_UNITS.get(parameter, (parameter, "value"))
            series.append((f"{kind} {region}: {title}", unit, values[:, :, region]))
    return series


def rank_counts(values, bins: int = 20):
    """Per chain, the histogram (chain, bins) of its draws' ranks among every chain's finite draws pooled.

    Ties get their average rank; a chain's NaN draws are left out of its histogram.
    """
    from scipy.stats import rankdata

    values = np.asarray(values, float)
    finite = np.isfinite(values)
    ranks = np.full(values.shape, np.nan)
    ranks[finite] = rankdata(values[finite])
    edges = np.linspace(0.5, finite.sum() + 0.5, bins + 1)
    return np.stack([np.histogram(row[np.isfinite(row)], bins=edges)[0] for row in ranks])


_STYLES = ("-", "--", ":", "-.")


def chain_figure(idata, max_regions: int = 2, burn_in: int | None = None):
    """Traces (left) and rank histograms (right) of :func:`chain_series`, one row each; None without series.

    ``burn_in``: the kept draws start after it (said in the x label); the traces are of kept draws.
    """
    plt = pyplot()
    series = chain_series(idata, max_regions)
    if not series:
        return None
    n_chains = series[0][2].shape[0]
    colours = plt.get_cmap("tab10").colors
    fig, axes = plt.subplots(len(series), 2, figsize=(13, 1.9 * len(series) + 0.9), squeeze=False,
                             gridspec_kw={"width_ratios": (2.2, 1)}, layout="constrained")
    for row, (title, unit, values) in enumerate(series):
        trace, rank = axes[row]
        for chain in range(values.shape[0]):
            trace.plot(values[chain], lw=0.7, alpha=0.85, color=colours[chain % 10], ls=_STYLES[chain % 4],
                       label=f"chain {chain}")
        trace.set_title(title, fontsize=8, loc="left")
        trace.set_ylabel(unit, fontsize=8)
        trace.ticklabel_format(axis="y", useOffset=False)
        trace.tick_params(labelsize=7)
        counts = rank_counts(values)
        # each chain's histogram in its own band, as ArviZ's plot_rank draws them: bars of the mean height
        # (the dotted line) are what chains that sample one distribution give
        height = max(float(counts.max()), 1.0)
        for chain, chain_counts in enumerate(counts):
            base = chain * height * 1.1
            rank.bar(np.arange(len(chain_counts)), chain_counts, bottom=base, width=1.0, color=colours[chain % 10],
                     edgecolor="white", linewidth=0.3)
            rank.axhline(base + chain_counts.mean(), color="k", ls=":", lw=0.7)
        rank.set_yticks([chain * height * 1.1 + height / 2 for chain in range(len(counts))],
                        [f"chain {chain}" for chain in range(len(counts))], fontsize=7)
        rank.set_xticks([-0.5, len(counts[0]) - 0.5], ["lowest", "highest"], fontsize=7)
        rank.set_ylim(0, len(counts) * height * 1.1)
    # above the first trace, right of its title: inside, it would hide the draws
    axes[0, 0].legend(fontsize=7, ncol=min(n_chains, 4), loc="lower right", bbox_to_anchor=(1.0, 1.0),
                      frameon=False)
    fig.suptitle("Traces of the kept draws (left) and rank plots (right: flat, equal histograms = the chains agree)",
                 fontsize=10)
    kept = "kept draw" + (f" (iterations after the burn-in of {burn_in})" if burn_in is not None else "")
    axes[-1, 0].set_xlabel(kept)
    axes[-1, 1].set_xlabel("rank of the draw among all chains' draws (20 bins)")
    return fig
