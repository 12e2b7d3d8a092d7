"""Running chains: recording, checkpoint/resume, several chains in parallel processes.

Every random draw of a chain comes from one ``numpy.random.Generator`` seeded from
``SeedSequence(seed).spawn(n_chains)[chain]``; the generator's bit-generator state is saved
in each checkpoint, so a chain resumed from its last checkpoint draws exactly the numbers
an uninterrupted run would have drawn and yields identical samples.

Threads: a chain runs the large passes over observations on ``threads`` Numba threads
(:mod:`rjfit.sampler.passes`); :func:`run_chains` gives each chain the cores its parallel
chains leave free. The samples do not depend on the number of threads.

Checkpoints are pickles written atomically (temporary file in the same folder, then
``os.replace``): a chain killed mid-write (even by SIGKILL) leaves the previous checkpoint
intact.
"""
from __future__ import annotations

import dataclasses
import functools
import hashlib
import os
import pickle
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from rjfit.progress import progress
from rjfit.sampler.forward import Problem
from rjfit.sampler.kernel import ChainContext, effect_log_likelihood, initial_state, log_posterior, step
from rjfit.sampler.state import ChainState, SamplerConfig

__all__ = ["ChainSpec", "ChainRecord", "ChainRecorder", "run_chain", "run_chains", "chain_rngs", "atomic_write_bytes",
           "run_fingerprint", "available_cores", "default_threads", "numba_threads", "TRUE_REGIONS_AGREEMENT"]

CHECKPOINT_VERSION = 4
TRUE_REGIONS_AGREEMENT = 0.99


@dataclass
class ChainSpec:
    """Everything a worker process needs to run (or resume) one chain (picklable)."""

    problem: Problem
    prior: object
    config: SamplerConfig
    seed: int
    chain: int
    n_chains: int
    iterations: int
    checkpoint_path: str | None = None
    checkpoint_every: int = 1000
    cp_thin: int = 10
    truth_labels: np.ndarray | None = None
    start: dict | None = None          # keyword arguments of initial_state (theta; change points: model, changepoints)
    # the region model's shared_start(problem): built once for every chain of a fit from the data and the
    # configuration alone (both in the checkpoint's fingerprint), so not fingerprinted itself
    shared: dict | None = None
    progress: bool = False
    stop_after: int | None = None      # testing: return after this many iterations (simulates a crash)


