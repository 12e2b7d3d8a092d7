"""The files of a photometric-stereo folder (DiLiGenT layout), read and checked one by one.

:func:`rjfit.data.diligent.load_diligent` puts them together into a Dataset; the mesh-stack
loader reads its images with :func:`read_raw_image` and :func:`check_depth` too. Every
reader names the file (and line) in its error.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from rjfit.data.checks import check_finite, check_radiance
from rjfit.data.codes import BITS, ENCODINGS, RESPONSES, read_codes
from rjfit.errors import DatasetError, DatasetFileNotFoundError
from rjfit.io import call_capturing_stderr

__all__ = ["require_file", "numbered_lines", "read_vectors", "size_text", "read_with_opencv", "read_raw_image",
           "check_depth", "read_mask", "find_normal_map", "read_normal_map", "check_reading", "read_images",
           "NORMAL_MAP_NAMES", "MAT_VARIABLES"]

NORMAL_MAP_NAMES = tuple(f"{stem}.{ext}" for stem in ("Normal_gt", "normals", "normal")
                         for ext in ("mat", "npy", "exr"))
MAT_VARIABLES = ("Normal_gt", "normals", "normal", "N")


# -- text files ---------------------------------------------------------------------------------

def require_file(path: Path, role: str) -> Path:
    if not path.is_file():
        raise DatasetFileNotFoundError(f"{path}: no such file (the {role} of a photometric-stereo folder)")
    return path


def numbered_lines(path: Path):
    """``(line_number, text)`` of the non-blank lines of a text file (1-based line numbers)."""
    try:
        text = path.read_text()
    except UnicodeDecodeError as error:
        raise DatasetError(f"{path}: not a text file ({error})") from error
    return [(number, line.strip()) for number, line in enumerate(text.splitlines(), start=1) if line.strip()]


def read_vectors(path: Path, widths, what):
    """Rows of numbers, one per non-blank line, each of one of ``widths`` lengths."""
    rows, numbers = [], []
    for number, line in numbered_lines(path):
        try:
            values = [float(token) for token in line.replace(",", " ").split()]
        except ValueError:
            raise DatasetError(f"{path} line {number}: expected numbers, got {line!r}") from None
        if len(values) not in widths:
            expected = " or ".join(str(w) for w in widths)
            raise DatasetError(f"{path} line {number}: expected {expected} numbers ({what}), got {len(values)}: "
                               f"{line!r}")
        if not np.all(np.isfinite(values)):
            raise DatasetError(f"{path} line {number}: {what} is NaN or Inf: {line!r}")
        rows.append(values)
        numbers.append(number)
    if not rows:
        raise DatasetError(f"{path}: the file is empty (no {what})")
    return rows, numbers


# -- images and maps ----------------------------------------------------------------------------

def size_text(array) -> str:
    return f"{array.shape[1]} x {array.shape[0]} (width x height)"


def read_with_opencv(path: Path) -> np.ndarray:
    """The file as OpenCV decodes it (unchanged depth and channels); a file it cannot decode is one
    line naming it, with the decoder's own message (libpng's, libtiff's) in it instead of before it."""
    import cv2

    image, messages = call_capturing_stderr(cv2.imread, str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        detail = f": {' '.join(messages.split())}" if messages else ""
        raise DatasetError(f"{path}: not a readable image (OpenCV could not decode it{detail})")
    if messages:        # decoded after all (a warning): the messages are the library's to show
        print(messages, file=sys.stderr)
    return image


def read_raw_image(path: Path) -> np.ndarray:
    """The image as stored: (H, W, 3) in R, G, B order, integer or float."""
    if path.suffix.lower() == ".exr":
        from rjfit.data.exr import read_exr

        channels = read_exr(path)
        if all(c in channels for c in "RGB"):
            return np.stack([channels[c] for c in "RGB"], axis=-1)
        if "Y" in channels:
            return np.repeat(channels["Y"][..., None], 3, axis=-1)
        raise DatasetError(f"{path}: needs channels R, G, B (or Y), has {sorted(channels)}")
    image = read_with_opencv(path)
    if image.ndim == 2:
        return np.repeat(image[..., None], 3, axis=-1)
    if image.shape[-1] != 3:
        raise DatasetError(f"{path}: has {image.shape[-1]} channels, expected 3 (RGB) or 1 (grey)")
    return image[..., ::-1]  # OpenCV reads BGR


def check_depth(raw: np.ndarray, path: Path, encoded, reference, response=None, bits=None):
    """The image's codes as declared (:func:`rjfit.data.codes.read_codes`: undeclared 8-bit data and
    8-bit codes in 16-bit files are refused), and its largest code; refuses mixed kinds of images."""
    codes, max_code = read_codes(raw, path, encoded, response, bits)
    if reference is not None and raw.dtype != reference[0]:
        raise DatasetError(f"{path}: pixels are {raw.dtype}, but {reference[1].name} holds {reference[0]}; every "
                           f"image of a stack must have one type (one unit)")
    return codes, max_code


def read_mask(path: Path) -> np.ndarray:
    """The object mask: pixels where any colour (or grey) channel is above half its range.

    The mask is drawn in colour (DiLiGenT's are 8-bit RGB, 0 or 255); an alpha channel is not
    part of it. OpenCV returns grey + alpha and RGBA files with the alpha last (4 channels,
    or 2 for a grey + alpha TIFF): that channel is set aside, so an opaque alpha does not
    select the whole frame. Where the alpha itself varies and marks other pixels than the
    colour does, the file is ambiguous and refused.
    """
    mask = read_with_opencv(path)
    if np.issubdtype(mask.dtype, np.floating):
        check_finite(mask, path)
    alpha = None
    if mask.ndim == 3 and mask.shape[-1] in (2, 4):
        mask, alpha = mask[..., :-1], mask[..., -1]
    above_half = (lambda values: values > 0.5) if np.issubdtype(mask.dtype, np.floating) else (
        lambda values: values > np.iinfo(mask.dtype).max // 2)
    selected = above_half(mask)
    selected = selected.any(axis=-1) if selected.ndim == 3 else selected
    if alpha is not None and (alpha != alpha.flat[0]).any():
        by_alpha = above_half(alpha)
        if not np.array_equal(by_alpha, selected):
            raise DatasetError(f"{path}: the mask's alpha channel marks {int(by_alpha.sum())} pixels but its colour "
                               f"channels mark {int(selected.sum())}; rjfit reads the colour (non-zero on the "
                               f"object), so save the mask without an alpha channel, as grey or RGB")
    return selected


def find_normal_map(folder: Path, normals) -> Path:
    if normals is not None:
        candidate = Path(normals)
        candidate = candidate if candidate.is_absolute() else folder / candidate
        return require_file(candidate, "normal map")
    for name in NORMAL_MAP_NAMES:
        if (folder / name).is_file():
            return folder / name
    raise DatasetFileNotFoundError(f"{folder}: no normal map (looked for {', '.join(NORMAL_MAP_NAMES)}); pass "
                                   f"normals=FILE to name one")


def read_normal_map(path: Path) -> np.ndarray:
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            normals = np.load(path, allow_pickle=False)
        # Broad on purpose: it wraps only this one read of the user's file, numpy documents no complete
        # list of what a bad file raises (ValueError, EOFError, OSError seen), and it is re-raised as a
        # DatasetError that names the file.
        except Exception as error:
            raise DatasetError(f"{path}: not a readable .npy file ({error})") from error
    elif suffix == ".mat":
        import scipy.io

        try:
            contents = scipy.io.loadmat(str(path))
        except NotImplementedError as error:  # MATLAB v7.3 files are HDF5
            raise DatasetError(f"{path}: MATLAB v7.3 (HDF5) file, which scipy cannot read; save it with "
                               f"-v7, or as .npy") from error
        # Broad on purpose: it wraps only this one read of the user's file, and scipy raises whatever its
        # parser hits on a corrupt one (MatReadError, ValueError, even IndexError for junk bytes); it is
        # re-raised as a DatasetError that names the file.
        except Exception as error:
            raise DatasetError(f"{path}: not a readable MATLAB file ({error})") from error
        variables = {k: v for k, v in contents.items() if not k.startswith("__")}
        named = [k for k in MAT_VARIABLES if k in variables]
        maps = [k for k, v in variables.items() if np.ndim(v) == 3 and np.shape(v)[-1] == 3]
        if named:
            normals = variables[named[0]]
        elif len(maps) == 1:
            normals = variables[maps[0]]
        else:
            raise DatasetError(f"{path}: cannot tell which variable holds the normals (expected one of "
                               f"{', '.join(MAT_VARIABLES)}; has {sorted(variables)})")
    elif suffix == ".exr":
        from rjfit.data.exr import read_exr

        channels = read_exr(path)
        for names in (("N.X", "N.Y", "N.Z"), ("X", "Y", "Z"), ("R", "G", "B")):
            if all(name in channels for name in names):
                normals = np.stack([channels[name] for name in names], axis=-1)
                break
        else:
            raise DatasetError(f"{path}: needs channels N.X N.Y N.Z (or X Y Z, or R G B), has {sorted(channels)}")
    else:
        raise DatasetError(f"{path}: unsupported normal map format {suffix!r} (use .npy, .mat or .exr; a PNG "
                           f"picture of normals is quantised and not unit length)")
    normals = np.asarray(normals)
    if normals.ndim != 3 or normals.shape[-1] != 3 or not np.issubdtype(normals.dtype, np.number):
        raise DatasetError(f"{path}: normal map must be a numeric (height, width, 3) array, got shape "
                           f"{normals.shape}, type {normals.dtype}")
    return normals.astype(np.float64)


# -- the loader ---------------------------------------------------------------------------------

def check_reading(folder: Path, encoded, response, bits) -> None:
    """The declared encoding, response and bit depth, checked alone and together (arguments bypass
    :func:`folder_options`)."""
    if encoded is not None and encoded not in ENCODINGS:
        raise DatasetError(f"{folder}: encoded must be None (linear data) or one of {ENCODINGS}, got {encoded!r}")
    if response is not None and response not in RESPONSES:
        raise DatasetError(f"{folder}: response must be None (known) or one of {RESPONSES}, got {response!r}")
    if bits is not None and bits not in BITS:
        raise DatasetError(f"{folder}: bits must be None (the files' own type) or one of {BITS}, got {bits!r}")
    if response == "unknown" and encoded is not None:
        raise DatasetError(f"{folder}: response='unknown' and encoded={encoded!r} contradict each other; declare "
                           f"one (encoded when the response is known, response='unknown' when it is not)")


def read_images(image_files, mask, mask_file, intensities, encoded, response, bits, saturation, dark):
    """Read the stack whole: check, take the declared codes, flag clipped and dark observations, decode,
    divide by the light's intensity.

    Returns ``(images, saturated, too_dark, threshold_used, pixel_type, max_code)``: float32 (L, H, W, 3),
    (L, H, W) flags, the saturation threshold applied (in codes), the files' pixel type and the largest
    code of the declared depth (None for float images).
    """
    height, width = mask.shape
    images = np.empty((len(image_files), height, width, 3), dtype=np.float32)
    saturated = np.zeros((len(image_files), height, width), dtype=bool)
    too_dark = None if dark is None else np.zeros((len(image_files), height, width), dtype=bool)
    reference, threshold_used, max_code = None, saturation, None
    for index, image_file in enumerate(image_files):
        raw = read_raw_image(image_file)
        if raw.shape[:2] != (height, width):
            raise DatasetError(f"{image_file}: image is {size_text(raw)}, but {mask_file.name} is {size_text(mask)}; the "
                               f"mask, the normal map and every image must have one size")
        codes, max_code = check_depth(raw, image_file, encoded, reference, response, bits)
        reference = reference or (raw.dtype, image_file)
        check_radiance(codes, image_file)
        threshold = saturation if saturation is not None else max_code
        if threshold is not None:
            saturated[index] = (codes >= threshold).any(axis=-1)
            threshold_used = threshold
        if too_dark is not None:
            too_dark[index] = (codes <= dark).all(axis=-1)
        if max_code is not None and encoded == "sRGB":
            import colour

            linear = colour.cctf_decoding(codes / float(max_code), "sRGB")
        else:
            linear = codes
        images[index] = linear / intensities[index]
    return images, saturated, too_dark, threshold_used, str(reference[0]), max_code
