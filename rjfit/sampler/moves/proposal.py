"""What a structure move proposes: the new state's parts, the log acceptance ratio, its kind and whether it jumps."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["Proposal", "RowProposal"]


class Proposal(NamedTuple):
    """A proposed state (its parts) and the log acceptance ratio of the move that made it.

    ``log_ratio`` is complete: target ratio, the move's proposal densities both ways and its
    Jacobian. ``-inf`` marks an invalid proposal (outside the support, or a draw that could
    not be made): it is tested like any other (its uniform drawn) and rejected; the parts
    an invalid proposal did not get to build are None. Accepting a full proposal makes its
    parts the current state (:meth:`rjfit.sampler.state.Work.take`). An incremental one (the
    vector redraw) carries the parameters unchanged and, instead of labels and statistics,
    the observations that change region (``shift``), which its move applies in place.

    Attributes
    ----------
    layout : object
        The region model's new structure (change points: ``Changepoints(u, v)``).
    theta : ndarray (R, 4) or None
    labels : ndarray (N,) or None
        Region of each observation under ``layout``.
    stats : ndarray (R, 7) or None
    log_lik : ndarray (R,) or None
    log_ratio : float
    shift : tuple or None
        ``(starts, ends, delta)`` of :func:`rjfit.sampler.regions.changepoints.sweeps.element_shift`
        (incremental proposals only).
    kind : str
        The move's name in the step's acceptance counts (``birth_u``, ``cluster``, ...).
    jump : bool
        Whether it changes the model's dimension (a birth, death, merge or split): an accepted
        jump is recorded per draw (:attr:`rjfit.sampler.state.StepInfo.jump`).
    tested : bool
        False for a proposal with nothing to test (a renaming, a set of two labels): counted as
        a rejection, no uniform drawn (:func:`rjfit.sampler.moves.base.decide`).
    """

    layout: object
    theta: np.ndarray | None
    labels: np.ndarray | None
    stats: np.ndarray | None
    log_lik: np.ndarray | None
    log_ratio: float
    shift: tuple | None = None
    kind: str = ""
    jump: bool = False
    tested: bool = True

    @classmethod
    def invalid(cls, layout, labels=None) -> Proposal:
        """A proposal that can only be rejected (log ratio -inf)."""
        return cls(layout, None, labels, None, None, -np.inf)

    @classmethod
    def untested(cls, kind: str) -> Proposal:
        """Nothing to test: a move of ``kind`` that is counted as a rejection and draws no uniform."""
        return cls(None, None, None, None, None, -np.inf, kind=kind, tested=False)

    def named(self, kind: str, jump: bool = False) -> Proposal:
        """This proposal as a move of ``kind`` (``jump``: one that changes the model's dimension)."""
        return self._replace(kind=kind, jump=jump)


class RowProposal(NamedTuple):
    """A within-region move's proposal: new parameters for one row of the working copy, and its test.

    A within-region move never changes the model's dimension (``jump`` False). Its uniform is
    drawn by the move where it always has been (some moves draw it before they know whether
    the proposal is valid, and those draws must stay in the random stream), so it travels
    here as ``log_u``; :func:`rjfit.sampler.moves.base.decide_row` tests it.

    Attributes
    ----------
    r : int
        The parameter row (a region, or one channel's row of a colour material).
    theta : tuple
        Its proposed ``(I0, kd, gamma, sigma^2)``.
    stats : ndarray (7,) or None
        Its statistics at the proposed gamma (None: unchanged).
    log_lik : float or None
        Its log-likelihood there (None: computed when accepted).
    log_ratio : float
        The complete log acceptance ratio (``-inf``: invalid, rejected).
    log_u : float
        Log of the move's uniform draw.
    kind : str
        The move's name in the step's acceptance counts.
    jump : bool
        Always False: a within-region move keeps the model's dimension.
    """

    r: int
    theta: tuple
    stats: np.ndarray | None
    log_lik: float | None
    log_ratio: float
    log_u: float
    kind: str
    jump: bool = False
