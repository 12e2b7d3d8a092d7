"""Integer pixel codes of measured images: bit depth, 8-bit data widened to 16 bits, encodings, quantisation.

A measured image is read whole (:func:`rjfit.data.diligent_files.read_raw_image`); this module
decides what its integer values mean before any other use:

- **Bit depth.** 16-bit files are linear sensor counts unless declared otherwise; an 8-bit
  file is read only when the folder says how (``encoded`` ``"sRGB"`` or ``"linear"``, or
  ``response`` ``"unknown"``), because a linear 16-bit stack re-saved by a tool that drops the
  low byte looks the same.
- **8-bit codes in 16-bit files.** The usual 8- to 16-bit conversions multiply by 257
  (``v * 65535 / 255``, i.e. ``v << 8 | v``) or by 256 (``v << 8``, the low byte always 0).
  Such a file holds only 256 levels; read as 16-bit counts its quantisation would be
  misstated 256-fold. It is refused unless the folder declares ``"bits": 8``, which divides
  the values back to 8-bit codes (every value must then be a multiple of 257, or of 256).
  ``"bits": 16`` declares the file's full 16 bits real and skips the detection.
- **Quantisation.** Rounding to integer codes adds an error uniform on one code step, of
  variance ``step^2 / 12`` with ``step = 1`` code (Widrow and Kollar, "Quantization Noise",
  2008): a known noise floor, recorded per light and channel on the Dataset in the stored
  units (raw codes divided by the light's intensity) for linear and raw (unknown-response)
  codes. sRGB-decoded values have a non-uniform step and no recorded floor.
"""
from __future__ import annotations

import numpy as np

from rjfit.data.formats import CHANNELS
from rjfit.errors import DatasetError

__all__ = ["ENCODINGS", "RESPONSES", "BITS", "QUANTISATION_VARIANCE_CODES", "widening_factor", "read_codes",
           "response_of", "channel_quantisation_variance"]

ENCODINGS = ("sRGB", "linear")
RESPONSES = ("unknown",)
BITS = (8, 16)
#: Variance of uniform quantisation in units of one code step squared: 1 / 12.
QUANTISATION_VARIANCE_CODES = 1.0 / 12.0
_OPTIONS_FILE = "rjfit.json"


def widening_factor(raw: np.ndarray) -> int | None:
    """257 or 256 when a 16-bit image holds 8-bit codes widened by that factor, else None.

    257: every value is a multiple of 257 (``v * 257``, the usual conversion); 256: the low
    byte is always 0 (``v << 8``). An image whose values are all 0 or the largest code tells
    nothing (None): a black or clipped frame is not evidence of 8-bit data.
    """
    if raw.dtype != np.uint16:
        return None
    informative = raw[(raw != 0) & (raw != np.iinfo(np.uint16).max)]
    if informative.size == 0:
        return None
    if not (informative % 257).any():
        return 257
    if not (informative & 0xFF).any():
        return 256
    return None


def response_of(encoded, response) -> str:
    """The camera response the folder declares: ``"unknown"``, ``"sRGB"`` or ``"linear"``."""
    if response == "unknown":
        return "unknown"
    return "sRGB" if encoded == "sRGB" else "linear"


def _declaration_hint() -> str:
    return (f"if its codes are linear, write {{\"encoded\": \"linear\"}} to {_OPTIONS_FILE} in its folder; if "
            f"sRGB-encoded, {{\"encoded\": \"sRGB\"}}; if the camera response is not known, "
            f"{{\"response\": \"unknown\"}}")


