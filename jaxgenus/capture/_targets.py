"""Target images of a reconstruction: validation, their kind, and what each stage needs of them.

A run's targets are `(N, H, W, C)` images in [0, 1], one per camera, row 0 at
the top. Their kind says what the channels mean:

* `"silhouette"`: `(N, H, W)` or `(N, H, W, 1)`, the object's coverage (mask).
* `"normals"`: `(N, H, W, 4)` RGBA with RGB = `(n + 1) / 2` of the world normal
  and A = coverage (what `render_targets` makes).
* `"photo"`: `(N, H, W, 4)` RGBA photographs, A = the object's mask, fitted
  through Lambertian shading with an unknown albedo and lighting (`_shading`).

For RGBA images the kind is inferred when not given (`infer_targets`: normal maps
are told from photos by the unit length of `2 RGB - 1`). The visual hull needs
only the silhouettes (`Targets.alpha`); the optimizer fits `Targets.fit` (alpha
alone, RGBA normal images, or photos with their colour premultiplied by A, as the
renderer composites its colour over black).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxgenus.geometry import Cameras
from jaxgenus.capture._images import infer_targets

__all__ = ["TARGET_KINDS", "Targets", "check_targets"]

TARGET_KINDS = ("silhouette", "normals", "photo")


class Targets(NamedTuple):
    """Validated targets (float32 copies; the caller's arrays are never modified).

    Attributes:
        kind: one of `TARGET_KINDS`.
        alpha: `(N, H, W)` coverage in [0, 1].
        normals: `(N, H, W, 3)` world normals in [-1, 1] (`"normals"` targets), else None.
        fit: the array the optimizer fits: `(N, H, W, 1)` alpha, `(N, H, W, 4)` RGBA normal
            images, or `(N, H, W, 4)` photos premultiplied by their alpha.
        inferred: the kind was inferred (not given).
    """

    kind: str
    alpha: np.ndarray
    normals: np.ndarray | None
    fit: np.ndarray
    inferred: bool = False


def check_targets(images, cams: Cameras, kind: str | None = None) -> Targets:
    """Validate target `images` against `cams` and return them as `Targets`.

    `images` is `(N, H, W, 4)` RGBA in [0, 1] (RGB = (n + 1) / 2 world normals,
    A = silhouette) or `(N, H, W)` / `(N, H, W, 1)` silhouettes. `kind` is one of
    `TARGET_KINDS` or None (inferred). Raises `ValueError` naming the problem
    (dtype, shape, view count, image size, NaN, range, empty silhouettes, a kind
    the images cannot be).
    """
    if kind is not None and kind not in TARGET_KINDS:
        raise ValueError(f"targets must be one of {TARGET_KINDS} or None, got {kind!r}")
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
    img = img.astype(np.float32)  # a copy
    if not np.all(np.isfinite(img)):
        raise ValueError("images contain NaN or inf pixels")
    if img.min() < 0.0 or img.max() > 1.0:
        raise ValueError(f"images must lie in [0, 1], got values in [{img.min():.3g}, {img.max():.3g}]")
    alpha = img[..., -1]
    empty = np.flatnonzero(alpha.reshape(n, -1).max(axis=1) < 0.5)
    if empty.size:
        raise ValueError(f"images: empty silhouettes (no alpha >= 0.5) in views {empty.tolist()}")
    if img.shape[-1] == 1:
        if kind not in (None, "silhouette"):
            raise ValueError(f"targets={kind!r} needs RGBA images (N, H, W, 4), got silhouettes {np.shape(images)}")
        return Targets("silhouette", alpha, None, img, kind is None)
    inferred = kind is None
    kind = infer_targets(img) if inferred else kind
    if kind == "normals":
        return Targets("normals", alpha, img[..., :3] * 2.0 - 1.0, img, inferred)
    if kind == "photo":
        return Targets("photo", alpha, None, np.concatenate([img[..., :3] * img[..., 3:], img[..., 3:]], -1), inferred)
    return Targets(kind, alpha, None, img[..., 3:], inferred)
