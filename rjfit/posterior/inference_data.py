"""A fit's chains as ArviZ InferenceData (``chains.nc``), in the form ArviZ's own tools take.

``az.summary``, ``az.plot_trace``, ``az.plot_rank`` and ``az.loo`` read the file as it is.
Reversible jumps change the number of regions from draw to draw, so the groups hold:

- ``posterior``: ``theta`` (chain, draw, region or material, [channel,] parameter), the
  parameters of the MAP model's regions at the kept draws in that model, and nothing where
  a draw does not define them (no NaN padding): for change points the kept draws whose
  (n_u, n_v) is the MAP model's, region r the model's cell r; for materials the kept draws
  with the MAP number of materials, relabelled to one numbering
  (:mod:`rjfit.posterior.materials`). Chains are cut to the shortest one's number of such
  draws (ArviZ needs equal lengths; a chain with fewer than 4 is left out while another has
  more, and ``chain`` keeps the fit's chain numbers). ``iteration`` (chain, draw) says which
  iteration each draw is. A fit with effects adds ``effects`` (chain, draw,
  effect_parameter) at the same draws. It is the posterior given the MAP model: the
  summary's ``regions`` are its means and intervals.
- ``sample_stats`` (every kept iteration) and ``warmup_sample_stats`` (the burn-in): ``lp``
  (the log posterior density, up to its normalising constant), ``log_lik`` (the sum of the
  log likelihood over all observations) and the fixed-dimension quantities of the
  trans-dimensional chain: ``n_u``, ``n_v`` and ``model_number``, or ``n_materials``.
- ``log_likelihood``: ``y`` (chain, draw, pixel_block), the log likelihood of the
  observations of each block of pixels (every light of each pixel; one pixel per block
  unless the object has more than :data:`LOG_LIK_POINTS_MAX` observed pixels), at the kept
  iterations that have a layout snapshot (the labels of the others are not kept), thinned
  evenly so that it holds at most :data:`LOG_LIK_VALUES_MAX` values. It is the log
  likelihood the posterior used: tempered by the likelihood power zeta (divide by zeta for
  the plain Gaussian density), noise scales included; the material model's edge term is a
  prior term and not in it.
- ``constant_data``: ``block_of_pixel`` (image_row, image_column; -1 where a pixel has no
  observation) and ``block_observations`` (pixel_block).
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from rjfit.posterior.materials import snapshot_labels
from rjfit.posterior.summary import _arviz, map_model_draws
from rjfit.sampler.passes.densities import block_log_likelihood, coefficients
from rjfit.sampler.priors import PARAM_NAMES
from rjfit.sampler.regions.changepoints.grid import pixel_region_labels
from rjfit.sampler.runner import available_cores

__all__ = ["chains_inference_data", "changepoint_draws", "log_likelihood_entry", "pixel_blocks",
           "pointwise_log_likelihood", "LOG_LIK_POINTS_MAX", "LOG_LIK_VALUES_MAX"]

#: most pixel blocks of the log_likelihood group: an object with more observed pixels is cut into square blocks
LOG_LIK_POINTS_MAX = 2048
#: most values (chains x draws x blocks) of the log_likelihood group: 3.2 MB of float64, the draws thinned to fit
LOG_LIK_VALUES_MAX = 400_000
#: a chain with fewer MAP-model draws than this is left out of the posterior group while another has more
MIN_CHAIN_DRAWS = 4


def pixel_blocks(problem) -> tuple[np.ndarray, int]:
    """``(block_of_pixel (H, W) int64, side)``: the observed pixels in square blocks of ``side`` pixels.

    ``side`` is the smallest that leaves at most :data:`LOG_LIK_POINTS_MAX` blocks holding
    an observation; blocks are numbered row by row from 0, -1 where a pixel has none.
    """
    height, width = problem.image_shape
    observed = np.diff(problem.pixel_start).reshape(height, width) > 0
    rows, cols = np.indices((height, width))
    side = 1
    while True:
        key = (rows // side) * ((width + side - 1) // side) + cols // side
        used, block = np.unique(key[observed], return_inverse=True)
        if used.size <= LOG_LIK_POINTS_MAX:
            break
        side += 1
    block_of_pixel = np.full((height, width), -1, np.int64)
    block_of_pixel[observed] = block.ravel()
    return block_of_pixel, side


def changepoint_draws(records, burn_in: int, model) -> tuple[list, list]:
    """Per chain, the kept draws of change-point ``model`` (n_u, n_v): their parameters
    (:func:`rjfit.posterior.summary.map_model_draws`) and their iterations."""
    n_u, n_v = model
    iterations = [burn_in + np.flatnonzero((r.n_u[burn_in:] == n_u) & (r.n_v[burn_in:] == n_v)) for r in records]
    return map_model_draws(records, burn_in, model), iterations


def log_likelihood_entry(idata) -> dict:
    """The summary's ``log_likelihood`` entry: the size of ``idata``'s log_likelihood group, or why it has none."""
    if "log_likelihood" not in idata.groups():
        return {"note": "no log_likelihood group: a fit with effects (their per-observation transform is not "
                        "recorded) or no kept layout snapshot"}
    attrs = idata.log_likelihood.attrs
    return {key: attrs[key] for key in ("points", "block_pixels", "chains", "draws_per_chain", "values",
                                        "likelihood_power", "reff") if key in attrs}


def _pixel_labels(record, snapshot: int, image_shape) -> np.ndarray:
    """The region (row of ``record.theta``) of every pixel at layout snapshot ``snapshot``, flat; -1: none."""
    t = int(record.cp_iteration[snapshot])
    if record.material_labels is not None:     # a material fit's snapshots
        return snapshot_labels(record, snapshot).ravel()
    n_u, n_v = int(record.n_u[t]), int(record.n_v[t])
    return pixel_region_labels(record.cp_u[snapshot, :, :n_u].astype(float),
                               record.cp_v[snapshot, :, :n_v].astype(float), image_shape).ravel()


def _snapshot_draws(records, burn_in: int, n_points: int) -> list:
    """Per chain, the kept snapshots whose log likelihood is written: as many per chain, evenly thinned."""
    kept = [np.flatnonzero(r.cp_iteration >= burn_in) for r in records]
    count = min(len(k) for k in kept)
    most = max(1, LOG_LIK_VALUES_MAX // max(1, len(records) * n_points))
    step = -(-count // most) if count > most else 1
    return [k[:count][::step] for k in kept]


class _BlockLikelihood:
    """Each pixel block's untempered log likelihood at a draw: the density of
    :func:`rjfit.sampler.likelihood.observation_log_likelihood` (noise scales included) summed per block.

    A fit writes it at a few hundred draws of one problem, so what does not depend on the draw is converted
    once here, and the model's factors and ``log sigma^2`` are taken per row of theta
    (:func:`rjfit.sampler.passes.densities.coefficients`): a draw costs one exponential per observation in a
    compiled loop (:func:`rjfit.sampler.passes.densities.block_log_likelihood`) that runs without the GIL, so
    :func:`pointwise_log_likelihood` evaluates draws on threads side by side.
    """

    def __init__(self, problem, block_of_obs, n_blocks: int):
        self.block, self.n_blocks = block_of_obs.astype(np.int64), n_blocks
        self.y = problem.y.astype(np.float64)
        self.C = np.maximum(problem.C.astype(np.float64), 0.0)     # eq. 2's <l.n> clipped, as the oracle's
        self.log_cos_hn = problem.log_cos_hn.astype(np.float64)
        self.log_s2 = self.inverse_s2 = np.zeros(0)
        if problem.noise_scale is not None:     # undo the weighting: N(y s; mu s, sigma^2 s^2), s known
            s = problem.noise_scale.astype(np.float64)
            self.y *= s
            self.C *= s
            self.log_s2, self.inverse_s2 = 2.0 * np.log(s), 1.0 / (s * s)

    def __call__(self, rows, theta) -> np.ndarray:
        """The blocks' log likelihood when observation i is in row ``rows[i]`` of ``theta`` (R, 4)."""
        out = np.zeros(self.n_blocks)
        block_log_likelihood(self.y, self.C, self.log_cos_hn, np.asarray(rows, np.int64),
                             coefficients(np.ascontiguousarray(theta, dtype=np.float64)), self.log_s2,
                             self.inverse_s2, self.block, out)
        return out


