"""Camera files that store `K`, `R`, `t` with OpenCV's pixel convention.

Readers for `jaxgenus.capture._camera_files.load_cameras`, whose docstring describes
the fields read: OpenCV JSON (`read_opencv_json`), IDR/NeuS `cameras*.npz`
(`read_idr`; `P = K [R | t]` decomposed by RQ) and Middlebury `*_par.txt`
(`read_middlebury`). All three put the centre of the top-left pixel at
`(0, 0)`, so `cx, cy` get + 0.5 for jaxgenus's `(0.5, 0.5)`.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from jaxgenus.capture._camera_checks import (
    IMAGE_SUFFIXES,
    FileCamera,
    assemble_cameras,
    float_array,
    image_file_size,
    pinhole_from_K,
    resolve_size,
    whole_pixels,
)

__all__ = ["idr_indices", "read_idr", "read_idr_region", "read_middlebury", "read_opencv_json"]


def read_opencv_json(path: Path, spec: dict, image_size):
    """`(cameras, names)` of a parsed OpenCV cameras JSON `spec` read from `path`."""
    own = None
    if "height" in spec or "width" in spec:
        own = (
            whole_pixels(path, "top level", "height", spec.get("height")),
            whole_pixels(path, "top level", "width", spec.get("width")),
        )
    height, width = resolve_size(path, own, image_size)
    cams = []
    for i, c in enumerate(spec["cameras"]):
        if not isinstance(c, dict):
            raise ValueError(f"{path}: camera {i}: expected an object with K, R, t")
        name = c.get("name")
        label = f"camera {i}" + (f" ({name!r})" if name is not None else "")
        for key in ("K", "R", "t"):
            if key not in c:
                raise ValueError(f"{path}: {label}: missing {key!r} (expected K, R, t in the OpenCV convention)")
        K = float_array(path, label, "K", c["K"], (3, 3))
        R = float_array(path, label, "R", c["R"], (3, 3))
        t = float_array(path, label, "t", c["t"], (3,))
        fx, fy, cx, cy = pinhole_from_K(path, label, K, height, width)
        cams.append(FileCamera(label, None if name is None else str(name), R, t, (fx, fy), (cx + 0.5, cy + 0.5)))
    return assemble_cameras(path, cams, height, width)


def idr_indices(p: Path) -> list[int]:
    """The sorted `i` of the `world_mat_i` arrays in an .npz (empty when it has none or cannot be read)."""
    try:
        with np.load(p, allow_pickle=False) as z:
            keys = list(z.files)
    except (OSError, ValueError):
        return []
    return sorted(int(m.group(1)) for k in keys if (m := re.fullmatch(r"world_mat_(\d+)", k)))


def read_idr_region(path: Path) -> tuple[np.ndarray, float] | None:
    """The sphere `(centre, radius)` an IDR/NeuS `cameras*.npz` declares the object to lie in: the
    image of the unit sphere under `scale_mat_i` (`x_world = scale_mat @ x_normalized`; the smallest
    sphere holding it when the scale is not the same along every axis). None without `scale_mat_i`."""
    indices = idr_indices(path)
    with np.load(path, allow_pickle=False) as z:
        mats = [z[f"scale_mat_{i}"] for i in indices if f"scale_mat_{i}" in z.files]
    if not mats:
        return None
    label = f"scale_mat_{indices[0]}"
    S = float_array(path, label, "the matrix", mats[0], (4, 4))
    if any(np.shape(m) != (4, 4) or not np.allclose(m, S, rtol=1e-6, atol=0.0) for m in mats[1:]):
        raise ValueError(f"{path}: the scale_mat_i differ between views (expected one normalization for all)")
    if not np.allclose(S[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError(f"{path}: {label}: expected a last row 0 0 0 1, got {S[3].tolist()}")
    scales = np.linalg.svd(S[:3, :3], compute_uv=False)
    if not scales.min() > 1e-12 * max(scales.max(), 1e-300):
        raise ValueError(f"{path}: {label}: the 3x3 part is singular (a scale of 0)")
    return S[:3, 3].copy(), float(scales.max())


def _decompose_projection(path: Path, label: str, P: np.ndarray):
    """`K, R, t` with `P ~ K [R | t]`, `diag(K) > 0`, `K[2, 2] = 1`, `det R = +1`."""
    from scipy.linalg import rq

    M, p4 = P[:, :3], P[:, 3]
    det = np.linalg.det(M)
    if not abs(det) > 1e-12 * np.linalg.norm(M) ** 3:
        raise ValueError(f"{path}: {label}: the 3x3 part of the projection matrix is singular")
    if det < 0:  # P is only defined up to scale; pick the sign that gives det R = +1
        M, p4 = -M, -p4
    upper, Q = rq(M)
    S = np.diag(np.sign(np.diag(upper)))
    K, R = upper @ S, S @ Q
    t = np.linalg.solve(K, p4)
    return K / K[2, 2], R, t


def _first_image_in(folder: Path):
    if not folder.is_dir():
        return None
    files = sorted(f for f in folder.iterdir() if f.suffix.lower() in IMAGE_SUFFIXES)
    return image_file_size(files[0]) if files else None


def read_idr(path: Path, image_size):
    """`(cameras, None)` of an IDR/NeuS `cameras*.npz`, in `world_mat_i` index order."""
    indices = idr_indices(path)
    def probe():  # IDR and NeuS keep the images in image/ beside the npz
        return _first_image_in(path.parent / "image") or _first_image_in(path.parent / "images")

    height, width = resolve_size(path, None, image_size, probe)
    cams = []
    with np.load(path, allow_pickle=False) as z:
        for i in indices:
            label = f"world_mat_{i}"
            P = np.asarray(z[label], dtype=np.float64)
            if P.shape not in ((4, 4), (3, 4)):
                raise ValueError(f"{path}: {label}: expected a 4x4 or 3x4 matrix, got shape {P.shape}")
            P = float_array(path, label, label, P[:3], (3, 4))
            K, R, t = _decompose_projection(path, label, P)
            fx, fy, cx, cy = pinhole_from_K(path, label, K, height, width)
            cams.append(FileCamera(label, None, R, t, (fx, fy), (cx + 0.5, cy + 0.5)))
    return assemble_cameras(path, cams, height, width)


def read_middlebury(path: Path, image_size):
    """`(cameras, names)` of a Middlebury `*_par.txt`, in file order."""
    lines = [(n + 1, ln.split()) for n, ln in enumerate(path.read_text().splitlines()) if ln.strip()]
    if not lines or len(lines[0][1]) != 1 or not lines[0][1][0].isdigit():
        raise ValueError(f"{path}: the first line must be the number of images")
    count, rows = int(lines[0][1][0]), lines[1:]
    if count != len(rows):
        raise ValueError(f"{path}: the first line says {count} images but {len(rows)} follow")

    def probe():  # the first named image, beside the file or in image/ or images/ (a capture folder)
        named = [path.parent / d / rows[0][1][0] for d in ("", "image", "images")] if rows else []
        return next((image_file_size(f) for f in named if f.is_file()), None)

    height, width = resolve_size(path, None, image_size, probe)
    cams = []
    for lineno, tok in rows:
        label = f"image {tok[0]!r} (line {lineno})"
        if len(tok) != 22:
            raise ValueError(f"{path}: {label}: expected name + 21 numbers (K, R, t), got {len(tok) - 1} numbers")
        try:
            vals = np.array([float(x) for x in tok[1:]])
        except ValueError:
            raise ValueError(f"{path}: {label}: not numbers") from None
        K = float_array(path, label, "K", vals[0:9].reshape(3, 3), (3, 3))
        R = float_array(path, label, "R", vals[9:18].reshape(3, 3), (3, 3))
        t = float_array(path, label, "t", vals[18:21], (3,))
        fx, fy, cx, cy = pinhole_from_K(path, label, K, height, width)
        cams.append(FileCamera(label, tok[0], R, t, (fx, fy), (cx + 0.5, cy + 0.5)))
    return assemble_cameras(path, cams, height, width)