@dataclass
class ChainRecord:
    """The trace of one chain (per iteration unless noted).

    The model keys and layout snapshots are the region model's
    (:attr:`RegionModel.key_names <rjfit.sampler.regions.base.RegionModel.key_names>`,
    :meth:`~rjfit.sampler.regions.base.RegionModel.snapshot`): change points record
    ``n_u``, ``n_v`` and snapshots ``cp_u``, ``cp_v``; materials record ``n_materials`` and
    snapshots ``material_labels``; a fixed label map records neither. The other fields are None.
    """

    theta: np.ndarray               # (T, R_max, 4), NaN beyond the current model's regions
    log_lik: np.ndarray             # (T,)
    log_post: np.ndarray            # (T,)
    exact_truth: np.ndarray         # (T,) int8: 1 if object pixels fall into exactly the true regions, -1 unknown
    true_regions: np.ndarray        # (T,) int8: 1 if one region per true region, agreeing on >= 99 % of pixels; -1 unknown
    object_regions: np.ndarray      # (T,) int16: number of regions holding object pixels (with observations)
    cp_iteration: np.ndarray        # (S,) iteration of each layout snapshot
    accepted: dict
    proposed: dict
    seconds: float
    iterations_done: int
    resumed_from: tuple = ()        # iterations of the checkpoints this chain resumed from, in order
    threads: int = 1                # Numba threads it ran on (its samples do not depend on them; its seconds do)
    nan_rejected: dict = dataclasses.field(default_factory=dict)   # per move kind: proposals rejected for a NaN ratio
    n_u: np.ndarray | None = None               # (T,) int: change points
    n_v: np.ndarray | None = None
    cp_u: np.ndarray | None = None              # (S, H, max_u), NaN padded
    cp_v: np.ndarray | None = None              # (S, W, max_v), NaN padded
    n_materials: np.ndarray | None = None       # (T,) int: materials
    material_labels: np.ndarray | None = None   # (S, H, W) float32, NaN off the labelled pixels
    effects: np.ndarray | None = None           # (T, K) constrained effect parameters (EffectData.names); None: none
    # (T,) int8: 1 if the step accepted a move that changed the number of regions (rows may be renumbered
    # there), 0 if not; None: not recorded (a chain resumed from an older checkpoint records 1 before it)
    jumped: np.ndarray | None = None
    # sampled normals (--normals sample): per pixel the sums over the kept draws (after burn-in) of the tangent
    # coordinates (H W, 2) and of their squares, and the number of draws summed; None: the normals were given
    normal_sum: np.ndarray | None = None
    normal_sq: np.ndarray | None = None
    normal_draws: int = 0

    #: fields with one entry per draw, and per snapshot (what :meth:`truncated` cuts)
    PER_DRAW = ("theta", "log_lik", "log_post", "exact_truth", "true_regions", "object_regions", "n_u", "n_v",
                "n_materials", "effects", "jumped")
    PER_SNAPSHOT = ("cp_iteration", "cp_u", "cp_v", "material_labels")

    def truncated(self, t: int) -> ChainRecord:
        keep = self.cp_iteration < t
        changes = {name: getattr(self, name)[:t] for name in self.PER_DRAW if getattr(self, name) is not None}
        changes.update({name: getattr(self, name)[keep] for name in self.PER_SNAPSHOT
                        if getattr(self, name) is not None})
        return dataclasses.replace(self, **changes, accepted=dict(self.accepted), proposed=dict(self.proposed),
                                   iterations_done=min(t, self.iterations_done), nan_rejected=dict(self.nan_rejected))


def chain_rngs(seed: int, n_chains: int):
    """One independent generator per chain from a user seed."""
    return [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(n_chains)]