def read_codes(raw: np.ndarray, path, encoded, response, bits) -> tuple[np.ndarray, int | None]:
    """The image's values as codes of its declared bit depth, checked; and the largest code (None: float).

    Parameters
    ----------
    raw : ndarray
        The image as stored, (H, W, 3), integer or float.
    path : path-like
        The file, for messages.
    encoded : None, "sRGB" or "linear"
        As declared (see :mod:`rjfit.data.diligent`); None: linear 16-bit (or float) data.
    response : None or "unknown"
        ``"unknown"``: the codes are read as they are, whatever the response.
    bits : None, 8 or 16
        The declared depth of integer codes; None: the file's own type, with 8-bit data
        widened to 16 bits refused.

    Returns
    -------
    codes : ndarray
        ``raw``, or for ``bits=8`` in a 16-bit file the values divided back to 8-bit codes (uint8).
    max_code : int or None
        The largest code of the declared depth (255, 65535); None for float images.

    Raises
    ------
    DatasetError
        One line naming the file: an unsupported pixel type, a float image with an encoding or
        bit depth, 8-bit data with no declaration, 8-bit codes in a 16-bit file without
        ``"bits": 8``, or ``"bits": 8`` on values that are not widened 8-bit codes.
    """
    kind = raw.dtype
    floating = np.issubdtype(kind, np.floating)
    if not floating and kind not in (np.uint8, np.uint16):
        raise DatasetError(f"{path}: pixels are {kind}; expected 8- or 16-bit unsigned integers, or float")
    if floating:
        if encoded is not None or bits is not None:
            declared = f"encoded={encoded!r}" if encoded is not None else f"bits={bits!r}"
            raise DatasetError(f"{path}: float image, but {declared} was given; only integer images have "
                               f"codes to decode")
        return raw, None
    if kind == np.uint8 and bits == 16:
        raise DatasetError(f"{path}: 8-bit image, but bits=16 was declared; declare \"bits\": 8 (or leave it out)")
    codes = raw
    if kind == np.uint16 and bits != 16:
        factor = widening_factor(raw)
        if bits == 8:
            if factor is None:
                raise DatasetError(f"{path}: bits=8 was declared, but this 16-bit file is not 8-bit codes widened "
                                   f"by 257 or 256 (some values are multiples of neither); leave \"bits\" out to "
                                   f"read it as 16-bit")
            codes = (raw // factor).astype(np.uint8)
        elif factor is not None:
            how = ("every value is a multiple of 256, the low byte is always 0" if factor == 256 else
                   "every value is a multiple of 257: 8-bit codes times 257, the usual 8- to 16-bit conversion")
            raise DatasetError(f"{path}: 16-bit file holding 8-bit data ({how}); use the original 16-bit file, or "
                               f"declare \"bits\": 8 in {_OPTIONS_FILE} to read its 8-bit codes (with \"encoded\" "
                               f"or \"response\" saying what they are)")
    if codes.dtype == np.uint8 and encoded is None and response != "unknown":
        where = "8-bit image" if kind == np.uint8 else "8-bit codes (bits=8)"
        raise DatasetError(f"{path}: {where}, but linear data must have 16 bits per channel unless declared (the "
                           f"DiLiGenT layout stores 16-bit PNGs; a tool that drops the low byte, such as Pillow or "
                           f"imageio's default plugin, leaves 8 bits); use the original 16-bit file, or "
                           f"{_declaration_hint()} (or pass the option to load_dataset)")
    return codes, int(np.iinfo(codes.dtype).max)


def channel_quantisation_variance(dataset, channel: str = "mean") -> np.ndarray | None:
    """Per light, the quantisation noise variance of one channel's values in the Dataset's units.

    The colour channels' rounding errors are independent, so the mean of R, G and B has
    variance ``sum_c v_c / 9``, the luminance ``sum_c w_c^2 v_c`` with its BT.709 weights.

    Parameters
    ----------
    dataset : rjfit.data.dataset.Dataset
    channel : {"mean", "R", "G", "B", "luminance"}

    Returns
    -------
    ndarray of float64, shape (L,), or None
        None when the data set records no quantisation (float or sRGB-decoded images).

    Raises
    ------
    ValueError
        If ``channel`` is not one of :data:`rjfit.data.formats.CHANNELS`.
    """
    if channel not in CHANNELS:
        raise ValueError(f"channel must be one of {CHANNELS}, got {channel!r}")
    variance = getattr(dataset, "quantisation_variance", None)
    if variance is None:
        return None
    variance = np.asarray(variance, dtype=np.float64)
    if channel == "mean":
        return variance.sum(axis=-1) / 9.0
    if channel == "luminance":
        weights = np.asarray(dataset._channel_of(np.eye(3), "luminance"))  # each pure primary's luminance
        return variance @ (weights * weights)
    return variance[:, "RGB".index(channel)]
