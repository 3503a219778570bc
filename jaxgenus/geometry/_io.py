"""Reading and writing meshes (OBJ, PLY, and whatever else trimesh reads)."""

from __future__ import annotations

import os

import numpy as np

from jaxgenus.geometry._mesh import Mesh

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


def save_mesh(mesh: Mesh, path, *, vertex_colors=None) -> None:
    """Write the live part of `mesh` to `path`; the format follows the extension (.obj, .ply, ...).

    `vertex_colors`: optional `(V, 3)` RGB in [0, 1] per live vertex (e.g.
    `Reconstruction.albedo`), clipped to [0, 1] and written as 8-bit vertex colours
    (PLY: `red green blue` vertex properties; OBJ: `v x y z r g b`).
    """
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower().lstrip(".")
    if not ext:
        raise ValueError(f"path: cannot tell the format of {path!r} (no extension)")
    tm = mesh.to_trimesh()
    if vertex_colors is not None:
        c = np.asarray(vertex_colors, np.float64)
        if c.shape != (len(tm.vertices), 3) or not np.all(np.isfinite(c)):
            raise ValueError(f"vertex_colors must be finite with shape ({len(tm.vertices)}, 3), got {c.shape}")
        rgba = np.concatenate([np.round(np.clip(c, 0.0, 1.0) * 255.0), np.full((len(c), 1), 255.0)], axis=1)
        tm.visual.vertex_colors = rgba.astype(np.uint8)
    tm.export(path, file_type=ext)
