"""Moves of the RJMCMC kernel, one move family per module.

Within-region moves (every region model's regions get them; they see only labels,
statistics and parameters), run for every region by :mod:`~rjfit.sampler.moves.within`
(which also holds their settings):

- :mod:`~rjfit.sampler.moves.ab_conditional`: the (a, b) conditional and its redraw;
- :mod:`~rjfit.sampler.moves.sigma2`: the sigma^2 independence move;
- :mod:`~rjfit.sampler.moves.gamma`: gamma random walk and Newton moves;
- :mod:`~rjfit.sampler.moves.phi_walk`: the phi-space random walk of small regions;
- :mod:`~rjfit.sampler.moves.paper_mh`: the paper's component-wise MH;
- :mod:`~rjfit.sampler.moves.region_terms`: scalar terms they share (Giesen's normalisation).

Shared by the region models' structure moves:

- :mod:`~rjfit.sampler.moves.region_proposals`: Laplace proposals of whole regions' parameters;
- :mod:`~rjfit.sampler.moves.colour_within`: a joint colour fit's within-material moves;
- :mod:`~rjfit.sampler.moves.effects`: the effects' global parameters.

Each region model's own structure moves live in its package
(:mod:`rjfit.sampler.regions.changepoints`, :mod:`rjfit.sampler.regions.materials`).

Every move that tests a proposal decides with :func:`~rjfit.sampler.moves.accept.accept`;
structure moves return a :class:`~rjfit.sampler.moves.proposal.Proposal`, single-row
within-region moves a :class:`~rjfit.sampler.moves.proposal.RowProposal` tested by
:func:`~rjfit.sampler.moves.base.decide_row`. Each within-region family is an object with its
settings (:func:`~rjfit.sampler.moves.within.within_moves` builds them).
"""
