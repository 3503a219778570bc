"""A tiny dense soft silhouette used only by the optimizer tests (not the library's renderer).

Every (pixel, face) pair: D = sigmoid(min signed edge distance / sharpness) of the
projected triangle, alpha = 1 - prod(1 - D). O(pixels x faces); for tiny meshes.
"""

import jax
import jax.numpy as jnp

from jaxgenus import project


def soft_silhouette(mesh, cameras, *, channels=("alpha",), sharpness=0.7):
    if tuple(channels) != ("alpha",):
        raise ValueError("the test silhouette renders alpha only")
    uv = project(cameras, mesh.vertices)  # (N, V, 2)
    tri = uv[:, mesh.faces]  # (N, F, 3, 2)
    a, b, c = tri[:, :, 0], tri[:, :, 1], tri[:, :, 2]
    area = (b - a)[..., 0] * (c - a)[..., 1] - (b - a)[..., 1] * (c - a)[..., 0]
    live = mesh.face_mask[None] & (jnp.abs(area) > 1e-9)
    sign = jnp.where(area >= 0, 1.0, -1.0)
    h, w = cameras.height, cameras.width
    py, px = jnp.meshgrid(jnp.arange(h) + 0.5, jnp.arange(w) + 0.5, indexing="ij")
    p = jnp.stack([px, py], -1).reshape(-1, 2)  # (P, 2)

    def edge(e0, e1):
        d = e1 - e0
        ln = jnp.sqrt(jnp.maximum(jnp.sum(d * d, -1), 1e-12))
        cr = d[..., None, 0] * (p[None, None, :, 1] - e0[..., None, 1]) - d[..., None, 1] * (
            p[None, None, :, 0] - e0[..., None, 0]
        )
        return sign[..., None] * cr / ln[..., None]

    dist = jnp.minimum(jnp.minimum(edge(a, b), edge(b, c)), edge(c, a))  # (N, F, P)
    log1m = jnp.where(live[..., None], -jax.nn.softplus(dist / sharpness), 0.0)
    alpha = 1.0 - jnp.exp(jnp.sum(log1m, axis=1))
    return alpha.reshape(len(cameras), h, w, 1)