def atomic_write_bytes(path: str, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temporary file + fsync + os.replace; see :mod:`rjfit.io`)."""
    from rjfit.io import write_bytes_atomic

    write_bytes_atomic(path, data)


class ChainRecorder:
    """What :func:`run_chain` keeps of each draw (pickled in checkpoints); :meth:`result` is the :class:`ChainRecord`.

    The per-draw model key and the thinned layout snapshots are what the region model
    names (:attr:`~rjfit.sampler.regions.base.RegionModel.key_names`,
    :meth:`~rjfit.sampler.regions.base.RegionModel.snapshot`).
    """

    def __init__(self, spec: ChainSpec):
        problem, T = spec.problem, spec.iterations
        self.regions = spec.config.regions
        self.n_channels = problem.n_channels        # a joint colour fit records a row per material and channel
        self.r_max = self.regions.max_regions * self.n_channels
        self.keys = {name: np.zeros(T, np.int16) for name in self.regions.key_names}
        self.theta = np.full((T, self.r_max, 4), np.nan)
        self.log_lik = np.zeros(T)
        self.log_post = np.zeros(T)
        self.exact_truth = np.full(T, -1, np.int8)
        self.true_regions = np.full(T, -1, np.int8)
        self.object_regions = np.zeros(T, np.int16)
        n_snap = (T + spec.cp_thin - 1) // spec.cp_thin
        self.cp_iteration = np.arange(0, T, spec.cp_thin)[:n_snap]
        self.snapshots = {name: np.full((n_snap, *shape), np.nan, np.float32)
                          for name, shape in self.regions.snapshot_shapes(problem).items()}
        self.accepted, self.proposed, self.nan_rejected = {}, {}, {}
        self.seconds = 0.0
        self.resumed_from = ()
        self.cp_thin = spec.cp_thin
        self._exact_memo = (None, -1)
        # the effects' priors hold their transforms to the constrained values (small: checkpoints pickle them)
        self.effect_priors = None if problem.effects is None else problem.effects.priors()
        self.effects = None if problem.effects is None else np.full((T, problem.effects.n_params), np.nan)
        self.jumped = np.zeros(T, np.int8)
        self.burn_in = spec.config.kernel.burn_in
        sampled = problem.normals is not None
        self.normal_sum = np.zeros((problem.height * problem.width, 2)) if sampled else None
        self.normal_sq = np.zeros((problem.height * problem.width, 2)) if sampled else None
        self.normal_draws = 0
        self._truth_setup(spec)

    def _truth_setup(self, spec):
        problem = spec.problem
        counts = np.diff(problem.pixel_start)
        self.pixel_first_obs = problem.pixel_start[np.flatnonzero(counts > 0)]
        self.first_obs = None
        if spec.truth_labels is None:
            return
        truth = np.asarray(spec.truth_labels).ravel()
        pixels = np.flatnonzero((counts > 0) & (truth >= 0))
        self.first_obs = problem.pixel_start[pixels]
        self.truth_of_first = truth[pixels]
        self.n_truth = int(self.truth_of_first.max()) + 1 if pixels.size else 0

    def exact(self, labels) -> tuple[int, int, int]:
        """(exact-truth flag, true-regions flag, number of regions holding observed object pixels).

        The flags are -1 without truth labels. Exact: the partition of the observed object
        pixels equals the true one. True regions: one region per true region, and the
        optimal one-to-one matching agrees on at least ``TRUE_REGIONS_AGREEMENT`` of the
        observed object pixels (pixels whose few valid observations cannot tell the
        regions apart, at grazing angles, are then not required to be decided). Memoised
        per labelling.
        """
        if self._exact_memo[0] is labels:
            return self._exact_memo[1]
        memo_key = labels
        if self.n_channels > 1:       # rows (material C + channel) -> materials
            labels = labels // self.n_channels
        n_object = int(np.count_nonzero(np.bincount(labels[self.pixel_first_obs])))
        exact, true_regions = -1, -1
        if self.first_obs is not None:
            lab = labels[self.first_obs].astype(np.int64)    # labels are int8: no overflow below
            n_lab = int(lab.max()) + 1
            confusion = np.bincount(lab * max(self.n_truth, 1) + self.truth_of_first,
                                    minlength=n_lab * max(self.n_truth, 1)).reshape(n_lab, -1)
            held = confusion[confusion.sum(axis=1) > 0]
            exact = int(held.shape[0] == self.n_truth and np.all(np.count_nonzero(held, axis=1) == 1)
                        and np.all(np.count_nonzero(held, axis=0) == 1))
            true_regions = 0
            if held.shape[0] == self.n_truth:
                rows, cols = linear_sum_assignment(-held)
                true_regions = int(held[rows, cols].sum() >= TRUE_REGIONS_AGREEMENT * lab.size)
        self._exact_memo = (memo_key, (exact, true_regions, n_object))
        return exact, true_regions, n_object

    def record(self, t: int, state: ChainState, log_post: float, log_lik_constant: float = 0.0,
               jumped: bool = True):
        """Store draw ``t``; ``log_lik_constant`` (the Problem's known-noise-scale term) is added
        to the recorded log-likelihood and log-posterior, so they are the full densities;
        ``jumped``: whether the step that made it changed the number of regions
        (:attr:`StepInfo.jump <rjfit.sampler.state.StepInfo>`)."""
        for name, value in zip(self.regions.key_names, state.layout.model_key):
            self.keys[name][t] = value
        self.jumped[t] = bool(jumped)
        self.theta[t, :state.n_regions] = state.theta
        self.log_lik[t] = state.total_log_lik + log_lik_constant
        self.log_post[t] = log_post + log_lik_constant
        self.exact_truth[t], self.true_regions[t], self.object_regions[t] = self.exact(state.labels)
        if state.effects is not None:
            self.effects[t] = [float(prior.to_constrained(z)) for prior, z in zip(self.effect_priors, state.effects.z)]
        if state.normals is not None and t >= self.burn_in:
            self.normal_sum += state.normals.d
            self.normal_sq += state.normals.d * state.normals.d
            self.normal_draws += 1
        if t % self.cp_thin == 0:
            s = t // self.cp_thin
            for name, values in self.regions.snapshot(state.layout).items():
                self.snapshots[name][s][tuple(slice(0, n) for n in values.shape)] = values

    def add_counts(self, info) -> None:
        """Add one step's acceptance and NaN-rejection counts (:class:`~rjfit.sampler.state.StepInfo`)."""
        for key, value in info.accepted.items():
            self.accepted[key] = self.accepted.get(key, 0) + value
            self.proposed[key] = self.proposed.get(key, 0) + info.proposed[key]
        for key, value in info.nan_rejected.items():
            self.nan_rejected[key] = self.nan_rejected.get(key, 0) + value

    def result(self, done: int) -> ChainRecord:
        rec = ChainRecord(theta=self.theta, log_lik=self.log_lik, log_post=self.log_post, exact_truth=self.exact_truth,
                          true_regions=self.true_regions, object_regions=self.object_regions,
                          cp_iteration=self.cp_iteration, accepted=self.accepted, proposed=self.proposed,
                          seconds=self.seconds, iterations_done=done, resumed_from=tuple(self.resumed_from),
                          nan_rejected=self.nan_rejected, effects=self.effects, jumped=self.jumped,
                          normal_sum=self.normal_sum, normal_sq=self.normal_sq, normal_draws=self.normal_draws,
                          **self.keys, **self.snapshots)
        return rec.truncated(done)


def _as_bytes(part) -> bytes:
    """A value's content as bytes: arrays by their data and floats exactly, never by repr.

    (An array's repr elides its middle, and NumPy's print options, which any code may
    change, alter the repr of arrays and NumPy scalars.)
    """
    if isinstance(part, bytes):
        return part
    if isinstance(part, np.ndarray):
        return repr((part.dtype.str, part.shape)).encode() + np.ascontiguousarray(part).tobytes()
    if isinstance(part, np.generic):
        part = part.item()
    if isinstance(part, float):
        return part.hex().encode()
    if dataclasses.is_dataclass(part) and not isinstance(part, type):
        return type(part).__name__.encode() + _as_bytes({f.name: getattr(part, f.name) for f in dataclasses.fields(part)})
    if isinstance(part, dict):
        return b"{" + b",".join(repr(key).encode() + b":" + _as_bytes(part[key]) for key in sorted(part)) + b"}"
    if isinstance(part, (list, tuple)):
        return type(part).__name__.encode() + b"(" + b",".join(_as_bytes(item) for item in part) + b")"
    if part is None or isinstance(part, (bool, int, str)):
        return repr(part).encode()
    raise TypeError(f"cannot fingerprint a {type(part).__name__}")


def _digest(*parts) -> str:
    h = hashlib.sha256()
    for part in parts:
        h.update(_as_bytes(part))
    return h.hexdigest()[:16]


def run_fingerprint(spec: ChainSpec) -> dict:
    """What a checkpoint must share with the run that resumes it, as short digests.

    The data (every array the likelihood reads), the prior, the kernel's configuration,
    the chain's seed and place among the chains, its length and start, and the sampler's
    code (the source of ``rjfit.sampler``, of the effects' fit forms, ``rjfit.effects``, and of the physics they
    call, ``rjfit.model``):
    a checkpoint written by other settings, other data or an older kernel would silently mix
    two different chains.
    """
    problem = spec.problem
    sampler_dir = Path(__file__).resolve().parent
    code_files = sorted(sampler_dir.rglob("*.py")) + sorted((sampler_dir.parent / "effects").rglob("*.py")) + sorted(
        (sampler_dir.parent / "model").rglob("*.py"))
    code = [path.read_bytes() for path in code_files]
    data = [getattr(problem, name) for name in ("y", "C", "log_cos_hn", "pixel")]
    if problem.effects is not None:     # the effects and their features are part of the model fitted
        data.append(problem.effects)
    if problem.normals is not None:     # so are the sampled normals' terms and prior
        data.append(problem.normals)
    return {"data": _digest(*data, problem.image_shape, float(problem.likelihood_power)),
            "prior": _digest(spec.prior), "config": _digest(spec.config),
            "chain": _digest(spec.seed, spec.chain, spec.n_chains, spec.iterations, spec.cp_thin, spec.start),
            "code": _digest(*code)}


def _load_checkpoint(path, fingerprint):
    with open(path, "rb") as handle:
        try:
            payload = pickle.load(handle)
        except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, ImportError) as error:
            raise ValueError(f"checkpoint {path} is unreadable ({type(error).__name__}: {error}): it was not written "
                             "by rjfit or was damaged; delete it to start the chain afresh") from None
    if not isinstance(payload, dict) or payload.get("version") != CHECKPOINT_VERSION:
        payload = payload if isinstance(payload, dict) else {}
        raise ValueError(f"checkpoint {path} has version {payload.get('version')}, expected {CHECKPOINT_VERSION}: "
                         "delete it to start the chain afresh")
    differ = [key for key, value in fingerprint.items() if payload.get("fingerprint", {}).get(key) != value]
    if differ:
        raise ValueError(f"checkpoint {path} belongs to another run (its {' and '.join(differ)} "
                         f"{'differ' if len(differ) > 1 else 'differs'} from this run's): resuming it would mix two different chains. Delete it (or choose another --out) "
                         "to start afresh, or rerun with the settings that wrote it to resume.")
    return payload


