"""Reading and writing OpenEXR files (float32, named channels), atomically.

OpenEXR 3.x writes non-contiguous numpy slices silently wrong (OpenEXR issue 1929) and
rejects float64, so every channel is made a contiguous float32 array here, in one place.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rjfit.io import atomic_path

__all__ = ["write_exr", "read_exr"]


def write_exr(path, channels: dict[str, np.ndarray]) -> None:
    """Write named 2-D channels to ``path`` as float32 EXR; the file appears atomically.

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
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
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
    import OpenEXR

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such EXR file")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as exr_file:
            return {name: np.array(channel.pixels, dtype=np.float32)
                    for name, channel in exr_file.channels().items()}
    except Exception as error:  # OpenEXR raises bare RuntimeError/Exception on corrupt files
        raise ValueError(f"{path}: not a readable EXR file ({error})") from error
