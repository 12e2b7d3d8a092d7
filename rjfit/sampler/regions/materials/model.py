"""Free-form materials: a material label per pixel under a Potts prior, K unknown (issue 27).

The model
---------
Every labelled pixel p (the object mask's pixels and every pixel with an observation)
carries a material label z_p in {0 .. K - 1}; K, the number of materials, is unknown,
``1 <= K <= K_max`` (``max_materials``, default 8: a cap, and the fit's summary warns when
posterior mass sits on it). Every label is in use: no state has an empty material.

- Prior of the partition S that z induces: a Gibbs distribution over partitions,
  ``pi(S) ~ rho^K(S) exp(-beta B(S))``, B(S) the number of 4-neighbour pairs of labelled
  pixels with different materials. Its normaliser is one number for fixed (beta, rho), so
  every acceptance ratio is exact without it. The labelled state z has density
  ``pi(S(z)) / K!`` (the K! labellings of a partition;
  :class:`~rjfit.sampler.regions.materials.layout.PottsPrior`).
- Each material k has its own parameters ``theta_k = (I0, kd, gamma, sigma^2)``, drawn iid
  from the fit's region prior (:func:`rjfit.sampler.priors.make_prior`), shared by every
  pixel that carries it, connected or not.
- beta and rho are fixed: ``beta = 3`` per neighbour pair by default and, in a fit, ``rho = 0.01``
  (:data:`rjfit.pipeline.options.PLAIN_POTTS_RHO`; this class's own default, 1, is the neutral
  prior the exactness tests use). Why beta:
  beta must lie above the critical coupling of the K_max-state Potts model on the square
  lattice, ``log(1 + sqrt(K_max))`` (1.34 for K_max = 8). Below it the prior's mass lies on
  labellings scattered pixel by pixel, which with K free means K_max "twins" of one paint
  (measured at beta 1: K = K_max on every synthetic layout; ``validation/materials.py``,
  docs/results/materials.md). Of beta 1, 2, 3 measured on four rendered layouts, 3 is the smallest
  at which extra materials of one or two boundary pixels did not take a tenth of the
  posterior on any of them; the measured preset's mask rule gives 2.8 to 3.5 on real masks.
  rho = 0.01: each further material has prior odds 1:100, so it needs a decisive Bayes factor
  (at 1, materials of one pixel fitting its noise held up to a fifth of a layout's posterior).
- Observations enter through the change-point model's likelihood (likelihood power zeta,
  known noise scales): materials are regions.

The moves of one iteration (after the kernel's within-region moves, which serve materials
unchanged), in order:

1. ``sweeps`` checkerboard Gibbs sweeps of the labels over the K existing materials, no
   material emptied (:mod:`rjfit.sampler.regions.materials.label_gibbs`);
2. ``cluster.moves`` Swendsen-Wang-cut cluster moves: a cluster of one label, grown by
   data-driven bonds, moved to another label or to a NEW material (a birth), a whole
   material moved (a death) (:mod:`rjfit.sampler.regions.materials.cluster_swc`);
3. ``component_moves`` component moves: the cluster move with bonds that ignore the data (Swendsen and Wang's
   ``1 - exp(-beta)`` on every edge of one label), so that a connected piece of a material is moved whole
   (:mod:`rjfit.sampler.regions.materials.component_move`): what removes a start's pieces of another appearance
   from a paint's material;
4. ``segments.moves`` segment moves: a region of the image drawn from a fixed, data-driven
   family (the nodes of a Ward hierarchy of superpixels,
   :mod:`rjfit.sampler.regions.materials.segments`), when all of it carries one material,
   moved to another material or to a NEW one (:mod:`rjfit.sampler.regions.materials.segment_move`):
   what proposes a compact region of a second paint whose per-pixel features are too noisy
   for the bonds to follow its outline (measured stacks);
5. ``merge_split.moves`` merges of two whole materials and their reverse, splits of one by
   sequential allocation guided by a deterministic 2-means of its pixels (with ``jumps``;
   :mod:`rjfit.sampler.regions.materials.merge_split`): what removes twins (two materials of one paint)
   and separates a second paint hidden in a material;
6. ``merge_split.spatial_moves`` spatial splits of one material into the two halves of its pixels' positions, and
   their reverse (with ``jumps``; the same module): what separates two paints side by side that no per-pixel
   feature tells apart (pixels of one or two observations);
7. ``scatter_moves`` scatter moves (with ``jumps``): a whole material dissolved into the others pixel by pixel, and
   its reverse, a material born of pixels anywhere (:mod:`rjfit.sampler.regions.materials.scatter_move`): what
   removes a material of a few scattered pieces.

With ``edge_power`` > 0 the target also holds an edge term, a boundary's fit to the data's
step (:mod:`rjfit.sampler.regions.materials.edges`), which every label move and parameter move holds.

Each leaves the posterior invariant on its own. The kernel's annealed warm-up tempers the
likelihood for these moves as for change points. Start: K0 given (a fit's chains are
stratified over 1 .. min(4, K_max), with the edge term all at min(4, K_max):
:meth:`MaterialRegions.start_materials`) or uniform on
1 .. min(4, K_max), labels from a k-means (seeded by the chain's generator) of the per-pixel
features the bonds use; parameters as the change-point start draws them.

A joint colour fit (``--channel rgb``, :mod:`rjfit.sampler.colour`): a material owns one
theta row per channel sharing its gamma (one statistics row per channel, the observation
labels are rows ``k C + c``); the label moves sum the channels per pixel and see a pixel
set as C statistics rows at one gamma, so this module is unchanged.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rjfit.sampler.moves.base import Scheduled
from rjfit.sampler.moves.region_proposals import RegionProposalSettings
from rjfit.sampler.regions.base import RegionModel
from rjfit.sampler.regions.materials.cluster_swc import ClusterSettings
from rjfit.sampler.regions.materials.edges import EDGE_GAP, edge_term, start_theta
from rjfit.sampler.regions.materials.edge_noise import valid_noise
from rjfit.sampler.regions.materials.layout import (
    MaterialLabels,
    PottsPrior,
    bond_probabilities,
    kmeans_labels,
    labelled_pixels,
    majority_labels,
)
from rjfit.sampler.regions.materials.merge_split import MergeSplitSettings
from rjfit.sampler.regions.materials.moves import (ClusterMove, ComponentMove, LabelSweep, MergeSplit, ScatterMove,
                                                  SegmentMove, SpatialMergeSplit)
from rjfit.sampler.regions.materials.segment_move import SegmentSettings
from rjfit.sampler.regions.materials.segments import segment_family

#: the starts' numbers of materials range over 1 .. this (at most K_max)
START_MATERIALS = 4

__all__ = ["MaterialRegions"]


@dataclass(frozen=True)
class MaterialRegions(RegionModel):
    """Regions as free-form materials under a Potts prior, with the settings of their moves.

    Attributes
    ----------
    max_materials : int
        K_max, the most materials a state may have (flat option ``max_materials``).
    potts : PottsPrior
        beta (``potts_beta``) and rho (``potts_rho``).
    update_labels, jumps : bool
        Whether labels move (sweeps and cluster moves) and whether materials are born and
        die (False: K fixed at the start's).
    sweeps : int
        Gibbs sweeps per iteration.
    cluster : ClusterSettings
        Of the cluster moves (and their bonds).
    segments : SegmentSettings
        Of the segment moves (and their family of candidate sets).
    merge_split : MergeSplitSettings
        Of the merge/split moves of whole materials (made only with ``jumps``).
    proposals : RegionProposalSettings
        Of the proposals of a born (dying) material's parameters.
    edge_power : float or 'auto'
        The power of the target's edge term (:mod:`rjfit.sampler.regions.materials.edges`; flat option
        ``edge_power``); 'auto': the coarsening rule on the data's differences
        (:func:`~rjfit.sampler.regions.materials.edges.edge_term`); 0 (the default): no edge term, the model above.
    edge_gap : int
        How far apart (px, odd) the pixels of the edge term's pairs lie
        (:data:`rjfit.sampler.regions.materials.edges.EDGE_GAP`; 1 on the exactness tests' tiny images).
    component_moves : int
        Component moves per iteration (:mod:`rjfit.sampler.regions.materials.component_move`: a connected piece
        of a material moved whole; flat option ``component_moves``; 0, the default: none).
    scatter_moves : int
        Scatter moves per iteration (with ``jumps``; :mod:`rjfit.sampler.regions.materials.scatter_move`: a whole
        material dissolved into the others pixel by pixel, and its reverse; flat option ``scatter_moves``; 0, the
        default: none).
    edge_gain_sd : float or 'auto'
        tau, the sd of the local gain the edge term integrates out of each pair (flat option ``edge_gain_sd``;
        :mod:`rjfit.sampler.regions.materials.edges`, "The local gain"); 'auto': measured on the data
        (:func:`~rjfit.sampler.regions.materials.edges.shared_gain_sd`); 0 (the default): none.
    edge_noise : str or tuple
        'constant' (the default): the edge term's differences on one scale per channel; 'measured': each match's
        variance measured on the data, or its coefficients ``(white, shading, turn)`` as measured once for a fit
        (flat option ``edge_noise``; :mod:`rjfit.sampler.regions.materials.edges`, "The differences' noise").
    """

    max_materials: int = 8
    potts: PottsPrior = field(default_factory=PottsPrior)
    update_labels: bool = True
    jumps: bool = True
    sweeps: int = 1
    cluster: ClusterSettings = field(default_factory=ClusterSettings)
    segments: SegmentSettings = field(default_factory=SegmentSettings)
    merge_split: MergeSplitSettings = field(default_factory=MergeSplitSettings)
    proposals: RegionProposalSettings = field(default_factory=RegionProposalSettings)
    edge_power: float | str = 0.0
    edge_gap: int = EDGE_GAP
    edge_gain_sd: float | str = 0.0
    edge_noise: str | tuple = "constant"
    component_moves: int = 0
    scatter_moves: int = 0

    key_names = ("n_materials",)

    def __post_init__(self):
        if not 1 <= self.max_materials <= 127:
            raise ValueError(f"max_materials (--max-materials) must lie in 1 .. 127, got {self.max_materials}")
        if not (self.potts.beta >= 0 and self.potts.rho > 0):
            raise ValueError(f"potts beta must be >= 0 and rho > 0, got {self.potts.beta}, {self.potts.rho}")
        if self.sweeps < 0 or self.component_moves < 0 or self.scatter_moves < 0:
            raise ValueError(f"sweeps, component and scatter moves must be >= 0, got {self.sweeps}, "
                             f"{self.component_moves}, {self.scatter_moves}")
        if self.edge_power != "auto" and not (isinstance(self.edge_power, (int, float)) and
                                              np.isfinite(self.edge_power) and self.edge_power >= 0):
            raise ValueError(f"edge power (--edge-power) must be a number >= 0 or 'auto', got {self.edge_power!r}")
        if self.edge_gain_sd != "auto" and not (isinstance(self.edge_gain_sd, (int, float)) and
                                                np.isfinite(self.edge_gain_sd) and self.edge_gain_sd >= 0):
            raise ValueError(f"the edge term's gain sd (--edge-gain-sd) must be a number >= 0 or 'auto', got "
                             f"{self.edge_gain_sd!r}")
        if not valid_noise(self.edge_noise):
            raise ValueError(f"the edge term's noise (--edge-noise) must be 'constant', 'measured' or three "
                             f"coefficients >= 0 (white > 0), got {self.edge_noise!r}")

    @property
    def has_edge_term(self) -> bool:
        return self.edge_power == "auto" or self.edge_power > 0

    @property
    def max_regions(self) -> int:
        return self.max_materials

    def shared_start(self, problem, edges=None) -> dict:
        """``{"bonds": ...}``: the bonds, the segment family and the edge term, which depend on the data and the
        settings only. A fit builds them once for all its chains (on a 1024 x 1024 stack they took minutes and
        gigabytes per chain, 2026-11-28). ``edges``: :meth:`data_bonds`'."""
        return {"bonds": self.data_bonds(problem, edges)}

    def data_bonds(self, problem, edges=None):
        """The bonds of ``problem`` with the segment family and the edge term where this model samples them;
        ``edges``: the edge term of ``problem`` already built with this model's settings (the fit's measurement of
        them: :func:`rjfit.pipeline.fit_power.edge_settings`), taken instead of building it again.

        Raises
        ------
        ValueError
            If ``edges`` was built with other settings than this model's.
        """
        bonds = bond_probabilities(problem, self.cluster.q_max(self.potts.beta), self.cluster.bond_tau)
        labelled = labelled_pixels(problem)
        if self.segments.moves and self.update_labels:
            bonds = bonds._replace(segments=segment_family(bonds.features, labelled, self.segments.superpixel_size,
                                                           self.segments.max_regions))
        if self.has_edge_term and edges is not None:
            if not self.built_with(edges):
                raise ValueError(f"the edge term given was built with power {edges.power}, gain sd {edges.gain_sd} "
                                 f"and noise {edges.noise}, not the model's {self.edge_power}, "
                                 f"{self.edge_gain_sd} and {self.edge_noise}")
            bonds = bonds._replace(edges=edges)
        elif self.has_edge_term:
            bonds = bonds._replace(edges=edge_term(problem, labelled, self.edge_power, self.edge_gap,
                                                   self.edge_gain_sd, self.edge_noise))
        return bonds

    def built_with(self, edges) -> bool:
        """Whether the edge term ``edges`` has this model's settings (gap, and power, gain and noise as numbers:
        measured)."""
        noise = None if isinstance(self.edge_noise, str) and self.edge_noise == "constant" else self.edge_noise
        return (edges.gap == self.edge_gap and not isinstance(self.edge_power, str)
                and edges.power == float(self.edge_power)
                and not isinstance(self.edge_gain_sd, str) and edges.gain_sd == float(self.edge_gain_sd)
                and (edges.noise is None if noise is None else
                     not isinstance(noise, str) and edges.noise == tuple(float(c) for c in noise)))

    def initial_layout(self, problem, rng, *, n_materials=None, pixel_labels=None, bonds=None) -> MaterialLabels:
        """A dispersed start: ``pixel_labels`` (H, W) if given, else a k-means of ``n_materials`` clusters.

        The default ``n_materials`` is uniform on 1 .. min(4, max_materials); the k-means
        clusters the per-pixel features of the bonds, from centres drawn from ``rng``. ``bonds``:
        :meth:`data_bonds` of this problem and model, built once for every chain (:meth:`shared_start`);
        default: built here.

        Raises
        ------
        ValueError
            If the start has more materials than ``max_materials`` or the labelled pixels,
            or ``pixel_labels`` has another shape, leaves a labelled pixel without a label
            or a label 0 .. K - 1 unused.
        """
        bonds = self.data_bonds(problem) if bonds is None else bonds
        labelled = labelled_pixels(problem)
        if pixel_labels is not None:
            pixel_labels = np.asarray(pixel_labels)
            if pixel_labels.shape != labelled.shape or np.any(pixel_labels[labelled] < 0):
                raise ValueError(f"start pixel_labels must give every labelled pixel a material >= 0 "
                                 f"(shape {labelled.shape})")
            pixels = np.where(labelled, pixel_labels, -1).astype(np.int8)
            n_materials = int(pixels.max()) + 1
            if np.any(np.bincount(pixels[labelled], minlength=n_materials) == 0):
                raise ValueError("start pixel_labels leave a material 0 .. K - 1 without a pixel")
        else:
            if n_materials is None:
                n_materials = int(rng.integers(1, min(START_MATERIALS, self.max_materials) + 1))
            n_materials = min(int(n_materials), int(labelled.sum()))
            pixels = np.full(labelled.shape, -1, np.int8)
            pixels[labelled] = kmeans_labels(bonds.features[labelled.ravel()], n_materials, rng)
            compact, kept = majority_labels(pixels, n_materials)      # compact, as the Potts prior likes
            if kept == n_materials:     # the start's K is its own (a fixed-K chain cannot regain a lost one)
                pixels = compact
        if n_materials > self.max_materials:
            raise ValueError(f"start has {n_materials} materials, more than max_materials={self.max_materials}")
        return MaterialLabels(pixels, int(n_materials), bonds)

    @staticmethod
    def start_materials(chain: int, max_materials: int, *, edge_term: bool = False) -> int:
        """K0 of chain ``chain`` in a fit: stratified, 1, 2, 3, 4, 1, ...; with the edge term every chain at 4 (at
        most ``max_materials``).

        Why 4 with the edge term: there a boundary that the data do not step at costs, so a chain sheds a start's
        surplus materials within its first iterations (merges, label sweeps), while a material it never had must
        be proposed whole by a split or cluster move, which on a large image is rare. From K0 = 1 or 2 the chains
        lost psm-rock's pebble at seeds 1 and 2 (2 of 4 chains held it); from 4, each from its own k-means, 3 of 4
        held it, and the ball's chains still shed every shading part of their starts
        (docs/results/2026-11-28-trend-cost.md).
        """
        if edge_term:
            return min(START_MATERIALS, max_materials)
        return 1 + chain % min(START_MATERIALS, max_materials)

    def log_prior(self, problem, layout) -> float:
        return self.potts.log_density(layout.pixels, layout.n_materials)

    def edge_term(self, layout):
        return layout.bonds.edges

    def start_theta(self, problem, layout, prior):
        """With the edge term, each start material's least-squares fit (:func:`rjfit.sampler.regions.materials.edges.start_theta`)."""
        return start_theta(problem, layout.pixels, layout.n_materials, prior) if layout.bonds.edges is not None \
            else None

    def schedule(self) -> list:
        """Label sweeps, cluster moves, component moves, segment moves, then (with jumps) merges and splits, and
        spatial ones, each so many times."""
        if not self.update_labels:
            return []
        return [Scheduled(LabelSweep(self.potts), times=self.sweeps),
                Scheduled(ClusterMove(self.cluster, self.proposals, self.potts, self.max_materials, self.jumps),
                          times=self.cluster.moves),
                Scheduled(ComponentMove(self.cluster.new_prob, self.proposals, self.potts, self.max_materials,
                                        self.jumps), times=self.component_moves),
                Scheduled(SegmentMove(self.cluster.new_prob, self.proposals, self.potts, self.max_materials,
                                      self.jumps), times=self.segments.moves),
                Scheduled(MergeSplit(self.merge_split, self.proposals, self.potts, self.max_materials),
                          times=self.merge_split.moves if self.jumps else 0),
                Scheduled(SpatialMergeSplit(self.merge_split, self.proposals, self.potts, self.max_materials),
                          times=self.merge_split.spatial_moves if self.jumps else 0),
                Scheduled(ScatterMove(self.proposals, self.potts, self.max_materials),
                          times=self.scatter_moves if self.jumps else 0)]

    def snapshot(self, layout) -> dict:
        return {"material_labels": np.where(layout.pixels >= 0, layout.pixels, np.nan).astype(np.float32)}

    def snapshot_shapes(self, problem) -> dict:
        return {"material_labels": tuple(problem.image_shape)}
