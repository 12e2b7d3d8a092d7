"""How a set of pixels differs from its surroundings, light by light: the reading that tells a paint from shading.

A change of albedo alone (a paint) scales a pixel's intensity by one factor under every light, so the ratio of a
piece's brightness to that of the pixels just around it is the same under every light. Shading does not keep that
ratio: a cast shadow or interreflection in a concavity darkens or lightens some lights more than others, and so does
a different lobe (a glossy patch brightens the lights whose highlight it holds). The shading that the given normals
explain is divided out first: each side's brightness under a light is its observations' sum over the sum of their
Lambertian shading ``E <l.n>`` (a Lambertian albedo), so that a piece whose normals turn away from a light is not
read as a shadow (psm-rock's gaps between pebbles: 0.38 to 1.10 times their surroundings in raw intensity, 1.30 to
1.96 after the shading). On psm-cat the painted nose keeps one factor (0.44 to 0.46 over the middle half of its 12
lights) and on the DiLiGenT ball a speck of dust too (0.93 to 0.95 over the middle half of 85 lights), while the
tail's cast shadow on psm-horse's hind leg changes 2.1-fold over the middle half of its lights
(docs/results/2026-12-03-paint-or-shading.md).

:func:`ring` is the comparison's surroundings and :func:`border` the piece's side of it: its pixels within
:data:`RING_OUTER` px of the ring, so that both sides lie near the outline and see the lights alike (the whole of a
large material brings its own shading: in raw intensity, psm-cat's whole body against the inside of its nose varied
1.6-fold over the lights, its border 1.1-fold, as the nose). :func:`light_contrasts` is the ratio per light from the
fit's observations, :func:`contrast_entry` its summary (its range and its middle half over the lights: a few lights,
at a highlight or the terminator, where the normals' errors weigh most, can stray while the rest agree) and
:func:`contrast_words` the summary in words. The reading is stated, not judged: what spread still is "one factor"
depends on the noise and the normals' errors of each stack, so no threshold turns it into a verdict.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["RING_INNER", "RING_OUTER", "ring", "border", "light_contrasts", "contrast_entry", "contrast_words",
           "piece_around", "piece_contrast", "material_contrasts", "MEANING"]

#: how to read the figures, said wherever they are shown
MEANING = ("A Lambertian albedo here is the intensity over the given normals' Lambertian shading E <l.n>. A change "
           "of albedo alone (a paint) gives one factor under every light; a cast shadow, interreflection, normals in "
           "error or a different lobe give a factor that changes with the light.")
#: the ring starts this many pixels (8-neighbour steps) outside the piece: the pixels next to a boundary mix both
#: sides (the optics' blur, a segmentation a pixel off), so they would pull the ratio towards 1
RING_INNER = 2
#: and ends this many pixels outside it: near enough that its normals and lighting are the piece's own
RING_OUTER = 4


def ring(piece, inside, inner: int = RING_INNER, outer: int = RING_OUTER) -> np.ndarray:
    """(H, W) bool: the pixels of ``inside`` (H, W bool, the object) that lie ``inner`` to ``outer`` 8-neighbour
    steps outside ``piece`` (H, W bool).

    Raises
    ------
    ValueError
        If the two masks differ in shape, or ``inner`` is below 1 or above ``outer``.
    """
    piece, inside = np.asarray(piece, bool), np.asarray(inside, bool)
    if piece.shape != inside.shape:
        raise ValueError(f"the piece's mask is {piece.shape} and the object's {inside.shape}; give both on the "
                         "image's pixel grid")
    if not 1 <= inner <= outer:
        raise ValueError(f"the ring runs from {inner} to {outer} px outside the piece; give 1 <= inner <= outer")
    square = np.ones((3, 3), bool)
    near = ndimage.binary_dilation(piece, square, iterations=inner - 1) if inner > 1 else piece
    return ndimage.binary_dilation(piece, square, iterations=outer) & ~near & inside


def border(piece, around, width: int = RING_OUTER) -> np.ndarray:
    """(H, W) bool: the pixels of ``piece`` (H, W bool) within ``width`` 8-neighbour steps of ``around`` (H, W bool,
    its :func:`ring`, which begins 2 px outside: with the default width, the pixels up to 3 px inside its outline, so
    all of a piece up to 6 px across and a band along the outline of a larger one (not along the object's
    silhouette, where there is no ring).

    Raises
    ------
    ValueError
        If the masks differ in shape or ``width`` is below 1.
    """
    piece, around = np.asarray(piece, bool), np.asarray(around, bool)
    if piece.shape != around.shape or width < 1:
        raise ValueError(f"a border of width {width} of a {piece.shape} piece along a {around.shape} ring: give both "
                         "on the image's pixel grid and a width of 1 or more")
    return ndimage.binary_dilation(around, np.ones((3, 3), bool), iterations=width) & piece


def light_contrasts(y, light, pixel, piece, around, n_lights: int, shading=None, channel=None,
                    n_channels: int = 1) -> np.ndarray:
    """(n_lights,) the brightness of ``piece`` under each light over that of ``around``: each side's observations
    ``y`` summed over the light, over the sum of their ``shading`` (the mean of ``y`` where ``shading`` is None); NaN
    where either side holds no observation under that light or a sum is not positive. With ``channel`` (per
    observation, 0 .. ``n_channels`` - 1), (n_lights, 1 + n_channels): the channels together, then each alone, from
    one pass over the observations.

    ``y``, ``light``, ``pixel``, ``shading``: per observation, its intensity, its light (0 .. ``n_lights`` - 1), its
    row-major flat pixel index and its Lambertian shading ``E <l.n>``; ``piece`` and ``around`` (H, W bool). Each
    pixel counts by its observations (a pixel whose observation under a light was left out, as a cast shadow, does
    not count under it). Sums, not a mean of per-pixel ratios: an observation at grazing light, whose shading is near
    0, would dominate a mean of ratios.
    """
    pixel = np.asarray(pixel)
    groups = n_lights * n_channels
    key = np.asarray(light).astype(np.int64) * n_channels
    if channel is not None:
        key += np.asarray(channel)
    y = np.asarray(y, np.float64)
    weight = np.ones_like(y) if shading is None else np.asarray(shading, np.float64)
    sides = []
    for mask in (piece, around):
        chosen = np.asarray(mask, bool).ravel()[pixel]
        total = np.bincount(key[chosen], weights=y[chosen], minlength=groups).reshape(n_lights, n_channels)
        norm = np.bincount(key[chosen], weights=weight[chosen], minlength=groups).reshape(n_lights, n_channels)
        if channel is not None:          # the channels together first, then each alone
            total, norm = (np.column_stack([sums.sum(axis=1), sums]) for sums in (total, norm))
        with np.errstate(invalid="ignore", divide="ignore"):
            sides.append(np.where((norm > 0) & (total > 0), total / norm, np.nan))
    ratios = sides[0] / sides[1]
    return ratios if channel is not None else ratios[:, 0]


def contrast_entry(ratios, piece_pixels: int, border_pixels: int, ring_pixels: int) -> dict | None:
    """The summary of :func:`light_contrasts`' ``ratios``: ``lights`` (how many have a finite ratio), ``min``,
    ``lower_quartile``, ``median``, ``upper_quartile`` and ``max`` of the ratio over them, ``spread`` (max over min)
    and ``middle_spread`` (upper over lower quartile: 1 for one factor under every light), the piece's size, its
    border's and its ring's (``pixels``, ``border_pixels``, ``ring_pixels``) and the ring's span (``ring``: from, to
    px); None where no light has a finite positive ratio."""
    ratios = np.asarray(ratios, np.float64)
    finite = ratios[np.isfinite(ratios) & (ratios > 0)]
    if not finite.size:
        return None
    low, median, high = np.percentile(finite, [25, 50, 75])
    return {"lights": int(finite.size), "min": float(finite.min()), "lower_quartile": float(low),
            "median": float(median), "upper_quartile": float(high), "max": float(finite.max()),
            "spread": float(finite.max() / finite.min()), "middle_spread": float(high / low),
            "pixels": int(piece_pixels), "border_pixels": int(border_pixels), "ring_pixels": int(ring_pixels),
            "ring": [RING_INNER, RING_OUTER]}


def contrast_words(entry: dict | None) -> str | None:
    """:func:`contrast_entry` in words: "its Lambertian albedo is 0.43 to 0.48 times that of the pixels 2 to 4 px
    outside it under its 12 lights, 0.44 to 0.46 under the middle half of them (1.04-fold)", with "at its outline
    (its pixels up to 3 px inside it)" where the border is not the whole piece; None without an entry."""
    if not entry:
        return None
    inner, outer = entry.get("ring", (RING_INNER, RING_OUTER))
    lights = f"{entry['lights']} light{'' if entry['lights'] == 1 else 's'}"
    whole = entry.get("border_pixels", entry["pixels"]) == entry["pixels"]
    where = "" if whole else f" at its outline (its pixels up to {outer - 1} px inside it)"
    words = (f"its Lambertian albedo{where} is {_range(entry['min'], entry['max'])} times that of the pixels {inner} "
             f"to {outer} px outside it under its {lights}, {_range(entry['lower_quartile'], entry['upper_quartile'])} "
             f"under the middle half of them ({entry['middle_spread']:.2f}-fold)")
    channels = [f"{name} {_range(one['lower_quartile'], one['upper_quartile'])} ({one['middle_spread']:.2f}-fold)"
                for name, one in (entry.get("channels") or {}).items() if one]
    return words + (f"; per channel, under the middle half: {', '.join(channels)}" if channels else "")