def pointwise_log_likelihood(records, burn_in: int, problem, pixel_labels=None):
    """The log likelihood of every pixel block at the kept snapshot draws (see the module docstring).

    ``pixel_labels`` (H, W): the region of every pixel where the layout never changes (a fixed
    label map, whose records hold no layout); else each snapshot's layout.

    Returns ``(values (C, D, B), iterations (C, D), block_of_pixel (H, W), side)``; ``values``
    tempered by ``problem.likelihood_power``; D may be 0 (no kept snapshot).

    Raises
    ------
    ValueError
        If ``problem`` has effects' lobe terms (not this density's plain lobe), or a snapshot
        leaves an observed pixel without a region (the records do not belong to ``problem``).
    """
    if problem.lobe is not None:
        raise ValueError("the pointwise log likelihood of a problem with effects' lobe terms is not written")
    block_of_pixel, side = pixel_blocks(problem)
    n_blocks = int(block_of_pixel.max()) + 1
    density = _BlockLikelihood(problem, block_of_pixel.ravel()[problem.pixel], n_blocks)
    chosen = _snapshot_draws(records, burn_in, n_blocks)
    values = np.zeros((len(records), len(chosen[0]), n_blocks))
    iterations = np.zeros((len(records), len(chosen[0])), np.int64)

    def draw(c, d, s):
        record = records[c]
        t = int(record.cp_iteration[s])
        layout = _pixel_labels(record, s, problem.image_shape) if pixel_labels is None else pixel_labels.ravel()
        rows = layout[problem.pixel]
        if rows.size and rows.min() < 0:
            raise ValueError(f"chain {c}, iteration {t}: an observed pixel has no region in the layout snapshot")
        if problem.n_channels > 1:      # a joint colour fit records a row per material and channel
            rows = rows * problem.n_channels + problem.channel
        values[c, d] = problem.likelihood_power * density(rows, record.theta[t])
        iterations[c, d] = t

    # the draws on the process's cores side by side (the density's kernel runs without the GIL; on the DiLiGenT
    # ball's 1.4 million observations a draw took 34 ms in NumPy, 200 draws in a fit's summary)
    with ThreadPoolExecutor(max_workers=available_cores()) as pool:
        futures = [pool.submit(draw, c, d, s) for c, snapshots in enumerate(chosen) for d, s in enumerate(snapshots)]
        for future in futures:
            future.result()
    return values, iterations, block_of_pixel, side


