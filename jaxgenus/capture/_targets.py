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

__all__ = ["TARGET_KINDS", "Targets", "check_targets", "infer_targets", "inferred_targets", "unit_float"]

TARGET_KINDS = ("silhouette", "normals", "photo")
# normal-map test (infer_targets) over pixels with A >= 0.5, d = | ||2 rgb - 1|| - 1 |:
_NORMALS_MEDIAN = 0.05  # median of d below this,
_NORMALS_NEAR, _NORMALS_FRACTION = 0.15, 0.9  # >= 90 % of the pixels with d < 0.15,
_NORMALS_SPREAD = 0.05  # directions not all along one axis (a grey photo's lie on (1, 1, 1)),
_NORMALS_MIN_PIXELS = 64  # and enough pixels to tell


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


def unit_float(pixels) -> np.ndarray:
    """`pixels` in [0, 1] as float32: uint8 / 255, uint16 / 65535 (8- and 16-bit images as read),
    anything else as it is. Used a view at a time, so a stack of 8-bit photos is never held as floats."""
    arr = np.asarray(pixels)
    if arr.dtype in (np.uint8, np.uint16):
        return arr.astype(np.float32) / np.float32(255.0 if arr.dtype == np.uint8 else 65535.0)
    return np.asarray(arr, np.float32)


def inferred_targets(images: np.ndarray) -> tuple[str, str]:
    """`infer_targets` of an `(N, H, W, C)` stack, and why, in one line."""
    if images.shape[-1] == 1:
        return "silhouette", "silhouettes only"
    flat = unit_float(images.reshape(-1, 4)[:: images[..., 0].size // 4_000_000 + 1])  # a million covered pixels: plenty
    rgb = flat[flat[:, 3] >= 0.5, :3]
    rgb = rgb[:: len(rgb) // 1_000_000 + 1]
    if len(rgb) < _NORMALS_MIN_PIXELS:
        return "photo", f"only {len(rgb)} covered pixels, too few to tell a normal map"
    v = 2.0 * rgb.astype(np.float64) - 1.0
    length = np.linalg.norm(v, axis=-1)
    d = np.abs(length - 1.0)
    u = v / np.maximum(length, 1e-6)[:, None]
    med, near, spread = np.median(d), np.mean(d < _NORMALS_NEAR), np.linalg.eigvalsh(u.T @ u / len(u))[1]
    stats = f"median | |2 rgb - 1| - 1 | = {med:.3f}, {near:.0%} within {_NORMALS_NEAR}, direction spread {spread:.2f}"
    if med < _NORMALS_MEDIAN and near >= _NORMALS_FRACTION and spread > _NORMALS_SPREAD:
        return "normals", f"RGB reads as unit normals ({stats})"
    return "photo", f"RGB is not a normal map ({stats})"


def infer_targets(images) -> str:
    """What an image stack holds: `"silhouette"`, `"normals"` or `"photo"`.

    `(N, H, W)` / `(N, H, W, 1)` -> `"silhouette"`. For `(N, H, W, 4)` RGBA the pixels with A >= 0.5
    of all images are pooled, `v = 2 rgb - 1` and `d = | ||v|| - 1 |`. It is `"normals"` only when all
    hold: the median of d is below 0.05; at least 90 % of the pixels have d < 0.15 (anti-aliased edges
    and creases average normals to shorter vectors, 8-bit and JPEG quantisation add ~0.01-0.03: rendered
    sphere and torus targets give medians < 0.01 and > 97 %); the directions `v / ||v||` do not all lie
    along one axis (second eigenvalue of their mean outer product > 0.05; one view of a sphere gives
    0.25, a grey photo 0, as its v lie on the (1, 1, 1) diagonal even where a flat grey of 0.79 has
    ||v|| = 1); and at least 64 pixels are covered. Otherwise `"photo"`: shading spreads ||v|| far more
    (Lambert-shaded grey and textured photos give medians of 0.3-0.6), so a photo is not taken for a
    normal map, at the price of a single view of one flat face reading as a photo (give
    `targets="normals"`). World- and camera-space normal maps both read as normals.
    """
    arr = np.asarray(images)
    arr = arr[..., None] if arr.ndim == 3 else arr
    if arr.ndim != 4 or arr.shape[-1] not in (1, 4):
        raise ValueError(f"images: expected (N, H, W), (N, H, W, 1) or (N, H, W, 4), got {arr.shape}")
    return inferred_targets(arr)[0]


def check_targets(images, cams: Cameras, kind: str | None = None) -> Targets:
    """Validate target `images` against `cams` and return them as `Targets`.

    `images` is `(N, H, W, 4)` RGBA in [0, 1] (RGB = (n + 1) / 2 world normals,
    A = silhouette) or `(N, H, W)` / `(N, H, W, 1)` silhouettes; uint8 and uint16 images are read
    as value / 255 and / 65535, as image files are (`unit_float`). `kind` is one of
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
        raise ValueError(f"images must be a float array in [0, 1] (or uint8 / uint16 pixels), got dtype {img.dtype}")
    if img.ndim == 3:
        img = img[..., None]
    if img.ndim != 4 or img.shape[-1] not in (1, 4):
        raise ValueError(f"images must have shape (N, H, W, 4), (N, H, W, 1) or (N, H, W), got {np.shape(images)}")
    n, h, w, _ = img.shape
    if n != len(cams):
        raise ValueError(f"images has {n} views but cams has {len(cams)}")
    if (h, w) != (cams.height, cams.width):
        raise ValueError(f"images are {h}x{w} but cams expect {cams.height}x{cams.width} (height x width)")
    _check_values(img)
    empty = np.flatnonzero([unit_float(view[..., -1]).max() < 0.5 for view in img])
    if empty.size:
        scaled = f" ({img.dtype} images are read as value / {np.iinfo(img.dtype).max})" if img.dtype in (np.uint8, np.uint16) else ""
        raise ValueError(f"images: empty silhouettes (no alpha >= 0.5) in views {empty.tolist()}{scaled}")
    if img.shape[-1] == 1 and kind not in (None, "silhouette"):
        raise ValueError(f"targets={kind!r} needs RGBA images (N, H, W, 4), got silhouettes {np.shape(images)}")
    inferred = kind is None
    kind = "silhouette" if img.shape[-1] == 1 else infer_targets(img) if inferred else kind
    src = img[..., -1:] if kind == "silhouette" else img  # alpha alone for silhouettes of RGBA images
    fit = np.empty(src.shape, np.float32)  # written view by view (no temporary of the whole stack)
    for out, view in zip(fit, src):
        out[...] = unit_float(view)
        if kind == "photo":  # colour premultiplied by A
            out[..., :3] *= out[..., 3:]
    normals = fit[..., :3] * 2.0 - 1.0 if kind == "normals" else None
    return Targets(kind, fit[..., -1], normals, fit, inferred)


def _check_values(img: np.ndarray) -> None:
    """A `ValueError` unless every pixel of `img` is finite and in [0, 1]; view by view (no copy of the stack)."""
    lo, hi = np.inf, -np.inf
    for view in img:
        view = unit_float(view)
        if not np.all(np.isfinite(view)):
            raise ValueError("images contain NaN or inf pixels")
        lo, hi = min(lo, float(view.min())), max(hi, float(view.max()))
    if lo < 0.0 or hi > 1.0:
        raise ValueError(f"images must lie in [0, 1], got values in [{lo:.3g}, {hi:.3g}]")
