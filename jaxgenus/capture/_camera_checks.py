"""Checks shared by the camera-file readers of `jaxgenus.capture._camera_files.load_cameras`.

Each reader (`_camera_files` for COLMAP, `_nerf_cameras`, `_krt_cameras`) turns
its file into `FileCamera`s in jaxgenus's convention and hands them to
`assemble_cameras`, which checks them (rotation orthonormal with det +1 within
1e-4, finite numbers, positive focal lengths, at least one camera) and stacks
them into `Cameras`. The helpers below read one image size for all cameras
(`check_image_size`, `resolve_size`, `image_file_size`), numbers and arrays from
the file with one-line errors naming the file and the camera (`whole_pixels`,
`finite_number`, `float_array`), and a pinhole from an upper-triangular K whose
skew moves no pixel by more than 0.05 px (`pinhole_from_K`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxgenus.geometry import Cameras

__all__ = [
    "IMAGE_SUFFIXES",
    "FileCamera",
    "assemble_cameras",
    "check_image_size",
    "finite_number",
    "float_array",
    "image_file_size",
    "pinhole_from_K",
    "resolve_size",
    "whole_pixels",
]

_ROT_TOL = 1e-4
_SKEW_TOL_PX = 0.05
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp")


class FileCamera(NamedTuple):
    """One camera as read from a file, before `assemble_cameras` checks it."""

    label: str  # for messages, e.g. "frame 3 ('./train/r_3')"
    name: str | None
    rotation: np.ndarray
    translation: np.ndarray
    focal: tuple[float, float]
    principal_point: tuple[float, float]  # jaxgenus convention (top-left pixel centre at 0.5)


def check_image_size(image_size):
    """`image_size` as `(height, width)` ints, or None; a ValueError unless positive whole pixels."""
    if image_size is None:
        return None
    try:
        h, w = image_size
        ok = all(float(v) == int(v) and int(v) > 0 for v in (h, w))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"image_size must be (height, width) in positive whole pixels, got {image_size!r}")
    return int(h), int(w)


def resolve_size(path: Path, own, image_size, probe=None) -> tuple[int, int]:
    """The image size: the file's own (checked against `image_size`), else `image_size`, else `probe()`."""
    if own is not None:
        if image_size is not None and tuple(image_size) != tuple(own):
            raise ValueError(f"{path}: image_size={tuple(image_size)} but the file says (height, width) = {tuple(own)}")
        return own
    if image_size is not None:
        return image_size
    found = probe() if probe is not None else None
    if found is None:
        raise ValueError(
            f"{path}: the file gives no image size and no image to read it from; pass image_size=(height, width)"
        )
    return found


def image_file_size(f: Path) -> tuple[int, int]:
    """`(height, width)` of an image file, read from its header."""
    from PIL import Image

    try:
        with Image.open(f) as im:
            w, h = im.size
    except OSError as err:
        raise ValueError(f"{f}: cannot read the image size ({err})") from None
    return h, w


def whole_pixels(path: Path, label: str, what: str, value) -> int:
    """`value` as a positive whole number of pixels, else a ValueError naming the file and camera."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if not (math.isfinite(v) and v == int(v) and v > 0):
        raise ValueError(f"{path}: {label}: {what} must be a positive whole number of pixels, got {value!r}")
    return int(v)


def finite_number(path: Path, label: str, what: str, value) -> float:
    """`value` as a finite float, else a ValueError naming the file and camera."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: {label}: {what} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{path}: {label}: {what} is not finite ({value!r})")
    return v


def float_array(path: Path, label: str, what: str, value, shape) -> np.ndarray:
    """`value` as a finite float64 array of `shape` (a 1-D shape also takes e.g. a 3x1 column)."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: {label}: {what} must be numbers of shape {shape}") from None
    if a.size == int(np.prod(shape)) and a.shape != shape and len(shape) == 1:
        a = a.reshape(shape)  # e.g. t given as a 3x1 column
    if a.shape != shape:
        raise ValueError(f"{path}: {label}: {what} must have shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{path}: {label}: {what} has non-finite values")
    return a


def pinhole_from_K(path: Path, label: str, K: np.ndarray, height: int, width: int):
    """`(fx, fy, cx, cy)` of an upper-triangular K (skew small enough is dropped)."""
    fx, fy = K[0, 0], K[1, 1]
    scale = max(abs(fx), abs(fy), 1.0)
    if abs(K[2, 2] - 1.0) > 1e-6 or max(abs(K[1, 0]), abs(K[2, 0]), abs(K[2, 1])) > 1e-9 * scale:
        raise ValueError(f"{path}: {label}: K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}")
    if not (fx > 0 and fy > 0):
        raise ValueError(f"{path}: {label}: focal lengths must be positive, got fx={fx:.6g}, fy={fy:.6g}")
    skew = K[0, 1]
    # Dropping s moves u by s*y/z; over the image |y/z| <= max(cy, H - cy) / fy.
    shift = abs(skew) * max(abs(K[1, 2]), abs(height - K[1, 2])) / fy
    if shift > _SKEW_TOL_PX:
        raise ValueError(
            f"{path}: {label}: K has skew {skew:.6g} (moves pixels by up to {shift:.3g} px); "
            "jaxgenus cameras have no skew"
        )
    return float(fx), float(fy), float(K[0, 2]), float(K[1, 2])


def assemble_cameras(path: Path, cams: list[FileCamera], height: int, width: int):
    """`(cameras, names)` of checked `FileCamera`s; names None unless every camera has one."""
    if not cams:
        raise ValueError(f"{path}: no cameras in the file")
    for c in cams:
        R, t = c.rotation, c.translation
        if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
            raise ValueError(f"{path}: {c.label}: the pose has non-finite values")
        dev = float(np.max(np.abs(R.T @ R - np.eye(3))))
        det = float(np.linalg.det(R))
        if dev > _ROT_TOL or abs(det - 1.0) > _ROT_TOL:
            raise ValueError(
                f"{path}: {c.label}: R is not a rotation (max |R^T R - I| = {dev:.3g}, det = {det:.6g}; "
                f"tolerance {_ROT_TOL:g})"
            )
        fx, fy = c.focal
        if not (math.isfinite(fx) and math.isfinite(fy) and fx > 0 and fy > 0):
            raise ValueError(
                f"{path}: {c.label}: focal lengths must be positive and finite, got fx={fx:.6g}, fy={fy:.6g}"
            )
        if not all(math.isfinite(v) for v in c.principal_point):
            raise ValueError(f"{path}: {c.label}: the principal point is not finite")
    dtype = jnp.result_type(float)
    cameras = Cameras(
        jnp.asarray(np.stack([c.rotation for c in cams]), dtype),
        jnp.asarray(np.stack([c.translation for c in cams]), dtype),
        jnp.asarray(np.array([c.focal for c in cams]), dtype),
        jnp.asarray(np.array([c.principal_point for c in cams]), dtype),
        int(height),
        int(width),
    )
    names = [c.name for c in cams]
    return cameras, (names if all(n is not None for n in names) else None)
