"""Chain state, sampler configuration and per-step info (kept apart, BlackJAX style).

The state (:class:`ChainState`) is a frozen dataclass whose arrays the kernel never writes
to: a step builds new arrays for what it changes. Its ``layout`` is the region model's
structure (for change points :class:`~rjfit.sampler.regions.changepoints.grid.Changepoints`,
the u and v vectors); ``labels`` (region per observation), ``stats`` and ``log_lik`` are
functions of the layout and the parameters cached for speed;
:func:`rjfit.sampler.kernel.refresh` recomputes them from scratch. During a step the kernel
and the moves work on a mutable copy (:class:`Work`) that never outlives the step.

The configuration (:class:`SamplerConfig`) is composed of the settings each part owns: the
region model with its structure moves' settings (``regions``), the within-region moves'
(``within``) and the kernel's own (``kernel``: burn-in, annealing, refresh).
:meth:`SamplerConfig.from_flat` builds it from the flat option names the pipeline uses
(:data:`FLAT_OPTIONS` says where each one lives).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from rjfit.sampler.likelihood import RegionData
from rjfit.sampler.moves.effects import EffectSettings
from rjfit.sampler.moves.within import WithinSettings
from rjfit.sampler.regions.base import RegionModel
from rjfit.sampler.regions.changepoints import ChangepointRegions
from rjfit.sampler.regions.materials import MaterialRegions

__all__ = ["ChainState", "Work", "StepInfo", "KernelSettings", "SamplerConfig", "FLAT_OPTIONS", "REGION_MODELS",
           "flat_option_applies"]


@dataclass(frozen=True, eq=False)
class ChainState:
    """One state of a chain.

    Attributes
    ----------
    layout : object
        The region model's structure (change points: ``Changepoints(u, v)``, each row of u
        sorted, vector k = k-th order statistic of every row). It has ``n_regions``,
        ``model_key`` and ``labels(problem)``.
    theta : ndarray (R, 4)
        Region parameters ``(I0, kd, gamma, sigma2)``.
    stats : ndarray (R, 7)
        Sufficient statistics of each region (see :mod:`rjfit.sampler.likelihood`).
    log_lik : ndarray (R,)
        Log-likelihood of each region.
    labels : ndarray (N,)
        Region of each observation.
    log_g_scale : float
        Log of the global multiplier of the gamma random-walk width (adapted in burn-in only).
    iteration : int
        Number of completed steps.
    effects : EffectState or None
        The effect parameters of a problem with effects (:mod:`rjfit.sampler.moves.effects`);
        None for the plain model. ``stats`` and ``log_lik`` are then those of the problem
        transformed at its parameters.
    normals : NormalState or None
        The pixels' sampled normals of a problem that samples them (:mod:`rjfit.sampler.normals`);
        None where the normals are the given ones. ``stats`` and ``log_lik`` are then those of
        the problem at these normals.
    """

    layout: object
    theta: np.ndarray
    stats: np.ndarray
    log_lik: np.ndarray
    labels: np.ndarray
    log_g_scale: float = 0.0
    iteration: int = 0
    effects: object = None
    normals: object = None

    @property
    def n_regions(self) -> int:
        return int(self.theta.shape[0])

    @property
    def total_log_lik(self) -> float:
        return float(np.sum(self.log_lik))


@dataclass
class Work:
    """Mutable working copy of a state during one step (never shared across steps).

    ``region_index`` maps a region to its :class:`~rjfit.sampler.likelihood.RegionData`
    (its observations as runs of the problem's arrays) for the current ``labels``; it is
    filled on first use, and dropped whenever the labels change. ``labels_owned`` says
    whether ``labels`` is this step's own array (else it is the state's and must be copied
    before an in-place change). ``pixel_sets`` is the chain's memo of pixel sets'
    observations (:class:`~rjfit.sampler.pixel_sets.PixelSets`; None: none kept). ``edges``:
    the region model's edge term in the target (:meth:`RegionModel.edge_term`), which the
    parameter moves' ratios hold (:func:`rjfit.sampler.moves.region_terms.edge_delta`), with the chain's memo of its
    sums (``edge_memo``: :class:`~rjfit.sampler.regions.materials.edge_memo.BoundaryMemo`; the same values without).
    """

    layout: object
    theta: np.ndarray
    stats: np.ndarray
    log_lik: np.ndarray
    labels: np.ndarray
    labels_owned: bool = False
    region_index: dict | None = None  # region -> RegionData, valid for ``labels``
    pixel_sets: object = None
    edges: object = None    # the material model's EdgeTerm (rjfit.sampler.regions.materials.edges); None: no edge term
    edge_memo: object = None  # the chain's BoundaryMemo of the edge term's sums (edge_memo.py); None: summed afresh

    def region_data(self, r: int, problem):
        """:class:`RegionData` of region r; every region's runs come from one read of the labels, once per labelling."""
        if self.region_index is None:
            self.region_index = {}
        if not self.region_index:     # filled in place: the chain's context keeps this dict per labelling
            self.region_index.update(enumerate(RegionData.split(problem, self.labels, self.theta.shape[0])))
        return self.region_index[r]

    def take(self, proposal) -> None:
        """Make an accepted :class:`~rjfit.sampler.moves.proposal.Proposal` the current state (its arrays copied)."""
        self.layout = proposal.layout
        self.theta = proposal.theta.copy()
        self.stats = proposal.stats.copy()
        self.log_lik = np.array(proposal.log_lik, float)
        self.labels = proposal.labels
        self.labels_owned = True
        self.region_index = None


