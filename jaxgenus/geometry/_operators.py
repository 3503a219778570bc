"""Geometric and linear operators on padded meshes: face/vertex normals and the
uniform (combinatorial) Laplacian.

`uniform_laplacian(faces, n_vertices)` returns `L = D - A` as a matrix-free
operator built from the face list. Every face contributes its three edges with
weight 1/2 to both end points; on a closed manifold each undirected edge lies in
exactly two faces, so every edge ends up with weight 1 (on an open surface
boundary edges get weight 1/2, and `L` stays symmetric positive semi-definite
either way). Self-loop edges `(i, i)` get weight 0: they contribute nothing to
`L`, and this masks padded faces `(0, 0, 0)` without needing the face count.
Padded vertices are therefore isolated: their rows of `L` are zero and their
rows of `I + lambda L` are the identity.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from jaxgenus.geometry._mesh import Mesh

__all__ = ["face_normals", "vertex_normals", "UniformLaplacian", "uniform_laplacian"]


def _safe_normalize(v: Array, eps: float) -> Array:
    """`v / |v|`, and exactly 0 (with a zero gradient) where `|v|^2 <= eps` (double where)."""
    n2 = jnp.sum(v * v, axis=-1, keepdims=True)
    ok = n2 > eps
    return jnp.where(ok, v * jnp.where(ok, n2, 1.0) ** -0.5, 0.0)


def _face_cross(mesh: Mesh) -> Array:
    tri = mesh.vertices[mesh.faces]
    n = jnp.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return jnp.where(mesh.face_mask[:, None], n, 0.0)


def _eps(mesh: Mesh) -> float:
    return float(jnp.finfo(mesh.vertices.dtype).tiny)


def face_normals(mesh: Mesh) -> Float[Array, "F 3"]:
    """Unit outward face normals `(Fcap, 3)`; zero for padded and zero-area faces."""
    return _safe_normalize(_face_cross(mesh), _eps(mesh))


def vertex_normals(mesh: Mesh) -> Float[Array, "V 3"]:
    """Area-weighted unit vertex normals `(Vcap, 3)`; zero for padded or isolated vertices."""
    n = _face_cross(mesh)  # length = twice the face area: area weighting
    acc = jnp.zeros_like(mesh.vertices)
    for k in range(3):
        acc = acc.at[mesh.faces[:, k]].add(n)
    acc = jnp.where(mesh.vertex_mask[:, None], acc, 0.0)
    return _safe_normalize(acc, _eps(mesh))


class UniformLaplacian(eqx.Module):
    """The combinatorial Laplacian `L = D - A` of a padded mesh (a PyTree, matrix-free).

    `L @ x` for `x` of shape `(Vcap, ...)` is `op(x)` (or `op @ x`); `degree` is
    the diagonal `D` (the valence of each live vertex on a closed manifold, 0 on
    padding).

    Attributes:
        edges: `(3 * Fcap, 2)` int32 directed edges `(a, b), (b, c), (c, a)` of every face.
        weights: `(3 * Fcap,)` 1/2 per edge, 0 for self-loops (padded faces).
        degree: `(Vcap,)` the diagonal of `L`.
    """

    edges: Int[Array, "E 2"]
    weights: Float[Array, " E"]
    degree: Float[Array, " V"]

    def __call__(self, x: Float[Array, "V ..."]) -> Float[Array, "V ..."]:
        i, j = self.edges[:, 0], self.edges[:, 1]
        w = self.weights.astype(x.dtype).reshape((-1,) + (1,) * (x.ndim - 1))
        diff = w * (x[i] - x[j])
        n = x.shape[0]
        return jax.ops.segment_sum(diff, i, n) - jax.ops.segment_sum(diff, j, n)

    def __matmul__(self, x):
        return self(x)

    def todense(self) -> Float[Array, "V V"]:
        """The dense `(Vcap, Vcap)` matrix (for tests and small meshes)."""
        n = self.degree.shape[0]
        return self(jnp.eye(n, dtype=self.degree.dtype))


def uniform_laplacian(faces: Int[Array, "F 3"], n_vertices: int) -> UniformLaplacian:
    """Build the uniform Laplacian of a (padded) triangle mesh from its faces.

    Args:
        faces: `(Fcap, 3)` int vertex indices; padded rows `(0, 0, 0)` are ignored.
        n_vertices: the number of rows of `L`, a Python int: the vertex
            capacity of a padded mesh (`mesh.vertex_capacity`). Vertices that no
            face references are isolated (zero rows).
    """
    faces = jnp.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"faces must have shape (F, 3), got {faces.shape}")
    if not jnp.issubdtype(faces.dtype, jnp.integer):
        raise ValueError(f"faces must be integer, got dtype {faces.dtype}")
    if isinstance(n_vertices, bool) or not isinstance(n_vertices, int) or n_vertices <= 0:
        raise ValueError(f"n_vertices must be a positive Python int (the vertex capacity), got {n_vertices!r}")
    faces = faces.astype(jnp.int32)
    edges = jnp.stack([faces, jnp.roll(faces, -1, axis=1)], axis=-1).reshape(-1, 2)
    weights = jnp.where(edges[:, 0] != edges[:, 1], 0.5, 0.0).astype(jnp.result_type(float))
    degree = jax.ops.segment_sum(weights, edges[:, 0], n_vertices) + jax.ops.segment_sum(
        weights, edges[:, 1], n_vertices
    )
    return UniformLaplacian(edges=edges, weights=weights, degree=degree)
