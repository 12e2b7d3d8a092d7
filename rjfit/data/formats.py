"""The names that identify rjfit's data set layouts on disk, shared by their writers, readers and checks."""
from __future__ import annotations

from pathlib import Path

__all__ = ["DATASET_FORMAT", "MESH_STACK_FORMAT", "MESH_STACK_FILE", "CHANNELS", "COLOUR", "COLOUR_CHANNELS", "is_mesh_stack_folder"]

DATASET_FORMAT = "rjfit-dataset/1"          # dataset.json of a rendered (or converted) data set
MESH_STACK_FORMAT = "rjfit-mesh-stack/1"    # stack.json of a measured stack with a mesh
MESH_STACK_FILE = "stack.json"
CHANNELS = ("mean", "R", "G", "B", "luminance")   # the grey values a fit can be given
COLOUR = "rgb"          # a joint fit of R, G and B (one segmentation, per-channel amplitudes and noise)
COLOUR_CHANNELS = ("R", "G", "B")


def is_mesh_stack_folder(path) -> bool:
    """Whether ``path`` holds a mesh stack description (``stack.json``)."""
    return (Path(path) / MESH_STACK_FILE).is_file()
