"""Loading a measured object's mesh (PLY, OBJ, STL, ... via trimesh), with clear errors."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rjfit.errors import DatasetError, DatasetFileNotFoundError

__all__ = ["load_mesh"]


def load_mesh(path):
    """Load a triangle mesh as one ``trimesh.Trimesh``, unprocessed (vertices and normals as stored).

    A file holding several objects is concatenated into one mesh.

    Raises
    ------
    DatasetFileNotFoundError
        If ``path`` does not exist.
    DatasetError
        If trimesh cannot read it, it has no faces (a point cloud, or vertices only), or its
        vertices are not finite.
    """
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise DatasetFileNotFoundError(f"{path}: no such mesh file")
    try:
        loaded = trimesh.load(str(path), process=False)
        if isinstance(loaded, trimesh.Scene):  # several objects: one mesh, transforms applied
            vertex_count = sum(len(getattr(g, "vertices", ())) for g in loaded.geometry.values())
            loaded = trimesh.load(str(path), force="mesh", process=False) if loaded.geometry else loaded
        else:
            vertex_count = len(getattr(loaded, "vertices", ()))
    except Exception as error:  # trimesh raises ValueError, KeyError, ... depending on the format
        raise DatasetError(f"{path}: not a readable mesh ({type(error).__name__}: {error})") from error
    faces = getattr(loaded, "faces", None)
    if not isinstance(loaded, trimesh.Trimesh) or faces is None or len(faces) == 0:
        raise DatasetError(f"{path}: the mesh has no faces ({vertex_count} vertices, 0 triangles); a point "
                           f"cloud or a vertex list has no surface to render: export the triangles too")
    mesh = loaded
    vertices = np.asarray(mesh.vertices)
    if not np.isfinite(vertices).all():
        raise DatasetError(f"{path}: {int((~np.isfinite(vertices)).any(axis=1).sum())} vertices are NaN or Inf")
    return mesh
