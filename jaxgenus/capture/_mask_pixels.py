"""Masks saved as colour pictures: whether an RGB(A) picture is a mask, and its grey values.

Published masks are often RGB PNGs of 0/255 (DTU's, with a few stray coloured pixels) or JPEGs
whose chroma is lossy; `mask_like` recognises them and `grey_mask` turns them into one channel.
"""

from __future__ import annotations

import numpy as np

__all__ = ["coloured", "grey_mask", "is_grey", "luminance", "mask_like"]


def is_grey(rgb: np.ndarray) -> bool:
    return np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 1], rgb[..., 2])


def mask_like(px: np.ndarray, fmt: str) -> bool:
    """An RGB(A) picture (raw integers) that is a mask saved in colour: its channels agree (exactly;
    within 10 % in a JPEG, whose chroma is lossy) but on a few stray pixels (DTU's masks have a
    handful of yellow ones), and almost every pixel is near black or white."""
    if not px.size:
        return False
    step = int(np.ceil(np.sqrt(px.shape[0] * px.shape[1] / (1 << 14))))  # a sample of at most 2^14 pixels
    if step > 1 and not _mask_like(px[::step, ::step], fmt):  # a photo fails on a sparse sample already
        return False
    return _mask_like(px, fmt)


def _mask_like(px: np.ndarray, fmt: str) -> bool:
    """`mask_like` on every pixel of `px`."""
    top = float(np.iinfo(px.dtype).max) if px.dtype.kind in "ui" else 1.0
    odd = coloured(px, 0.1 * top if fmt == "JPEG" else 0.0)
    if float(np.mean(odd)) > 0.01:
        return False
    v = px[..., 0].astype(np.float32)
    v[odd] = luminance(px[odd][:, :3].astype(np.float32))
    return float(np.mean((v < 0.1 * top) | (v > 0.9 * top))) >= 0.95


def coloured(px: np.ndarray, tolerance: float) -> np.ndarray:
    """`(H, W)`: pixels whose R, G, B differ by more than `tolerance`."""
    r, g, b = px[..., 0], px[..., 1], px[..., 2]
    if tolerance <= 0:
        return (r != g) | (g != b)
    hi = np.maximum(np.maximum(r, g), b).astype(np.float32)
    return hi - np.minimum(np.minimum(r, g), b) > tolerance


def grey_mask(px: np.ndarray) -> np.ndarray:
    """`(H, W, 1)` of a mask saved as RGB(A): the grey value; a stray coloured pixel is black or
    white by its luminance."""
    top = np.iinfo(px.dtype).max
    grey = px[..., 0].copy()
    odd = coloured(px, 0.0)
    grey[odd] = np.where(luminance(px[odd][:, :3].astype(np.float32)) >= 0.5 * top, top, 0)
    return grey[..., None]


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec. 601 luma of `(..., 3)`; exactly the channel value for greys."""
    if is_grey(rgb):
        return rgb[..., 0].astype(np.float32)
    return (rgb.astype(np.float64) @ np.array([0.299, 0.587, 0.114])).astype(np.float32)