@dataclass
class StepInfo:
    """What happened in one step (acceptance counts per move kind); not part of the state.

    ``nan_rejected`` counts, per move kind, the proposals whose log acceptance ratio was NaN
    (a density that could not be evaluated): each is a rejection
    (:func:`rjfit.sampler.moves.accept.accept`), counted here so that it is seen.
    """

    accepted: dict = field(default_factory=dict)
    proposed: dict = field(default_factory=dict)
    nan_rejected: dict = field(default_factory=dict)
    jump: str = ""

    def count(self, kind: str, accepted, proposed=1):
        n_accepted = int(accepted) if isinstance(accepted, (bool, int, np.bool_)) else int(np.sum(accepted))
        self.accepted[kind] = self.accepted.get(kind, 0) + n_accepted
        self.proposed[kind] = self.proposed.get(kind, 0) + int(proposed)

    def count_nan(self, kind: str, n: int = 1):
        self.nan_rejected[kind] = self.nan_rejected.get(kind, 0) + int(n)


@dataclass(frozen=True)
class KernelSettings:
    """The kernel's own settings.

    Attributes
    ----------
    burn_in : int
        Iterations during which the gamma step adapts (0: no adaptation).
    anneal : int
        Iterations of tempered warm-up at the start of the burn-in (0: none): the
        likelihood power is multiplied by ``anneal_start ** (1 - t / anneal)`` at iteration
        t (:func:`rjfit.sampler.kernel.anneal_power`). Must not exceed ``burn_in``.
    anneal_start : float
        Factor on the likelihood power at the first iteration of the warm-up.
    refresh_every : int
        Recompute the cached statistics from scratch every so many iterations (bounds
        floating-point drift of the incremental updates; 0: never).
    """

    burn_in: int = 0
    anneal: int = 0
    anneal_start: float = 1e-3
    refresh_every: int = 200

    def __post_init__(self):
        if self.anneal < 0 or self.anneal > max(self.burn_in, 0):
            raise ValueError(f"anneal ({self.anneal}) must lie in [0, burn_in = {self.burn_in}]: "
                             "only burn-in iterations may be tempered")
        if not 0.0 < self.anneal_start <= 1.0:
            raise ValueError(f"anneal_start must lie in (0, 1], got {self.anneal_start}")


