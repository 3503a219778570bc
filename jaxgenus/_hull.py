"""Target images: validation and the visual-hull bounds used to place the initial shape."""

from __future__ import annotations

import numpy as np

from jaxgenus._cameras import Cameras

__all__ = ["split_targets", "visual_hull_bounds"]


def split_targets(images, cams) -> tuple[np.ndarray, np.ndarray | None]:
    """Validate target `images` against `cams`; return `(alpha (N,H,W), normals (N,H,W,3) or None)`.

    `images` is `(N, H, W, 4)` RGBA in [0, 1] (RGB = (n + 1) / 2 world normals,
    A = silhouette) or `(N, H, W)` / `(N, H, W, 1)` alpha only. The input is not modified.
    """
    if not isinstance(cams, Cameras):
        raise ValueError(f"cams must be a jaxgenus.Cameras, got {type(cams).__name__}")
    img = np.asarray(images)
    if img.dtype == bool or not (np.issubdtype(img.dtype, np.floating) or np.issubdtype(img.dtype, np.integer)):
        raise ValueError(f"images must be a float array in [0, 1], got dtype {img.dtype}")
    if img.ndim == 3:
        img = img[..., None]
    if img.ndim != 4 or img.shape[-1] not in (1, 4):
        raise ValueError(f"images must have shape (N, H, W, 4), (N, H, W, 1) or (N, H, W), got {np.shape(images)}")
    n, h, w, _ = img.shape
    if n != len(cams):
        raise ValueError(f"images has {n} views but cams has {len(cams)}")
    if (h, w) != (cams.height, cams.width):
        raise ValueError(f"images are {h}x{w} but cams expect {cams.height}x{cams.width} (height x width)")
    img = img.astype(np.float32)
    if not np.all(np.isfinite(img)):
        raise ValueError("images contain NaN or inf pixels")
    if img.min() < 0.0 or img.max() > 1.0:
        raise ValueError(f"images must lie in [0, 1], got values in [{img.min():.3g}, {img.max():.3g}]")
    alpha = img[..., -1]
    empty = np.flatnonzero(alpha.reshape(n, -1).max(axis=1) < 0.5)
    if empty.size:
        raise ValueError(f"images: empty silhouettes (no alpha >= 0.5) in views {empty.tolist()}")
    normals = img[..., :3] * 2.0 - 1.0 if img.shape[-1] == 4 else None
    return alpha, normals


def visual_hull_bounds(alpha, cams: Cameras, *, resolution: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounds `(lo, hi)` of the visual hull of silhouettes `alpha (N, H, W)`.

    Carves a `resolution^3` grid spanning the region every camera sees (around
    the least-squares intersection of the optical axes): a point survives when it
    projects inside the silhouette (alpha >= 0.5) of every view. Host-side numpy.
    """
    alpha = np.asarray(alpha, np.float32)
    rot = np.asarray(cams.rotation, np.float64)
    trans = np.asarray(cams.translation, np.float64)
    centers = -np.einsum("nji,nj->ni", rot, trans)
    axes = rot[:, 2, :]
    # point closest to all optical axes: sum (I - d d^T) (p - c) = 0
    proj = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]
    a = proj.sum(0)
    b = np.einsum("nij,nj->i", proj, centers)
    centre = np.linalg.lstsq(a, b, rcond=None)[0]
    dist = np.linalg.norm(centers - centre, axis=1)
    half_fov = np.arctan(0.5 * min(cams.height, cams.width) / np.asarray(cams.focal).max())
    radius = float(dist.min() * np.sin(half_fov) * 1.05)
    ticks = np.linspace(-radius, radius, resolution)
    grid = np.stack(np.meshgrid(ticks, ticks, ticks, indexing="ij"), -1).reshape(-1, 3) + centre
    inside = np.ones(len(grid), bool)
    focal = np.asarray(cams.focal, np.float64)
    pp = np.asarray(cams.principal_point, np.float64)
    h, w = cams.height, cams.width
    for i in range(len(cams)):
        xc = grid @ rot[i].T + trans[i]
        z = np.maximum(xc[:, 2], 1e-9)
        u = np.floor(xc[:, 0] / z * focal[i, 0] + pp[i, 0]).astype(np.int64)
        v = np.floor(xc[:, 1] / z * focal[i, 1] + pp[i, 1]).astype(np.int64)
        ok = (xc[:, 2] > 1e-9) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        hit = np.zeros(len(grid), bool)
        hit[ok] = alpha[i, v[ok], u[ok]] >= 0.5
        inside &= hit
    if not inside.any():
        raise ValueError("images: the silhouettes are inconsistent with cams (their visual hull is empty)")
    cell = 2.0 * radius / (resolution - 1)
    pts = grid[inside]
    return pts.min(0) - cell, pts.max(0) + cell
