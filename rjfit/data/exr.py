"""Reading and writing OpenEXR files (float32, named channels), atomically.

OpenEXR 3.x writes non-contiguous numpy slices silently wrong (OpenEXR issue 1929) and
rejects float64, so every channel is made a contiguous float32 array here, in one place.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rjfit.io import atomic_path

__all__ = ["write_exr", "read_exr", "read_exr_attributes"]


def write_exr(path, channels: dict[str, np.ndarray], attributes: dict[str, str] | None = None) -> None:
    """Write named 2-D channels to ``path`` as float32 EXR; the file appears atomically.

    ``attributes`` (name -> string) go into the header as string attributes.

    Raises
    ------
    ValueError
        If the channels are not 2-D or differ in shape.
    """
    import OpenEXR

    path = Path(path)
    shapes = {name: np.shape(data) for name, data in channels.items()}
    if not channels or len(set(shapes.values())) != 1 or len(next(iter(shapes.values()))) != 2:
        raise ValueError(f"{path}: EXR channels must be 2-D arrays of one shape, got {shapes}")
    prepared = {name: np.ascontiguousarray(np.asarray(data, dtype=np.float32)) for name, data in channels.items()}
    header = {**{name: str(value) for name, value in (attributes or {}).items()},
              "compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path) as temporary:       # the project's one atomic writer (fsync, unique name)
        OpenEXR.File(header, prepared).write(str(temporary))


def read_exr(path) -> dict[str, np.ndarray]:
    """Read every channel of an EXR file as a float32 (H, W) array, keyed by channel name.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        If the file cannot be read as EXR.
    """
    return _read(path, lambda exr_file: {name: np.array(channel.pixels, dtype=np.float32)
                                         for name, channel in exr_file.channels().items()}, separate_channels=True)


def read_exr_attributes(path, prefix: str = "") -> dict[str, str]:
    """The string attributes of an EXR file's header whose names start with ``prefix``.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        If the file cannot be read as EXR.
    """
    return _read(path, lambda exr_file: {name: value for name, value in exr_file.header().items()
                                         if name.startswith(prefix) and isinstance(value, str)})


def _read(path, read, **open_options):
    """``read(OpenEXR.File)`` of the file at ``path``; the errors of :func:`read_exr`."""
    import OpenEXR

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such EXR file")
    try:
        with OpenEXR.File(str(path), **open_options) as exr_file:
            return read(exr_file)
    except Exception as error:  # OpenEXR raises bare RuntimeError/Exception on corrupt files
        raise ValueError(f"{path}: not a readable EXR file ({error})") from error
