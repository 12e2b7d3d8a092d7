"""A chain's memo of pixel sets' observations, so that what is derived from a set alone is derived once.

The material model's label moves build a proposal from the data of a set of pixels: a
birth's or a merge's Laplace fit of log gamma, a split's guide. These are functions of the
set's observations (and of the prior) alone, and the same set comes back: the merge of the
two materials of a K = 2 state, or the split of the one material of a K = 1 state, is the
whole object every time; the segment moves draw from a fixed family of sets. A
:class:`PixelSets` hands out one data object per set (its ``memo`` keeps those values,
:func:`rjfit.sampler.likelihood.memoised`), so a set seen again costs no pass over its
observations. The values are those computed afresh, so the chain's draws are unchanged.

A chain's :class:`~rjfit.sampler.kernel.ChainContext` owns one; it is dropped whenever the
problem's arrays or likelihood power change (the data objects carry them).
"""
from __future__ import annotations

import numpy as np

from rjfit.sampler.colour import pixel_set_data

__all__ = ["PixelSets", "PIXEL_SETS_KEPT", "PIXELS_KEPT_PER_IMAGE"]

#: sets kept (the least recently used goes first): an iteration asks for about ten, mostly the cluster
#: moves' random sets, which must not push out the whole-material sets the next iteration asks for again
PIXEL_SETS_KEPT = 32
#: and at most this many images' worth of pixels over all kept sets (a set holds 24 bytes per pixel:
#: its key and runs), so that on a 2048 x 2048 stack the memo holds a few whole-object sets, not 32
PIXELS_KEPT_PER_IMAGE = 4


class PixelSets:
    """The observations of pixel sets of one problem (:func:`~rjfit.sampler.colour.pixel_set_data`), one object per set.

    Parameters
    ----------
    capacity : int
        Sets kept; the least recently used is dropped first.
    images : float
        Pixels kept over all sets, in units of the problem's image size: the least recently
        used sets are dropped first until the rest fit (the set just asked for always stays).
    """

    def __init__(self, capacity: int = PIXEL_SETS_KEPT, images: float = PIXELS_KEPT_PER_IMAGE):
        self.capacity = int(capacity)
        self.images = float(images)
        self._sets = {}
        self._pixels = 0
        self._problem_key = None

    def valid_for(self, problem) -> PixelSets:
        """This memo, emptied first if ``problem``'s arrays or likelihood power are not those of its sets."""
        key = (problem.y, problem.C, problem.log_cos_hn, problem.lobe, float(problem.likelihood_power))
        held = self._problem_key
        if held is None or not all(a is b for a, b in zip(held[:4], key[:4])) or held[4] != key[4]:
            self._sets, self._pixels, self._problem_key = {}, 0, key
        return self

    def data(self, problem, members):
        """The observations of the pixels ``members`` (ascending): the object handed out before for this set, if kept."""
        members = np.ascontiguousarray(members)
        key = (members.dtype.str, members.tobytes())
        data = self._sets.pop(key, None)
        if data is None:
            data = pixel_set_data(problem, members)
            self._pixels += members.size
        limit = self.images * problem.height * problem.width
        while self._sets and (len(self._sets) >= self.capacity or self._pixels > limit):
            oldest = next(iter(self._sets))
            self._pixels -= len(oldest[1]) // np.dtype(oldest[0]).itemsize
            del self._sets[oldest]
        self._sets[key] = data          # (re)inserted last: the most recently used
        return data