#: The region models :meth:`SamplerConfig.from_flat` builds, by name (``rjfit fit --regions``).
REGION_MODELS = {"changepoints": ChangepointRegions, "materials": MaterialRegions}

#: Where each flat option of :meth:`SamplerConfig.from_flat` lives: a path of attributes
#: from the config (one option may set several places). The settings classes document them.
FLAT_OPTIONS = {
    "max_u": ["regions.max_u"], "max_v": ["regions.max_v"],
    "cp_prior": ["regions.prior.kind"], "cp_smooth_sd": ["regions.prior.smooth_sd"],
    "update_changepoints": ["regions.update_changepoints"], "jumps": ["regions.jumps"],
    "cp_step": ["regions.sweep.step"], "cp_uniform_prob": ["regions.sweep.uniform_prob"],
    "cp_neighbour_prob": ["regions.sweep.neighbour_prob"], "cp_neighbour_sd": ["regions.sweep.neighbour_sd"],
    "block_prob": ["regions.block.prob"], "block_max": ["regions.block.max_lines"],
    "block_shift_sd": ["regions.block.shift_sd"],
    "vector_prob": ["regions.vector.prob"],
    "jump_prob": ["regions.birth_death.prob"], "free_jump_prob": ["regions.birth_death.free_prob"],
    "split_map": ["regions.birth_death.split_map"], "drop_jacobian": ["regions.birth_death.drop_jacobian"],
    "split_scale": ["regions.birth_death.split_scale"],
    "birth_straight_prob": ["regions.birth_death.straight_prob"],
    "birth_straight_sd": ["regions.birth_death.straight_sd"],
    "birth_gamma_inflation": ["regions.proposals.gamma_inflation"],
    # the same threshold in both places: conditional proposals need a well-posed sigma^2 shape
    "min_obs_conditional": ["within.min_obs_conditional", "regions.proposals.min_obs"],
    "sampler": ["within.sampler"], "gamma_move": ["within.gamma_move"], "newton_scale": ["within.newton_scale"],
    "g_moves": ["within.g_moves"], "target_accept": ["within.target_accept"],
    "fallback_step": ["within.fallback_step"], "small_region_obs": ["within.small_region_obs"],
    "full_recompute": ["within.full_recompute"],
    # the material region model's (region_model="materials")
    "max_materials": ["regions.max_materials"], "potts_beta": ["regions.potts.beta"],
    "potts_rho": ["regions.potts.rho"], "update_labels": ["regions.update_labels"],
    "label_sweeps": ["regions.sweeps"], "cluster_moves": ["regions.cluster.moves"],
    "cluster_new_prob": ["regions.cluster.new_prob"], "cluster_material_seed": ["regions.cluster.material_seed"],
    "segment_moves": ["regions.segments.moves"], "merge_split_moves": ["regions.merge_split.moves"],
    "spatial_split_moves": ["regions.merge_split.spatial_moves"],
    "edge_power": ["regions.edge_power"], "edge_gap": ["regions.edge_gap"],
    "edge_gain_sd": ["regions.edge_gain_sd"], "edge_noise": ["regions.edge_noise"],
    "component_moves": ["regions.component_moves"], "scatter_moves": ["regions.scatter_moves"],
    "burn_in": ["kernel.burn_in"], "anneal": ["kernel.anneal"], "anneal_start": ["kernel.anneal_start"],
    "refresh_every": ["kernel.refresh_every"],
    "effect_every": ["effects.every"], "effect_target_accept": ["effects.target_accept"],
    "effect_curvature_every": ["effects.curvature_every"], "effect_jitter": ["effects.jitter"],
}