def available_cores() -> int:
    """The CPU cores this process may run on (its affinity mask where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:      # macOS, Windows
        return os.cpu_count() or 1


def threads_pay() -> bool:
    """Whether Numba can load a threading layer under which a chain's threads pay: OpenMP
    (measured: 1.3 to 1.5 times faster on two threads) or TBB. Without either it falls back
    to its workqueue layer, under which two threads took twice as long as one."""
    import importlib

    for pool in ("omppool", "tbbpool"):
        try:
            importlib.import_module(f"numba.np.ufunc.{pool}")
            return True
        except ImportError:     # its runtime library (libgomp, libtbb) is not installed
            continue
    return False


def default_threads(chains_at_once: int) -> int:
    """Numba threads per chain when the user does not say: the cores left to each of the
    chains that run at once (a single chain on 2 cores gets 2; 4 chains on 2 cores get 1
    each), 1 where :func:`threads_pay` is False."""
    return max(1, available_cores() // max(1, chains_at_once)) if threads_pay() else 1


@contextmanager
def numba_threads(threads: int):
    """Run the block with ``threads`` Numba threads (at most Numba's pool; yields the count set), then restore it."""
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))
    try:
        yield numba.get_num_threads()
    finally:
        numba.set_num_threads(before)


def run_chain(spec: ChainSpec, threads: int = 1) -> ChainRecord:
    """Run (or resume from ``spec.checkpoint_path``) one chain and return its record.

    Spawn-safe entry point of the worker processes. ``threads``: Numba threads for the
    chain's large passes (1 where other chains share the cores, as on Dask workers); the
    samples are the same for any number.
    """
    from threadpoolctl import threadpool_limits

    problem, prior, config = spec.problem, spec.prior, spec.config
    # BLAS threads only add overhead to these small dot products
    with threadpool_limits(1), numba_threads(threads) as threads_used:
        rng = chain_rngs(spec.seed, spec.n_chains)[spec.chain]
        recorder = ChainRecorder(spec)
        start_t = 0
        fingerprint = run_fingerprint(spec) if spec.checkpoint_path else None
        if spec.checkpoint_path and os.path.exists(spec.checkpoint_path):
            payload = _load_checkpoint(spec.checkpoint_path, fingerprint)
            state = payload["state"]
            rng.bit_generator.state = payload["rng_state"]
            recorder = payload["recorder"]
            if getattr(recorder, "jumped", None) is None:       # pickled before the field: its past is unknown
                recorder.jumped = np.ones(len(recorder.log_lik), np.int8)
            start_t = payload["t"]
            # recorded, so that a resume can be told from a restart (both give the same samples)
            recorder.resumed_from = tuple(recorder.resumed_from) + (start_t,)
            if spec.progress:     # say so: a resumed fit and a fresh one look alike otherwise
                print(f"chain {spec.chain}: resumed from its checkpoint at iteration {start_t} of {spec.iterations}",
                      file=sys.stderr, flush=True)
        else:
            state = initial_state(problem, prior, config, rng, **(spec.start or {}), **(spec.shared or {}))
        bar = None
        if spec.progress:       # a bar on a terminal, plain lines in a log
            bar = progress(spec.iterations, f"chain {spec.chain}", "iteration", initial=start_t, position=spec.chain,
                           leave=False)
        context = ChainContext()       # what the chain's steps reuse (never saved: rebuilt on resume)
        t0 = time.perf_counter()
        seconds_before = recorder.seconds
        t = start_t
        for t in range(start_t, spec.iterations):
            state, info = step(state, rng, problem, prior, config, context)
            recorder.add_counts(info)
            constant = problem.log_likelihood_constant
            if state.effects is not None:      # the raw data's log-likelihood: with the effects' log-Jacobian
                constant += effect_log_likelihood(problem, state)
            recorder.record(t, state, log_posterior(problem, prior, state, config, context.edge_memo), constant,
                            bool(info.jump))
            if bar is not None:
                bar.update(1, functools.partial(_model_text, spec.config.regions, state))
            done = t + 1
            # every checkpoint_every iterations, and at the end: a fit whose results cannot be written
            # keeps its chains there, and running it again publishes them without sampling again
            if spec.checkpoint_path and spec.checkpoint_every and (done % spec.checkpoint_every == 0
                                                                   or done == spec.iterations):
                recorder.seconds = seconds_before + time.perf_counter() - t0
                payload = {"version": CHECKPOINT_VERSION, "fingerprint": fingerprint, "state": state, "rng_state": rng.bit_generator.state,
                           "recorder": recorder, "t": done}
                atomic_write_bytes(spec.checkpoint_path, pickle.dumps(payload, protocol=pickle.HIGHEST_PROTOCOL))
            if spec.stop_after is not None and done >= spec.stop_after:
                break
        else:
            done = spec.iterations if spec.iterations > start_t else start_t
        if bar is not None:
            bar.close()
        recorder.seconds = seconds_before + time.perf_counter() - t0
        return dataclasses.replace(recorder.result(done), threads=threads_used)