def piece_around(share, row: int, column: int, inside) -> np.ndarray:
    """(H, W bool) the 8-connected pixels of ``inside`` around (``row``, ``column``) whose ``share`` (H, W; NaN
    counts as 0) is at least half that pixel's: the place a per-pixel map such as the extra materials' share
    (:func:`rjfit.posterior.caveats.extra_materials`) peaks at, as a piece.

    Raises
    ------
    ValueError
        If (``row``, ``column``) lies outside the map or the object, or its share is not positive.
    """
    share, inside = np.nan_to_num(np.asarray(share, np.float64), nan=0.0), np.asarray(inside, bool)
    if not (0 <= row < share.shape[0] and 0 <= column < share.shape[1]) or share[row, column] <= 0 or \
            not inside[row, column]:
        raise ValueError(f"({row}, {column}) is not a pixel of the object with a positive share of the {share.shape} "
                         "map; give the map's peak")
    parts, _ = ndimage.label((share >= share[row, column] / 2) & inside,
                             structure=np.ones((3, 3)))
    return parts == parts[row, column]


def piece_contrast(y, light, pixel, piece, inside, n_lights: int, shading=None, channel=None,
                   channel_names=()) -> dict | None:
    """:func:`contrast_entry` of ``piece``'s :func:`border` (H, W bool) against its :func:`ring` on ``inside`` (H, W
    bool), from the observations ``y``, ``light``, ``pixel`` and ``shading`` (:func:`light_contrasts`); None where
    the ring is empty or no light has a ratio.

    With ``channel`` (per observation, 0 .. len(``channel_names``) - 1: a colour fit's) the entry, over all channels
    together, gains ``channels``: each channel's own entry by name. Why: a paint that changes the hue but not the
    grey level reads 1 over all channels, and its factor per channel is what sets it apart.
    """
    piece = np.asarray(piece, bool)
    around = ring(piece, inside)
    if not around.any():
        return None
    near = border(piece, around)
    sizes = (int(piece.sum()), int(near.sum()), int(around.sum()))
    ratios = light_contrasts(y, light, pixel, near, around, n_lights, shading, channel, len(channel_names) or 1)
    if channel is None:
        return contrast_entry(ratios, *sizes)
    entry = contrast_entry(ratios[:, 0], *sizes)
    if entry is not None:
        entry["channels"] = {name: contrast_entry(ratios[:, 1 + index], *sizes)
                             for index, name in enumerate(channel_names)}
    return entry


def material_contrasts(y, light, pixel, labels, n_lights: int, shading=None, channel=None,
                       channel_names=()) -> list:
    """Per material of ``labels`` (H, W int; below 0 off the object), its :func:`piece_contrast` against the
    object's other pixels around it (per channel too, with ``channel``); None for each of a labelling with one
    material (it has no surroundings)."""
    labels = np.asarray(labels)
    inside = labels >= 0
    n_materials = int(labels.max()) + 1 if inside.any() else 0
    if n_materials < 2:
        return [None] * n_materials
    return [piece_contrast(y, light, pixel, labels == material, inside, n_lights, shading, channel, channel_names)
            for material in range(n_materials)]


def _range(low: float, high: float) -> str:
    low, high = (f"{value:.2f}" if value < 10 else f"{value:.0f}" for value in (low, high))
    return low if low == high else f"{low} to {high}"