@dataclass(frozen=True)
class SamplerConfig:
    """How the kernel moves: the region model (with its structure moves' settings), the within-region moves, the kernel.

    Attributes
    ----------
    regions : RegionModel
        What partitions the pixels into regions, and its structure moves; default the
        paper's change points (:class:`~rjfit.sampler.regions.changepoints.ChangepointRegions`).
    within : WithinSettings
        The within-region moves (:mod:`rjfit.sampler.moves.within`).
    kernel : KernelSettings
        Burn-in, annealed warm-up, refresh of the cached statistics.
    effects : EffectSettings
        The effect move (:mod:`rjfit.sampler.moves.effects`), for a problem with effects.
    """

    regions: RegionModel = field(default_factory=ChangepointRegions)
    within: WithinSettings = field(default_factory=WithinSettings)
    kernel: KernelSettings = field(default_factory=KernelSettings)
    effects: EffectSettings = field(default_factory=EffectSettings)

    def __post_init__(self):
        if getattr(self.regions, "has_edge_term", False) and self.within.sampler != "adaptive":
            raise ValueError("the edge term (--edge-power) is held by the 'adaptive' within-region moves only; "
                             "give --edge-power 0 with the paper's sampler")

    @classmethod
    def from_flat(cls, region_model="changepoints", **options) -> SamplerConfig:
        """The config from flat option names (``max_u=2, sampler='paper', burn_in=500, ...``; see :data:`FLAT_OPTIONS`).

        ``region_model``: a name of :data:`REGION_MODELS` ('changepoints', the paper's and the
        default, or 'materials', :class:`~rjfit.sampler.regions.materials.MaterialRegions`) or a
        :class:`~rjfit.sampler.regions.base.RegionModel` class, built with its defaults. Options
        left out keep their settings' defaults.

        Raises
        ------
        TypeError
            For an option name that is not in :data:`FLAT_OPTIONS`, or one of another
            region model's.
        ValueError
            For a value a settings class rejects, or an unknown ``region_model``.
        """
        unknown = sorted(set(options) - set(FLAT_OPTIONS))
        if unknown:
            raise TypeError(f"unknown sampler option(s) {', '.join(unknown)}: choose from {', '.join(FLAT_OPTIONS)}")
        model = _region_model(region_model)
        if model is None:
            raise ValueError(f"unknown region model {region_model!r}: choose one of {', '.join(REGION_MODELS)}")
        base = cls(regions=model())
        changes: dict = {}
        for name, value in options.items():
            paths = [path for path in FLAT_OPTIONS[name] if _has_path(base, path)]
            if not paths:
                raise TypeError(f"sampler option {name} does not apply to the {region_model} region model")
            for path in paths:
                node = changes
                *parents, leaf = path.split(".")
                for part in parents:
                    node = node.setdefault(part, {})
                node[leaf] = value
        return _apply(base, changes)


def flat_option_applies(name: str, region_model="changepoints") -> bool:
    """Whether :meth:`SamplerConfig.from_flat` takes the flat option ``name`` for ``region_model`` (a name or a
    RegionModel class; False for names that are not flat options, and for another region model's options)."""
    model = _region_model(region_model)
    if name not in FLAT_OPTIONS or model is None:
        return False
    base = SamplerConfig(regions=model())
    return any(_has_path(base, path) for path in FLAT_OPTIONS[name])


def _region_model(region_model):
    """The RegionModel class of a name of :data:`REGION_MODELS` or a class (None: an unknown name)."""
    return REGION_MODELS.get(region_model) if isinstance(region_model, str) else region_model


def _has_path(obj, path: str) -> bool:
    for part in path.split("."):
        if not hasattr(obj, part):
            return False
        obj = getattr(obj, part)
    return True


def _apply(obj, changes: dict):
    """``obj`` with nested ``changes`` ({field: value or {subfield: ...}}) applied, each level rebuilt (and checked)."""
    updates = {}
    for name, value in changes.items():
        updates[name] = _apply(getattr(obj, name), value) if isinstance(value, dict) else value
    return replace(obj, **updates)
