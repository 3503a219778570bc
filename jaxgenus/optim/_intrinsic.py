"""Telling albedo from shading in photos: albedo edges and shading ratios.

**Albedo edges** (`albedo_edges`). The photometric term fits a per-vertex albedo,
blended flat over each face. An albedo edge (a printed line, the border of a painted
patch, a cell of a fine texture) runs through the faces, and a face cannot hold it:
within about a face of the edge the render's colour is a blend of the two sides, and the
photometric error there is not the shading's. Left in, it pulls the normals to make up
for the texture (on ray-cast photos of a high-frequency texture, photos fitted worse
than their silhouettes alone). So the photometric term leaves out the pixels within a
pixel of a jump between neighbouring pixels whose colour ratio, in any channel, is
beyond `EDGE_LOG_RATIO` (a jump that a smooth surface's shading does not make from one
pixel to the next: a normal turning by 5 degrees per pixel changes a lamp's light by
about 10 %). Cast shadows and the borders of highlights are left out with them, which
the model lacks anyway. Inside the albedo's patches the term works as before, and the
silhouette and photo-consistency terms are not touched (docs/results.md, "Albedo
edges").

**Shading ratios** (`shading_ratio_cost`). A matte photo is `albedo * E(n)`. Within a
patch of one albedo, the ratio of two nearby pixels is the ratio of their irradiance,
whatever that albedo is: `log I_p - log I_q = log E(n_p) - log E(n_q)`. Across an albedo
edge the ratio jumps by far more than shading changes over a few pixels. This term
compares, per colour channel, the log ratio of the photo over pixel pairs `offset`
pixels apart (along both image axes) with the log ratio of the render's irradiance, the
fitted lighting at the mesh's vertex normals interpolated over the faces (smooth, as a
photo of a smooth surface is: flat shading steps at every mesh edge where the photo
ramps, and the term then fits the steps). The cost of a residual `r` is the bounded
Geman-McClure `c r^2 / (r^2 + c^2)` with `c = scale`: pairs inside one albedo patch pull
the normals as shading does; pairs across an albedo edge, whose residual is large, pull
almost nothing. A texture finer than the mesh, which the per-vertex albedo cannot hold,
then no longer hides the shading (docs/results.md, "Shading ratios"). It is the
Retinex idea of intrinsic images (Land and McCann 1971), used as a loss on the normals.

Pairs count where both pixels are at least 2 px inside the rendered coverage and inside
the photo's mask, and neither photo value is dark (`MIN_LEVEL`) or clipped.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxgenus.optim._pyramid import window_reduce

__all__ = ["EDGE_LOG_RATIO", "MIN_LEVEL", "RATIO_BAND", "RATIO_OFFSET", "RATIO_SCALE", "albedo_edges",
           "shading_ratio_cost"]

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
        edge = window_reduce(edge, False, jax.lax.bitwise_or, size)
    return edge


#: Photo values below this carry too little light for a ratio (noise, the shadow of a dark albedo).
MIN_LEVEL = 0.02
#: The scale `c` of the bounded cost, in log-ratio units: albedo edges (ratios of 0.5-2) lie far beyond it.
RATIO_SCALE = 0.1
#: Pixels between the two of a pair.
RATIO_OFFSET = 3
#: The objective counts the pairs with a pixel within this many pixels of an albedo edge
#: (`albedo_edges(photos, band=RATIO_BAND)`): where the fitted albedo cannot follow the photo.
#: Elsewhere the photometric term sees the shading itself, and the ratios would add the lighting
#: model's own error (the order-4 harmonics' ripple, steep in the log where the light is low).
RATIO_BAND = 4
_COVER = 0.99
_HIGH = 254.5 / 255.0


def shading_ratio_cost(alpha: Float[Array, "N H W"], irradiance: Float[Array, "N H W 3"],
                       target: Float[Array, "N H W 4"], *, offset: int = RATIO_OFFSET,
                       scale: float = RATIO_SCALE, where: Bool[Array, "N H W"] | None = None
                       ) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """`(loss, pairs)`: the bounded cost of the log-ratio residuals (module doc) summed over the
    valid pixel pairs `offset` pixels apart along both image axes and over the colour channels,
    divided by the number of pixel-channels `N * H * W * 3` (as the image terms are, so the term
    does not grow with the resolution); and how many pairs counted.

    `alpha`: the render's coverage; `irradiance`: the rendered irradiance (composited over 0
    with the coverage, as the renderer's colour is); `target`: premultiplied RGBA photos;
    `where`: only pairs with a pixel here count (None: all)."""
    if not (isinstance(offset, int) and offset >= 1):
        raise ValueError(f"offset must be an int >= 1, got {offset!r}")
    if not scale > 0:
        raise ValueError(f"scale must be > 0, got {scale!r}")
    cover = jax.lax.stop_gradient(alpha)
    inner = window_reduce(cover, jnp.inf, jax.lax.min, 5) >= _COVER
    e = jnp.log(jnp.maximum(irradiance / jnp.maximum(alpha, _COVER)[..., None], MIN_LEVEL))
    mask = target[..., 3]
    rgb = target[..., :3] / jnp.maximum(mask, 1e-6)[..., None]
    ok = inner[..., None] & (mask >= 0.999)[..., None] & (rgb >= MIN_LEVEL) & (rgb < _HIGH)
    near = None if where is None else where[..., None]
    img = jnp.log(jnp.maximum(rgb, MIN_LEVEL))
    total, count = jnp.zeros((), e.dtype), jnp.zeros((), e.dtype)
    for axis in (1, 2):
        size = img.shape[axis]
        head = lambda x: jax.lax.slice_in_dim(x, offset, size, axis=axis)
        tail = lambda x: jax.lax.slice_in_dim(x, 0, size - offset, axis=axis)
        r = (head(e) - tail(e)) - (head(img) - tail(img))
        both = head(ok) & tail(ok)
        if near is not None:
            both = both & (head(near) | tail(near))
        both = both.astype(r.dtype)
        total = total + jnp.sum(both * scale * r * r / (r * r + scale * scale))
        count = count + jnp.sum(both)
    return total / float(img.size), count
