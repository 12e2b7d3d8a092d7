"""A chain's memo of the edge term's boundary sums: the labelling and parameters it last summed, and their sums.

Why: a material's parameter moves ask the term's change a few dozen times per iteration, and every
structure move's test asks the term of the current state again (:func:`rjfit.sampler.moves.base.decide`);
each answer was a pass over every pair of the changed boundaries at the old parameters as well as the new.
On psm-rock (71,000 pixels at 3 to 5 materials) those passes were 60 % of a chain's time
(docs/results/2026-11-30-edge-memo.md). The old parameters' sums are the current state's, which the last
question already summed: kept here, only the new ones are summed.

The memo is keyed by value (the term, a copy of the labels, the materials' coefficients), so an answer from
it is the sums :func:`~rjfit.sampler.regions.materials.passes.edges.boundary_sums` would return, to the bit
(the updated entries are summed over the same pairs in the same order): a chain gives the same draws with
or without it. It is the chain's (:class:`rjfit.sampler.kernel.ChainContext`), never part of its state.
"""
from __future__ import annotations

import numpy as np

__all__ = ["BoundaryMemo", "MEMO_ENTRIES"]

#: entries kept: the current state's, a proposal's and the one before (the most recently used first)
MEMO_ENTRIES = 3


class BoundaryMemo:
    """The edge term's boundary sums of the last few (term, labels, coefficients) asked for (module docstring)."""

    def __init__(self):
        self.entries = []       # (term, labels copy, coefficients copy, sums), most recently used first

    def find(self, term, pixels, coef):
        """The kept sums of ``term`` at labels ``pixels`` and coefficients ``coef``, or None."""
        for index, (kept_term, labels, kept_coef, sums) in enumerate(self.entries):
            if (kept_term is term and labels.shape == pixels.shape and np.array_equal(kept_coef, coef)
                    and np.array_equal(labels, pixels)):
                if index:
                    self.entries.insert(0, self.entries.pop(index))
                return sums
        return None

    def keep(self, term, pixels, coef, sums) -> None:
        """Remember ``sums`` as ``term``'s at ``pixels`` and ``coef`` (copies are kept; ``sums`` is not written to
        afterwards by its owner)."""
        self.entries.insert(0, (term, np.array(pixels, copy=True), np.array(coef, copy=True), sums))
        del self.entries[MEMO_ENTRIES:]
