"""What identifies a data set's content: the files a fit reads and a digest over them.

A validation, a fit and a diagnosis each record the digest of the data set they were made
from, so a later command can tell when the data set changed since.
"""
from __future__ import annotations

import hashlib
from pathlib import Path

from rjfit.data.diligent import folder_options
from rjfit.io import read_json

__all__ = ["dataset_files", "dataset_fingerprint"]


def dataset_files(dataset_dir) -> list:
    """Every file a fit of the data set reads, whatever its layout (the gate's fingerprint
    covers them all: a changed geometry or mesh must void a validation as a changed image does).

    rjfit layout: ``dataset.json``, its images, geometry, visibility, truth labels and meshes;
    mesh stack: ``stack.json``, its images and mesh; photometric-stereo folder: every file
    in it, plus a normal map its ``rjfit.json`` names elsewhere.
    """
    dataset_dir = Path(dataset_dir)
    if (dataset_dir / "dataset.json").is_file():
        meta = read_json(dataset_dir / "dataset.json")
        names = (["dataset.json"] + list(meta.get("images", []))
                 + [meta[key] for key in ("geometry", "visibility", "truth_labels") if meta.get(key)]
                 + [part["file"] for part in meta.get("meshes", [])])
        return [dataset_dir / name for name in names if (dataset_dir / name).is_file()]
    if (dataset_dir / "stack.json").is_file():
        meta = read_json(dataset_dir / "stack.json")
        names = ["stack.json"] + list(meta.get("images", [])) + ([meta["mesh"]] if meta.get("mesh") else [])
        return [dataset_dir / name for name in names if (dataset_dir / name).is_file()]
    files = sorted(p for p in dataset_dir.iterdir() if p.is_file())
    normals = folder_options(dataset_dir).get("normals")
    if normals and (dataset_dir / normals).is_file() and (dataset_dir / normals).parent != dataset_dir:
        files.append(dataset_dir / normals)
    return files


def dataset_fingerprint(dataset_dir) -> str:
    """SHA-256 over the names (relative to the folder) and bytes of :func:`dataset_files`."""
    dataset_dir = Path(dataset_dir)
    digest = hashlib.sha256()
    for file in dataset_files(dataset_dir):
        digest.update(str(file.relative_to(dataset_dir) if file.is_relative_to(dataset_dir) else file).encode())
        digest.update(file.read_bytes())
    return digest.hexdigest()
