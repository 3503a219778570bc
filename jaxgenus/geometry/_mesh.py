"""The `Mesh` PyTree: triangle meshes in fixed-capacity buffers.

A mesh holds `vertices (Vcap, 3)` and `faces (Fcap, 3)` plus the live counts
`n_vertices` and `n_faces` (int32 scalars, so they can change inside `jit`).
Rows past the live counts are padding: padded vertices are zero and padded faces
are `(0, 0, 0)` -- a degenerate face on vertex 0 with zero area. Every function
in jaxgenus masks padding with `vertex_mask` / `face_mask`, so padding never
contributes to a render, an energy or a topology count.

`load_mesh` and `save_mesh` read and write meshes (OBJ, PLY, and whatever else trimesh reads).
"""

from __future__ import annotations

import math
import os

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

__all__ = ["Mesh", "capacity_bucket", "load_mesh", "save_mesh"]


def capacity_bucket(n_faces: int, *, minimum: int = 256) -> tuple[int, int]:
    """Return a `(vertex_capacity, face_capacity)` bucket that holds `n_faces` faces.

    Face capacities grow in steps of about 1.5x (`2^k` and `1.5 * 2^k`), so a mesh
    whose face count drifts during remeshing triggers few recompilations. The
    vertex capacity is `face_capacity // 2 + 2`, enough for any closed surface
    (V = F/2 + chi with chi <= 2).
    """
    n_faces = int(n_faces)
    if n_faces < 0:
        raise ValueError(f"n_faces must be >= 0, got {n_faces}")
    cap = minimum
    while cap < n_faces:
        half = cap // 2
        cap = cap + half if (cap & (cap - 1)) == 0 else 2 ** math.ceil(math.log2(cap))
    return cap // 2 + 2, cap


class Mesh(eqx.Module):
    """A triangle mesh in fixed-capacity buffers (a PyTree).

    Attributes:
        vertices: `(Vcap, 3)` float positions; rows `>= n_vertices` are zero.
        faces: `(Fcap, 3)` int32 vertex indices, counter-clockwise seen from
            outside; rows `>= n_faces` are `(0, 0, 0)`.
        n_vertices: int32 scalar, the number of live vertices.
        n_faces: int32 scalar, the number of live faces.
    """

    vertices: Float[Array, "V 3"]
    faces: Int[Array, "F 3"]
    n_vertices: Int[Array, ""]
    n_faces: Int[Array, ""]

    @classmethod
    def from_numpy(cls, vertices, faces, capacity=None) -> "Mesh":
        """Build a mesh from `(V, 3)` vertices and `(F, 3)` faces (copied, never modified).

        `capacity` is `None` (exactly the live size), an int face capacity (the
        vertex capacity is then `capacity // 2 + 2`, or V if larger), or a pair
        `(vertex_capacity, face_capacity)`. Vertices become float32 (float64 when
        jax x64 is on and the input is float64); faces become int32.
        """
        v = np.array(vertices, copy=True)
        f = np.array(faces, copy=True)
        if v.ndim != 2 or v.shape[1] != 3:
            raise ValueError(f"vertices must have shape (V, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3:
            raise ValueError(f"faces must have shape (F, 3), got {f.shape}")
        if not np.issubdtype(v.dtype, np.floating) and not np.issubdtype(v.dtype, np.integer):
            raise ValueError(f"vertices must be numeric, got dtype {v.dtype}")
        if not np.issubdtype(f.dtype, np.integer):
            raise ValueError(f"faces must be integer, got dtype {f.dtype}")
        if not np.all(np.isfinite(v)):
            raise ValueError("vertices contain NaN or inf")
        nv, nf = v.shape[0], f.shape[0]
        if nf and (f.min() < 0 or f.max() >= nv):
            raise ValueError(f"faces index out of range [0, {nv}): min {f.min()}, max {f.max()}")
        if nv >= 2**31 or nf >= 2**31:
            raise ValueError("mesh too large for int32 indices")
        if capacity is None:
            vcap, fcap = nv, nf
        elif isinstance(capacity, (int, np.integer)):
            fcap = int(capacity)
            vcap = max(fcap // 2 + 2, nv)
        else:
            vcap, fcap = (int(c) for c in capacity)
        if vcap < nv or fcap < nf:
            raise ValueError(
                f"capacity ({vcap}, {fcap}) is smaller than the mesh ({nv} vertices, {nf} faces)"
            )
        dtype = jnp.float64 if (jax.config.jax_enable_x64 and v.dtype == np.float64) else jnp.float32
        vp = np.zeros((vcap, 3), dtype=dtype)
        vp[:nv] = v
        fp = np.zeros((fcap, 3), dtype=np.int32)
        fp[:nf] = f
        return cls(
            vertices=jnp.asarray(vp),
            faces=jnp.asarray(fp),
            n_vertices=jnp.asarray(nv, jnp.int32),
            n_faces=jnp.asarray(nf, jnp.int32),
        )

    @property
    def vertex_capacity(self) -> int:
        return self.vertices.shape[-2]

    @property
    def face_capacity(self) -> int:
        return self.faces.shape[-2]

    @property
    def vertex_mask(self) -> Array:
        """`(Vcap,)` bool, True for live vertices."""
        return jnp.arange(self.vertex_capacity) < self.n_vertices

    @property
    def face_mask(self) -> Array:
        """`(Fcap,)` bool, True for live faces."""
        return jnp.arange(self.face_capacity) < self.n_faces

    def to_numpy(self) -> tuple[np.ndarray, np.ndarray]:
        """Return `(V, F)` numpy copies of the live part (not usable under `jit`)."""
        nv, nf = int(self.n_vertices), int(self.n_faces)
        return np.array(self.vertices[:nv]), np.array(self.faces[:nf])

    def to_trimesh(self):
        """Return the live part as a `trimesh.Trimesh` (no vertex merging, no processing)."""
        import trimesh

        v, f = self.to_numpy()
        return trimesh.Trimesh(vertices=v, faces=f, process=False)

    def with_capacity(self, capacity) -> "Mesh":
        """Return a copy of the live part in new buffers of `capacity` (see `from_numpy`)."""
        v, f = self.to_numpy()
        return Mesh.from_numpy(v, f, capacity=capacity)


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