def _relative_efficiency(values) -> float | None:
    """The mean over blocks of ESS / draws of each block's likelihood ``exp(y)`` (None: too few draws)."""
    if values.shape[1] < MIN_CHAIN_DRAWS:
        return None
    az = _arviz()
    scaled = np.exp(values - values.max(axis=(0, 1), keepdims=True))
    ess = np.asarray(az.ess(az.convert_to_dataset({"x": scaled}), method="mean")["x"].values)
    finite = ess[np.isfinite(ess)]
    return float(np.mean(finite) / (values.shape[0] * values.shape[1])) if finite.size else None


def _equal_chains(draws_per_chain, iterations_per_chain):
    """The chains with draws, cut to the shortest one's length: ``(chain numbers, draws, iterations)``."""
    lengths = [len(d) for d in draws_per_chain]
    floor = MIN_CHAIN_DRAWS if max(lengths) >= MIN_CHAIN_DRAWS else 1
    chains = [c for c, n in enumerate(lengths) if n >= floor]
    length = min(lengths[c] for c in chains)
    return (chains, np.stack([np.asarray(draws_per_chain[c])[:length] for c in chains]),
            np.stack([np.asarray(iterations_per_chain[c])[:length] for c in chains]))


def _stats(records, key_names, start: int, stop: int) -> dict:
    """``lp``, ``log_lik`` and the model keys of iterations ``start:stop`` of every chain."""
    out = {"lp": np.stack([r.log_post[start:stop] for r in records]),
           "log_lik": np.stack([r.log_lik[start:stop] for r in records])}
    for name in key_names:
        out[name] = np.stack([getattr(r, name)[start:stop] for r in records]).astype(np.int64)
    return out


