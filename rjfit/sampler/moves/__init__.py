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

Structure moves of the change-point region model
(:mod:`rjfit.sampler.regions.changepoints` runs them), each module with its settings:

- :mod:`~rjfit.sampler.moves.sweeps`: element sweeps;
- :mod:`~rjfit.sampler.moves.block_shift`: block shift;
- :mod:`~rjfit.sampler.moves.vector_redraw`: whole-vector redraw (forward filtering, backward sampling);
- :mod:`~rjfit.sampler.moves.birth_death`: birth/death keeping ranks, split/merge maps;
- :mod:`~rjfit.sampler.moves.birth_death_free`: birth/death at any rank;
- :mod:`~rjfit.sampler.moves.region_proposals`: Laplace proposals of whole regions' parameters.

Every move that tests a proposal decides with :func:`~rjfit.sampler.moves.accept.accept`;
structure moves return a :class:`~rjfit.sampler.moves.proposal.Proposal`.
"""
