"""Per-face and per-vertex geometric operators on padded meshes."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from jaxgenus._mesh import Mesh

__all__ = ["face_normals", "vertex_normals"]


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
