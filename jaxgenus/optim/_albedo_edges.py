"""Where a photo changes more from one pixel to the next than shading can: albedo edges.

The photometric term fits a per-vertex albedo, blended flat over each face. An albedo
edge (a printed line, the border of a painted patch, a cell of a fine texture) runs
through the faces, and a face cannot hold it: within about a face of the edge the
render's colour is a blend of the two sides, and the photometric error there is not the
shading's. Left in, it pulls the normals to make up for the texture (on ray-cast photos
of a high-frequency texture, photos fitted worse than their silhouettes alone). So the
photometric term leaves out the pixels within a pixel of a jump between neighbouring
pixels whose colour ratio, in any channel, is beyond `EDGE_LOG_RATIO` (a jump that a
smooth surface's shading does not make from one pixel to the next: a normal turning
by 5 degrees per pixel changes a lamp's light by about 10 %). Cast shadows and the
borders of highlights are left out with them, which the model lacks anyway. Inside the
albedo's patches the term works as before, and the silhouette and photo-consistency
terms are not touched (docs/photometric.md, "Albedo edges").
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

__all__ = ["EDGE_LOG_RATIO", "albedo_edges"]

#: A jump of `|log(c_p / c_q)|` beyond this between neighbouring pixels, in any colour channel, is an edge.
EDGE_LOG_RATIO = 0.25
_DARK = 0.02  # colours are clamped to this before the log (noise in the dark makes no edge)
_INSIDE = 0.5  # only pairs inside the photo's mask count (its border is the silhouette's business)


def albedo_edges(photos: Float[Array, "N H W 4"], *, ratio: float = EDGE_LOG_RATIO,
                 band: int = 1) -> Bool[Array, "N H W"]:
    """`(N, H, W)` bool: the pixels within `band` pixels (a square) of a jump between horizontal or
    vertical neighbours, both inside the mask, whose colour ratio exceeds `exp(ratio)` in some
    channel (module doc). `photos` are premultiplied RGBA; no gradient flows."""
    if not ratio > 0:
        raise ValueError(f"ratio must be > 0, got {ratio!r}")
    if not (isinstance(band, int) and band >= 0):
        raise ValueError(f"band must be an int >= 0, got {band!r}")
    photos = jax.lax.stop_gradient(photos)
    alpha = photos[..., 3]
    log = jnp.log(jnp.maximum(photos[..., :3] / jnp.maximum(alpha, 1e-3)[..., None], _DARK))
    inside = alpha >= _INSIDE
    jump_u = (jnp.max(jnp.abs(log[:, :, 1:] - log[:, :, :-1]), axis=-1) > ratio) & inside[:, :, 1:] & inside[:, :, :-1]
    jump_v = (jnp.max(jnp.abs(log[:, 1:] - log[:, :-1]), axis=-1) > ratio) & inside[:, 1:] & inside[:, :-1]
    pad_u = lambda j, left: jnp.pad(j, ((0, 0), (0, 0), (1, 0) if left else (0, 1)))
    pad_v = lambda j, top: jnp.pad(j, ((0, 0), (1, 0) if top else (0, 1), (0, 0)))
    edge = pad_u(jump_u, True) | pad_u(jump_u, False) | pad_v(jump_v, True) | pad_v(jump_v, False)
    if band:
        size = 2 * band + 1
        edge = jax.lax.reduce_window(edge, False, jax.lax.bitwise_or, (1, size, size), (1, 1, 1), "SAME")
    return edge