def _model_text(regions, state) -> str:
    """``model (n_u, n_v) = (1, 2)``: the chain's current model in a progress line (a region model without model
    keys, whose layout never moves: its number of regions)."""
    if not regions.key_names:
        return f"{state.layout.n_regions} regions"
    names = ", ".join(regions.key_names)
    return f"model ({names}) = ({', '.join(str(int(k)) for k in state.layout.model_key)})"


def run_chains(specs, *, processes: int | None = None, threads: int | None = None):
    """Run chains in parallel worker processes (spawn context); returns their records in order.

    ``processes=1`` (or a single chain) runs in this process. ``threads``: Numba threads per
    chain; default: :func:`default_threads` of the chains that run at once.
    """
    specs = list(specs)
    if processes is None:
        processes = min(len(specs), available_cores())
    at_once = max(1, min(processes, len(specs)))
    if threads is None:
        threads = default_threads(at_once)
    if at_once == 1:
        return [run_chain(spec, threads) for spec in specs]
    with ProcessPoolExecutor(max_workers=processes, mp_context=get_context("spawn"),
                             initializer=_exit_with_parent, initargs=(os.getpid(),)) as pool:
        return list(pool.map(functools.partial(run_chain, threads=threads), specs))


#: seconds between a chain worker's checks that the process that started it is alive
PARENT_CHECK_SECONDS = 1.0


def _exit_with_parent(parent_pid: int) -> None:
    """In a chain worker: end this process once ``parent_pid`` is no longer its parent.

    A fit stopped by SIGTERM or SIGKILL sent to its main process alone (``kill PID``, a job
    scheduler's time limit) cannot shut its pool down, and the workers would run their whole
    chains on, orphaned, writing checkpoints that the resumed fit writes too. Checkpoints are
    written atomically, so ending at any moment loses at most the iterations since the last one.
    """
    def watch():
        while os.getppid() == parent_pid:
            time.sleep(PARENT_CHECK_SECONDS)
        os._exit(1)

    threading.Thread(target=watch, name="rjfit-parent-watch", daemon=True).start()
