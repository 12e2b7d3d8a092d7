"""The fixed region model's part of a fit (``rjfit fit --regions fixed --labels FILE``): the user's label map.

The label map is an image of the fit's size (after any crop) with an integer label per pixel:
a NumPy ``.npy`` array, an EXR (channel ``labels``, as a fit's ``labels.exr``, or its only
channel) or an integer image OpenCV reads (PNG, TIFF: one channel). Negative values (and NaN in
an EXR) mark pixels without a label; every pixel with an observation needs one. The labels
need not be 0 .. K - 1: each distinct value is one region, in increasing order of value.

Nothing but each label's BRDF parameters is sampled (:mod:`rjfit.sampler.regions.fixed`). The
summary's ``regions`` has one entry per label (``label``: its value in the file) with the
posterior of (I0, kd, gamma, sigma^2) and its pixel count; ``labels.exr`` holds the labels as
regions 0 .. K - 1; ``chains.nc`` the draws (dims chain, draw, region, parameter); the figures
(with ``figures``) the label map and the posterior mean radiance against the data.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rjfit.data.exr import read_exr
from rjfit.errors import DatasetError
from rjfit.pipeline.fit_chains import write_chains
from rjfit.pipeline.fit_settings import assemble
from rjfit.pipeline.regions.base import FitResult, RegionFit, truth_summary
from rjfit.posterior import caveats
from rjfit.posterior import summary as post
from rjfit.sampler.regions.fixed import FixedRegions
from rjfit.sampler.state import SamplerConfig

__all__ = ["FixedFit", "read_label_map"]


def read_label_map(path) -> np.ndarray:
    """The label map in ``path`` as int64 (H, W), -1 where a pixel has no label.

    Raises
    ------
    DatasetError
        If the file is missing, of no known kind, not one channel of one image, or holds a value
        that is not an integer (NaN in an EXR aside: no label).
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: no such label map (--labels)")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            values = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as error:
            raise DatasetError(f"{path}: not a readable .npy array ({error})") from None
    elif suffix == ".exr":
        channels = read_exr(path)
        if "labels" not in channels and len(channels) != 1:
            raise DatasetError(f"{path}: an EXR label map needs a channel 'labels' or a single channel, it has "
                               f"{', '.join(sorted(channels))}")
        values = channels.get("labels", next(iter(channels.values())))
    else:
        import cv2  # OpenCV reads the data sets' images too

        values = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if values is None:
            raise DatasetError(f"{path}: not a readable label map (.npy, .exr, or an image OpenCV reads)")
    values = np.asarray(values)
    if values.ndim != 2:
        raise DatasetError(f"{path}: a label map is one channel of one image (H, W), this one has shape "
                           f"{values.shape}")
    if values.dtype.kind == "f":
        labelled = np.isfinite(values)
        if np.any(values[labelled] != np.round(values[labelled])):
            raise DatasetError(f"{path}: the label map holds values that are not integers")
        return np.where(labelled, values, -1).astype(np.int64)
    if values.dtype.kind not in "iub":
        raise DatasetError(f"{path}: the label map holds {values.dtype} values, not integers")
    return values.astype(np.int64)


