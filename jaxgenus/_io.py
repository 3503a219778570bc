"""Reading and writing meshes (OBJ, PLY, and whatever else trimesh reads)."""

from __future__ import annotations

import os

import numpy as np

from jaxgenus._mesh import Mesh

__all__ = ["load_mesh", "save_mesh"]


def load_mesh(path, *, capacity=None) -> Mesh:
    """Load a triangle mesh from `path` (OBJ, PLY, ...) exactly as stored.

    Vertices are not merged or reordered (so topology is what the file says);
    polygons are triangulated by trimesh. Raises `ValueError` for files without faces.
    """
    import trimesh

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ValueError(f"path: no such file: {path!r}")
    loaded = trimesh.load(path, process=False, force="mesh")
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise ValueError(f"path: {path!r} holds no triangle mesh")
    return Mesh.from_numpy(np.asarray(loaded.vertices), np.asarray(loaded.faces), capacity=capacity)


def save_mesh(mesh: Mesh, path) -> None:
    """Write the live part of `mesh` to `path`; the format follows the extension (.obj, .ply, ...)."""
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower().lstrip(".")
    if not ext:
        raise ValueError(f"path: cannot tell the format of {path!r} (no extension)")
    mesh.to_trimesh().export(path, file_type=ext)
