"""Geometric energies of the objective (pure functions, padding-aware).

`bilaplacian_energy` is `tr(x^T L^2 x)` with the uniform Laplacian and
`inversion_penalty` is `sum_k min(0, det J_k)^2` against a rest shape. The image
term and the total objective that combines them live in `jaxgenus.optim._loss`.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxgenus.geometry._operators import uniform_laplacian

__all__ = ["bilaplacian_energy", "face_area_vectors", "inversion_penalty", "inverted_face_count"]


def bilaplacian_energy(vertices: Float[Array, "V 3"], faces: Int[Array, "F 3"]) -> Float[Array, ""]:
    """`tr(x^T L^2 x) = ||L x||^2` with the uniform Laplacian `L` (padding contributes nothing)."""
    lx = uniform_laplacian(faces, vertices.shape[0])(vertices)
    return jnp.sum(lx * lx)


def face_area_vectors(v: Float[Array, "V 3"], faces: Int[Array, "F 3"]) -> Float[Array, "F 3"]:
    """`(b - a) x (c - a)` per face: the normal scaled by twice the area (not normalized)."""
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    return jnp.cross(b - a, c - a)


def inversion_penalty(
    vertices: Float[Array, "V 3"], rest_vertices: Float[Array, "V 3"], faces: Int[Array, "F 3"]
) -> Float[Array, ""]:
    """`sum_k min(0, det J_k)^2` with `det J_k = (n_k . n_k_rest) / ||n_k_rest||^2`.

    `n = (b - a) x (c - a)`. `J_k` maps face k's rest shape (its shape at the
    last remesh) to its current shape, measured in its own plane: the penalty is 0
    while no face has flipped over relative to its rest orientation. Faces that
    are degenerate at rest (padding `(0, 0, 0)` among them) are ignored.
    """
    if vertices.shape != rest_vertices.shape:
        raise ValueError(f"rest_vertices must have shape {vertices.shape}, got {rest_vertices.shape}")
    n = face_area_vectors(vertices, faces)
    n0 = face_area_vectors(rest_vertices, faces)
    a2 = jnp.sum(n0 * n0, axis=-1)
    ok = a2 > jnp.finfo(a2.dtype).tiny
    det = jnp.where(ok, jnp.sum(n * n0, axis=-1) / jnp.where(ok, a2, 1.0), 0.0)
    return jnp.sum(jnp.minimum(det, 0.0) ** 2)


def inverted_face_count(
    vertices: Float[Array, "V 3"], rest_vertices: Float[Array, "V 3"], faces: Int[Array, "F 3"], face_mask: Bool[Array, "F"]
) -> Int[Array, ""]:
    """Number of live faces flipped (normal at or past 90 degrees) relative to their rest orientation.

    Faces degenerate at rest are not counted.
    """
    n, n0 = face_area_vectors(vertices, faces), face_area_vectors(rest_vertices, faces)
    nondegenerate = jnp.sum(n0 * n0, axis=-1) > 0
    return jnp.sum(face_mask & nondegenerate & (jnp.sum(n * n0, axis=-1) <= 0)).astype(jnp.int32)
