"""Procedural meshes for the built-in scenes, each part carrying one material index.

Every generator returns a list of ``(trimesh.Trimesh, material_index)`` parts with exact
(analytic) vertex normals, so that Mitsuba's shading normals are the true surface normals.
"""
from __future__ import annotations

import numpy as np

__all__ = ["sphere_quadrants", "dented_slab", "build_parts", "split_by_face_label"]


def _trimesh(vertices, faces, normals):
    import trimesh

    return trimesh.Trimesh(vertices=vertices, faces=faces, vertex_normals=normals, process=False)


def split_by_face_label(vertices, faces, normals, face_labels):
    """One mesh per label, holding only the vertices its faces use."""
    parts = []
    for label in np.unique(face_labels):
        part_faces = faces[face_labels == label]
        used, remapped = np.unique(part_faces, return_inverse=True)
        parts.append((_trimesh(vertices[used], remapped.reshape(-1, 3), normals[used]), int(label)))
    return parts


def sphere_quadrants(radius=1.0, n_longitude=256, n_latitude=128, materials=(0, 1, 2, 3)):
    """A UV sphere (poles on the y axis) cut into four parts by the planes x = 0 and y = 0.

    ``materials`` gives the material index of the parts (upper left, lower left, upper
    right, lower right) as seen by a camera on the +z axis with +y up, which sees +x on
    the right. ``n_longitude`` must be a multiple of 4 and ``n_latitude`` even so that no
    triangle straddles a cutting plane.
    """
    if n_longitude % 4 or n_latitude % 2:
        raise ValueError("n_longitude must be a multiple of 4 and n_latitude even")
    theta = np.linspace(0.0, np.pi, n_latitude + 1)           # polar angle from +y
    phi = np.linspace(0.0, 2.0 * np.pi, n_longitude + 1)       # azimuth about y, 0 at +z
    theta_grid, phi_grid = np.meshgrid(theta, phi, indexing="ij")
    normals = np.stack([np.sin(theta_grid) * np.sin(phi_grid), np.cos(theta_grid),
                        np.sin(theta_grid) * np.cos(phi_grid)], axis=-1).reshape(-1, 3)
    vertices = radius * normals
    ring = n_longitude + 1
    i, j = np.meshgrid(np.arange(n_latitude), np.arange(n_longitude), indexing="ij")
    a, b, c, d = i * ring + j, i * ring + j + 1, (i + 1) * ring + j, (i + 1) * ring + j + 1
    # Counter-clockwise seen from outside; degenerate triangles at the poles are dropped.
    faces = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    area2 = np.linalg.norm(np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]],
                                    vertices[faces[:, 2]] - vertices[faces[:, 0]]), axis=1)
    faces = faces[area2 > 1e-12 * radius * radius]
    centroid = vertices[faces].mean(axis=1)
    upper, right = centroid[:, 1] > 0, centroid[:, 0] > 0
    quadrant = np.where(upper, np.where(right, 2, 0), np.where(right, 3, 1))
    face_labels = np.asarray(materials)[quadrant]
    return split_by_face_label(vertices, faces, normals, face_labels)


def dented_slab(size=2.0, resolution=200, dents=(), grooves=(), boundary_x=0.0, materials=(0, 1), material_map=None):
    """A square height field ``z = h(x, y)`` with Gaussian dents and grooves (concave).

    ``dents`` are ``(x, y, depth, width)`` tuples, ``grooves`` ``(x, depth, width)`` tuples
    of grooves along y. Faces left of ``boundary_x`` get ``materials[0]``, the others
    ``materials[1]``; the grid has a vertex column on the boundary so no face straddles it.

    ``material_map`` (optional): a material index image (rows from y = +size/2 down to
    -size/2, columns from x = -size/2 to +size/2), mapped onto the slab by its (x, y)
    texture coordinates: each face takes the index of the texel under its centroid
    (nearest texel), and ``materials[index]`` is its material. With a fine grid
    (``resolution`` several times the map's size) boundaries follow the map to within a
    grid cell; the rendered truth labels are the faces' materials as the camera sees them.
    """
    half = size / 2.0
    x = np.unique(np.concatenate([np.linspace(-half, half, resolution + 1), [boundary_x]]))
    y = np.linspace(-half, half, resolution + 1)
    x_grid, y_grid = np.meshgrid(x, y, indexing="xy")
    height = np.zeros_like(x_grid)
    dh_dx = np.zeros_like(x_grid)
    dh_dy = np.zeros_like(x_grid)
    for cx, cy, depth, width in dents:
        bump = -depth * np.exp(-((x_grid - cx) ** 2 + (y_grid - cy) ** 2) / (2 * width ** 2))
        height += bump
        dh_dx += bump * -(x_grid - cx) / width ** 2
        dh_dy += bump * -(y_grid - cy) / width ** 2
    for cx, depth, width in grooves:
        bump = -depth * np.exp(-((x_grid - cx) ** 2) / (2 * width ** 2))
        height += bump
        dh_dx += bump * -(x_grid - cx) / width ** 2
    vertices = np.stack([x_grid, y_grid, height], axis=-1).reshape(-1, 3)
    normals = np.stack([-dh_dx, -dh_dy, np.ones_like(height)], axis=-1).reshape(-1, 3)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    n_x = x.size
    i, j = np.meshgrid(np.arange(y.size - 1), np.arange(n_x - 1), indexing="ij")
    a, b, c, d = i * n_x + j, i * n_x + j + 1, (i + 1) * n_x + j, (i + 1) * n_x + j + 1
    faces = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    centroid_x = vertices[faces, 0].mean(axis=1)
    if material_map is not None:
        texels = np.asarray(material_map, np.int64)
        centroid_y = vertices[faces, 1].mean(axis=1)
        col = np.clip(((centroid_x + half) / size * texels.shape[1]).astype(np.int64), 0, texels.shape[1] - 1)
        row = np.clip(((half - centroid_y) / size * texels.shape[0]).astype(np.int64), 0, texels.shape[0] - 1)
        return split_by_face_label(vertices, faces, normals, np.asarray(materials)[texels[row, col]])
    face_labels = np.where(centroid_x < boundary_x, materials[0], materials[1])
    return split_by_face_label(vertices, faces, normals, face_labels)


GENERATORS = {"sphere_quadrants": sphere_quadrants, "dented_slab": dented_slab}


def build_parts(geometry: dict):
    """Run the generator named by a scene's ``geometry`` entry with its arguments.

    Raises
    ------
    ValueError
        If the generator is unknown.
    """
    arguments = dict(geometry)
    name = arguments.pop("generator", None)
    if name not in GENERATORS:
        raise ValueError(f"unknown geometry generator {name!r}; known: {sorted(GENERATORS)}")
    for key, value in arguments.items():
        if isinstance(value, list):
            arguments[key] = tuple(tuple(v) if isinstance(v, list) else v for v in value)
    return GENERATORS[name](**arguments)