class FixedFit(RegionFit):
    """The user's label map held fixed: one region per label, each label's BRDF posterior."""

    name = "fixed"
    reads = frozenset({"labels"})
    noun = "label"

    @staticmethod
    def describe(summary: dict, options: dict) -> str:
        labels = options.get("labels")
        return (f"fixed: the label map {labels if labels else '(--labels)'} held fixed, "
                f"{len(summary.get('regions') or [])} labels, one BRDF per label; only the BRDFs are sampled")

    @staticmethod
    def result_rows(summary: dict) -> list:
        return [("labels (regions held fixed)", len(summary.get("regions") or []),
                 "the distinct labels of the label map, each a region with its own BRDF; the segmentation is not "
                 "sampled, so no probability of it is stated")]

    @classmethod
    def region_title(cls, region: dict, index: int) -> str:
        # the label's value in the user's file, not its index among the labels
        return f"label {region.get('label', region.get('region', index))}"

    def __init__(self, path, values: np.ndarray):
        self.path = Path(path)
        self.values = np.asarray(values)
        self.label_values = np.unique(self.values[self.values >= 0])
        # the map as regions 0 .. K - 1 (-1: no label)
        self.pixels = np.where(self.values >= 0, np.searchsorted(self.label_values, self.values), -1)

    @classmethod
    def for_fit(cls, options) -> FixedFit:
        """The label map of ``options.labels``, read (refused here, before any chain runs).

        Raises
        ------
        ValueError
            Without ``--labels``, or for a map without a label (:func:`read_label_map`'s errors).
        """
        if options.labels is None:
            raise ValueError("--regions fixed needs the label map: give --labels FILE (.npy, .exr or an image)")
        fit = cls(options.labels, read_label_map(options.labels))
        if fit.label_values.size == 0:
            raise DatasetError(f"{fit.path}: the label map gives no pixel a label (all are negative)")
        return fit

    def sampler_config(self, options, *, burn: int, fixed: bool = False, problem=None) -> SamplerConfig:
        if problem is not None:
            self._check(problem)
        return assemble(options, FixedRegions(n_labels=int(self.label_values.size)), burn)

    def _check(self, problem) -> None:
        """The map against the images: their shape, and a label for every pixel with an observation."""
        if self.pixels.shape != tuple(problem.image_shape):
            raise DatasetError(f"{self.path}: the label map is {self.pixels.shape[0]} x {self.pixels.shape[1]}, the "
                               f"fit's images {problem.height} x {problem.width} (after any crop)")
        unlabelled = np.flatnonzero((np.diff(problem.pixel_start) > 0) & (self.pixels.ravel() < 0))
        if unlabelled.size:
            row, col = divmod(int(unlabelled[0]), problem.width)
            raise DatasetError(f"{self.path}: {unlabelled.size} pixels with observations have no label (a negative "
                               f"value), the first at row {row}, column {col}; give every observed pixel a label")

    def chain_start(self, options, chain: int, start: dict, fixed_segmentation=None) -> dict:
        start.setdefault("pixel_labels", self.pixels if fixed_segmentation is None else fixed_segmentation)
        return start

    def summarise(self, records, problem, prior, config, options, run: dict, warnings: list, truth_labels,
                  observations) -> FitResult:
        burn, n_labels = config.kernel.burn_in, int(self.label_values.size)
        draws = [r.theta[burn:, :n_labels * problem.n_channels] for r in records]
        diag = post.diagnostics(draws)
        regions = [{**entry, "label": int(value)}
                   for entry, value in zip(post.region_summaries(draws, self.pixels), self.label_values)]
        summary = {"regions": regions, "rhat_max": diag["rhat_max"], "rhat_reason": diag["rhat_reason"],
                   "ess_min": min(diag["ess_bulk_min"], diag["ess_tail_min"]),
                   "ess_bulk_min": diag["ess_bulk_min"], "ess_tail_min": diag["ess_tail_min"], "diagnostics": diag}
        summary.update(run)
        observed = np.zeros(problem.height * problem.width, bool)
        observed[problem.pixel] = True
        # one model in every draw: the chains cannot disagree on it
        summary["warnings"] = (post.convergence_warnings(diag, [{}] * len(records), options.n_chains)
                               + caveats.nan_rejection_warnings(summary["acceptance_counts"])
                               + caveats.empty_region_warnings(self.pixels, observed.reshape(problem.image_shape),
                                                               n_labels)
                               + caveats.prior_range_warnings(regions, prior)
                               + caveats.support_bound_warnings(regions, prior)
                               + caveats.pooled_interval_warnings(regions) + warnings)
        if truth_labels is not None:
            summary.update(truth_summary(records, burn, self.pixels, truth_labels))
        obs_labels = config.regions.initial_layout(problem, None, pixel_labels=self.pixels).labels(problem)
        prediction = post.posterior_mean_prediction(records, burn, problem, labels_of=lambda record, snapshot, _: (
            n_labels * problem.n_channels, obs_labels))
        return FitResult(summary=summary, labels=self.pixels, prediction=prediction, problem=problem, burn=burn,
                         model=(n_labels,))

    def write_files(self, staging, result: FitResult, records, options, attributes: dict) -> None:
        """``chains.nc`` (:mod:`rjfit.posterior.inference_data`; every kept draw, the labels never change) and,
        with ``figures``, the figures."""
        burn, n_rows = result.burn, int(self.label_values.size) * result.problem.n_channels
        draws = [r.theta[burn:, :n_rows] for r in records]
        iterations = [burn + np.arange(len(d)) for d in draws]
        write_chains(staging / "chains.nc", records, result, (draws, iterations), options, attributes,
                     region_dim="region", key_names=(), pixel_labels=self.pixels,
                     about=f"region r is the r-th label of {self.path.name} in increasing order of value (summary.json "
                           f"regions[r].label); held fixed in every draw")
        if options.figures:
            from rjfit.posterior import figures as figs  # matplotlib: only when figures are drawn

            folder = staging / "figures"
            written = {"labels": figs.material_map(result.labels, folder / "labels.png"),
                       "reflectance": figs.reflectance(result.labels, result.prediction, folder / "reflectance.png")}
            result.summary["figures"] = {name: f"figures/{Path(path).name}" for name, path in written.items()}

    @staticmethod
    def printed_line(summary: dict) -> str:
        return f"{len(summary['regions'])} labels held fixed (--labels), each label's BRDF posterior"