def chains_inference_data(records, burn_in: int, problem, draws, *, region_dim: str, key_names=(), max_v=None,
                          effect_names=(), attrs=None, log_likelihood: bool = True, pixel_labels=None):
    """The InferenceData of ``chains.nc`` (module docstring).

    Parameters
    ----------
    records : sequence of ChainRecord
    burn_in : int
        Iterations discarded per chain.
    problem : Problem
        The problem the chains sampled (the log likelihood is evaluated on it).
    draws : (list of ndarray, list of ndarray)
        Per chain the MAP model's parameter draws (D_c, R, [channels,] 4) and their iterations (D_c,).
    region_dim : str
        'region' (change points) or 'material'.
    key_names : sequence of str
        The record's model keys per draw (``n_u``, ``n_v`` or ``n_materials``).
    max_v : int, optional
        Change points: adds ``model_number`` = n_u (max_v + 1) + n_v + 1 to the sample stats.
    effect_names : sequence of str
        The effects' parameters (``effect.param``), recorded per draw in ``record.effects``.
    attrs : dict, optional
        Written into every group's attributes (the fit's version, schema and options).
    log_likelihood : bool
        Whether to write the log_likelihood group (not for a fit with effects, whose
        per-observation transform and log-Jacobian it would need).
    pixel_labels : ndarray (H, W), optional
        The region of every pixel where the layout never changes (a fixed label map).

    Returns
    -------
    arviz.InferenceData

    Raises
    ------
    ValueError
        As :func:`pointwise_log_likelihood`.
    """
    az = _arviz()
    attrs = dict(attrs or {})
    T = min(len(r.log_post) for r in records)
    chains, theta, iterations = _equal_chains(*draws)
    posterior = {"theta": theta}
    coords = {"chain": chains, region_dim: np.arange(theta.shape[2]), "parameter": list(PARAM_NAMES)}
    dims = {"theta": [region_dim, "parameter"]}
    if theta.ndim == 5:         # a joint colour fit: a row per material and channel
        from rjfit.data.formats import COLOUR_CHANNELS

        coords["channel"] = list(COLOUR_CHANNELS[:theta.shape[3]])
        dims["theta"] = [region_dim, "channel", "parameter"]
    if effect_names:
        posterior["effects"] = np.stack([records[c].effects[iterations[i]] for i, c in enumerate(chains)])
        coords["effect_parameter"] = list(effect_names)
        dims["effects"] = ["effect_parameter"]
    stats, warmup = _stats(records, key_names, burn_in, T), _stats(records, key_names, 0, burn_in)
    if max_v is not None:
        for group in (stats, warmup):
            group["model_number"] = group["n_u"] * (max_v + 1) + group["n_v"] + 1
    groups = {"posterior": posterior, "sample_stats": stats, "warmup_sample_stats": warmup}
    notes = {}
    if log_likelihood:
        values, ll_iterations, block_of_pixel, side = pointwise_log_likelihood(records, burn_in, problem, pixel_labels)
        if values.shape[1]:
            groups["log_likelihood"] = {"y": values}
            groups["constant_data"] = {"block_of_pixel": block_of_pixel, "block_observations": np.bincount(
                block_of_pixel.ravel()[problem.pixel], minlength=values.shape[2])}
            dims.update(y=["pixel_block"], block_of_pixel=["image_row", "image_column"],
                        block_observations=["pixel_block"])
            notes = _log_likelihood_attrs(values, side, float(problem.likelihood_power))
    posterior_coords = {k: v for k, v in coords.items() if k != "chain"}
    idata = az.from_dict(posterior=posterior, coords=posterior_coords, dims=dims, save_warmup=True,
                         **{name: value for name, value in groups.items() if name != "posterior"})
    idata.posterior = idata.posterior.assign_coords(chain=chains, iteration=(("chain", "draw"), iterations))
    if "log_likelihood" in groups:
        idata.log_likelihood = idata.log_likelihood.assign_coords(iteration=(("chain", "draw"), ll_iterations))
        idata.log_likelihood.attrs.update(notes)
    for group in idata.groups():
        idata[group].attrs.update(attrs)
    return idata


def _log_likelihood_attrs(values, side: int, power: float) -> dict:
    """What the log_likelihood group holds, in its attributes (its size, thinning and tempering)."""
    reff = _relative_efficiency(values)
    out = {"points": int(values.shape[2]), "block_pixels": f"{side} x {side}", "chains": int(values.shape[0]),
           "draws_per_chain": int(values.shape[1]), "values": int(values.size),
           "tempered": 1, "likelihood_power": power,
           "description": (f"y: the log likelihood of the observations (every light) of each block of {side} x {side} "
                           f"pixels (constant_data.block_of_pixel), at the kept iterations with a layout snapshot "
                           f"(coordinate iteration), thinned evenly to at most {LOG_LIK_VALUES_MAX} values; tempered: "
                           f"the likelihood power {power:.6g} times the Gaussian log density (divide by it for the "
                           f"plain density); noise scales included; the material model's edge term is not in it")}
    if reff is not None:
        out["reff"] = reff
        out["loo_note"] = ("az.loo(idata) takes r_eff from the posterior group's draws, which these thinned draws do "
                           "not share; az.loo(idata, reff=idata.log_likelihood.attrs['reff']) uses these draws' r_eff")
    return out
