"""Carving: the visible surface moves away from the camera where its normal contradicts the image.

A refit starts from a result that still covers concavities few cameras see (a
boot's shaft, an eye socket) with a cap the visual hull left: it lies in front
of the true surface, and a normal image alone pulls it nowhere, since moving a
flat cap down keeps its normal. But where the result contains the truth (on the
boot 96 % of the true points more than 0.01 from a fit lie inside it), a
visible point of the result that lies on the true surface is also the truth's
first hit along that ray, and there the two surfaces touch, so their normals
agree. A pixel whose rendered normal differs from the target normal by more than
`MIN_ANGLE_DEG` therefore shows a result point in free space, and the term moves
it along its view ray, away from the camera.

`carving_term` is a force, not a quantity to fit: its value is 0 and its
gradient is that of minus the mean over the pixels of `mask * depth`, with the
mask (target and render both fully covered, normals more than `MIN_ANGLE_DEG`
apart) held constant. A value of 0 keeps the loss history (and the verdict's
divergence test) that of the image terms. `LossWeights.carve` weighs it (0 by
default in `objective`); `reconstruct` sets it in refits of normal maps
(`ReconstructOptions.refit_carve`), and retries a carving refit that fits its
images worse without it.

The angle (37 degrees) and carving in refits only, not in the first fit (where it erodes
the well-seen surface), were measured: docs/results.md, "Carving in refits".
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

__all__ = ["MIN_ANGLE_DEG", "carving_term"]

#: A pixel is carved when its rendered and target normals are further apart than this.
MIN_ANGLE_DEG = math.degrees(math.acos(0.8))
_FULL = 0.99  # coverage above which a pixel is inside both silhouettes (not at an edge)


def carving_term(
    rendered: Float[Array, "N H W 4"], depth: Float[Array, "N H W"], target: Float[Array, "N H W 4"]
) -> Float[Array, ""]:
    """0, with the gradient of `-mean(mask * depth)` over the pixels (`mask` constant: target
    and rendered alpha > 0.99, rendered normal more than `MIN_ANGLE_DEG` from the target's).

    `rendered`: alpha then the world normal in [-1, 1] (`render(..., ("alpha", "normal"))`);
    `depth`: the same render's camera-space depth; `target`: RGBA normal maps, RGB the world
    normal mapped to `(n + 1) / 2`.
    """
    if rendered.shape != target.shape or rendered.shape[-1] != 4 or depth.shape != rendered.shape[:-1]:
        raise ValueError(f"rendered, depth, target must be (N, H, W, 4), (N, H, W), (N, H, W, 4); got "
                         f"{rendered.shape}, {depth.shape}, {target.shape}")
    n_r = rendered[..., 1:4]
    n_t = 2.0 * target[..., :3] - 1.0
    cos = jnp.sum(n_r * n_t, -1) / (jnp.linalg.norm(n_r, axis=-1) * jnp.linalg.norm(n_t, axis=-1) + 1e-6)
    full = (target[..., 3] > _FULL) & (rendered[..., 0] > _FULL)
    mask = jax.lax.stop_gradient(full & (cos < math.cos(math.radians(MIN_ANGLE_DEG))))
    return jnp.mean(jnp.where(mask, jax.lax.stop_gradient(depth) - depth, 0.0))
