"""Images at their own resolution: pyramid levels and native-resolution crops.

A run on large images fits coarse, area-averaged copies of them first
(`pyramid_level`, cameras rescaled with `scaled_cameras`) and the images
themselves last, through random crops (`crop_views`), so that the cost of a
step is set by the pixels it renders, not by the size of the images.
`resolution_factors` gives each cycle's downsampling factor.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from jaxgenus.geometry import Cameras

__all__ = ["crop_views", "pyramid_level", "resolution_factors", "scaled_cameras", "step_views", "target_boxes",
           "window_reduce"]


def resolution_factors(height: int, width: int, n_cycles: int, coarse: int, native_cycles: int) -> list[int]:
    """Downsampling factor of each cycle: the last `native_cycles` cycles fit the images at their
    own resolution (factor 1); the others climb the pyramid from the power of two `F` that brings
    the longer side to about `coarse` pixels (at least 0.75 x coarse), halving the factor every
    cycle down to 2: F, F/2, ..., 2, 2 (1600 px, coarse 128, 4 cycles: 16, 8, 4, 1).
    `coarse = 0` or images already that small: 1 throughout."""
    side = max(height, width)
    if coarse <= 0 or side < 1.5 * coarse:
        return [1] * n_cycles
    f = max(2 ** int(math.floor(math.log2(side / (0.75 * coarse)))), 1)
    n_native = min(max(native_cycles, 0), n_cycles)
    return [max(f >> c, min(f, 2)) for c in range(n_cycles - n_native)] + [1] * n_native


def scaled_cameras(cams: Cameras, factor: int) -> Cameras:
    """The cameras of images downsampled by `factor` (pixel blocks of factor x factor;
    the last row/column of blocks may hang over the image, see `pyramid_level`)."""
    if factor == 1:
        return cams
    f = float(factor)
    return Cameras(
        cams.rotation, cams.translation, cams.focal / f, cams.principal_point / f,
        -(-cams.height // factor), -(-cams.width // factor),
    )


def pyramid_level(fit: np.ndarray, factor: int, *, normals: bool = True) -> np.ndarray:
    """Targets `(N, H, W, C)` (C = 1: alpha; C = 4: colour + alpha) averaged over
    `factor x factor` pixel blocks. Outside the image counts as background
    (alpha 0). Normal colours (`normals`) are averaged premultiplied by alpha, as
    the renderer composites normals over the background with its coverage; other
    colours (photos) are already premultiplied and are averaged as they are."""
    fit = np.asarray(fit)
    if factor == 1:
        return fit
    normals = normals and fit.shape[-1] == 4
    n, h, w, c = fit.shape
    if not normals and factor & (factor - 1) == 0:  # halvings: 1/4 of 1/4 is then 1/16 to the bit
        hh, ww, f = h, w, factor
        while f > 1:
            hh, ww, f = -(-hh // 2), -(-ww // 2), f // 2
        out = np.empty((n, hh, ww, c), np.float32)
        for i in range(n):  # a view at a time: the halvings' temporaries are one view's (all: 0.6 GB on DTU)
            level, f = np.asarray(fit[i:i + 1], np.float32), factor  # no copy of float32 targets
            while f > 1:
                level, f = _halved(level), f // 2
            out[i] = level[0]
        return out
    hh, ww = -(-h // factor), -(-w // factor)
    out = np.empty((n, hh, ww, c), np.float32)
    for i in range(n):  # a view at a time: no padded copy of the whole stack
        pad = np.zeros((1, hh * factor, ww * factor, c), np.float32)
        pad[:, :h, :w] = fit[i:i + 1]
        if normals:
            normal = 2.0 * pad[..., :3] - 1.0
            pad[..., :3] = pad[..., 3:4] * normal
        blocks = pad.reshape(1, hh, factor, ww, factor, c).mean(axis=(2, 4))
        if normals:
            blocks[..., :3] = 0.5 * (blocks[..., :3] + 1.0)
        out[i] = blocks[0]
    return out


def _halved(x: np.ndarray) -> np.ndarray:
    """`(N, H, W, C)` averaged over 2x2 blocks, an odd last row/column padded with zeros."""
    n, h, w, c = x.shape
    if h % 2 or w % 2:
        x = np.pad(x, ((0, 0), (0, h % 2), (0, w % 2), (0, 0)))
    out = x[:, 0::2, 0::2] + x[:, 1::2, 0::2]  # 0.25 * ((a + b) + (c + d)), two temporaries of the result's size
    out += x[:, 0::2, 1::2] + x[:, 1::2, 1::2]
    out *= np.float32(0.25) if out.dtype == np.float32 else 0.25
    return out


def target_boxes(targets: Float[Array, "N H W C"], margin: int) -> Int[Array, "N 4"]:
    """Per view `(row0, row1, col0, col1)`: the target's alpha > 0 bounding box grown
    by `margin` pixels and clipped to the image (the whole image when it is empty)."""
    alpha = targets[..., -1] > 0
    h, w = alpha.shape[1:]

    def span(any_, size):
        has = jnp.any(any_, axis=1)
        first = jnp.argmax(any_, axis=1)
        last = size - 1 - jnp.argmax(any_[:, ::-1], axis=1)
        lo = jnp.where(has, jnp.maximum(first - margin, 0), 0)
        hi = jnp.where(has, jnp.minimum(last + margin, size - 1), size - 1)
        return lo, hi

    r0, r1 = span(jnp.any(alpha, axis=2), h)
    c0, c1 = span(jnp.any(alpha, axis=1), w)
    return jnp.stack([r0, r1, c0, c1], axis=1).astype(jnp.int32)


def crop_views(key, cams: Cameras, targets, boxes, size: int):
    """A random `size x size` crop of every view (at most the image), centred at a
    uniform point of that view's box (`target_boxes`) and shifted to lie inside the
    image: returns the cropped `(cameras, targets)`."""
    n, h, w, c = targets.shape
    sh, sw = min(size, h), min(size, w)
    u = jax.random.uniform(key, (n, 2))
    cy = boxes[:, 0] + u[:, 0] * (boxes[:, 1] - boxes[:, 0] + 1)
    cx = boxes[:, 2] + u[:, 1] * (boxes[:, 3] - boxes[:, 2] + 1)
    oy = jnp.clip(jnp.floor(cy - sh / 2), 0, h - sh).astype(jnp.int32)
    ox = jnp.clip(jnp.floor(cx - sw / 2), 0, w - sw).astype(jnp.int32)
    crop = jax.vmap(lambda t, y, x: jax.lax.dynamic_slice(t, (y, x, 0), (sh, sw, c)))(targets, oy, ox)
    shift = jnp.stack([ox, oy], axis=1).astype(cams.principal_point.dtype)
    cropped = Cameras(cams.rotation, cams.translation, cams.focal, cams.principal_point - shift, sh, sw)
    return cropped, crop


def step_views(n_views: int, height: int, width: int, options) -> tuple[int, int]:
    """`(views, crop)` one step renders: `views` of the `n_views` cameras (all, or
    `options.views_per_step`), whole (`crop` 0) or through random `crop x crop` windows:
    `options.crop` when set, else the largest square that keeps the step within
    `options.max_pixels` when even one whole view holds more."""
    k = n_views if options.views_per_step is None else min(options.views_per_step, n_views)
    if options.crop:
        return k, options.crop if options.crop < max(height, width) else 0
    budget = options.max_pixels
    if budget is None or k * height * width <= budget:
        return k, 0
    if height * width <= budget:
        return budget // (height * width), 0
    return 1, math.isqrt(budget)


def window_reduce(x, init, op, size: int, stride: int = 1, padding: str = "SAME"):
    """`jax.lax.reduce_window` of `x (N, H, W)` over `size x size` windows (`stride` apart, "SAME" or
    "VALID"), as a pass along the rows and one along the columns: `2 size` operations a pixel instead
    of `size^2`. For max, min, or, and and exact; for a sum the same up to the order of the additions."""
    x = jax.lax.reduce_window(x, init, op, (1, size, 1), (1, stride, 1), padding)
    return jax.lax.reduce_window(x, init, op, (1, 1, size), (1, 1, stride), padding)
