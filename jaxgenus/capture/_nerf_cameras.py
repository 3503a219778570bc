"""NeRF `transforms.json` cameras (Blender synthetic, instant-ngp, nerfstudio).

`read_transforms` for `jaxgenus.capture._camera_files.load_cameras`, whose docstring
describes the fields read: camera-to-world OpenGL poses (`transform_matrix`)
turned into jaxgenus's world-to-camera OpenCV ones, intrinsics at the top level
or per frame, pinhole cameras only. The centre of the top-left pixel is at
`(0.5, 0.5)`, as nerfstudio and instant-ngp read it: nothing is shifted.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from jaxgenus.capture._camera_checks import (
    IMAGE_SUFFIXES,
    FileCamera,
    assemble_cameras,
    finite_number,
    float_array,
    image_file_size,
    resolve_size,
    whole_pixels,
)

__all__ = ["read_transforms"]

_FOCAL_KEYS = ("fl_x", "fl_y", "camera_angle_x", "camera_angle_y")
_INTRINSIC_KEYS = _FOCAL_KEYS + ("cx", "cy", "w", "h", "camera_model", "is_fisheye")
_DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "k5", "k6", "p1", "p2")
_PINHOLE_MODELS = ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE", "PERSPECTIVE")
_GL_TO_CV = np.diag([1.0, -1.0, -1.0])


def _frame_image(path: Path, file_path) -> Path | None:
    if not isinstance(file_path, str):
        return None
    f = path.parent / file_path
    if f.is_file():
        return f
    if not f.suffix or f.suffix.lower() not in IMAGE_SUFFIXES:
        for ext in (".png", ".jpg", ".jpeg"):
            g = f.with_name(f.name + ext)
            if g.is_file():
                return g
    return None


def read_transforms(path: Path, spec: dict, image_size):
    """`(cameras, names)` of a parsed transforms.json `spec` read from `path`."""
    frames = spec["frames"]
    top = {k: spec[k] for k in _INTRINSIC_KEYS + _DISTORTION_KEYS if k in spec}
    merged = []
    for i, fr in enumerate(frames):
        if not isinstance(fr, dict):
            raise ValueError(f"{path}: frame {i}: expected an object with transform_matrix")
        base = dict(top)
        if any(k in fr for k in _FOCAL_KEYS):
            for k in _FOCAL_KEYS:
                base.pop(k, None)
        base.update({k: fr[k] for k in _INTRINSIC_KEYS + _DISTORTION_KEYS if k in fr})
        name = fr.get("file_path")
        label = f"frame {i}" + (f" ({name!r})" if name is not None else "")
        merged.append((label, fr, base))

    sizes = {}
    for label, _, intr in merged:
        if "w" in intr or "h" in intr:
            hw = (whole_pixels(path, label, "h", intr.get("h")), whole_pixels(path, label, "w", intr.get("w")))
            sizes.setdefault(hw, label)
    if len(sizes) > 1:
        listed = ", ".join(f"{label} {w}x{h}" for (h, w), label in sizes.items())
        raise ValueError(f"{path}: frames have different image sizes ({listed}); jaxgenus needs one image size")

    def probe():
        if not merged:
            return None
        f = _frame_image(path, merged[0][1].get("file_path"))
        return None if f is None else image_file_size(f)

    height, width = resolve_size(path, next(iter(sizes)) if sizes else None, image_size, probe)

    cams = []
    for label, fr, intr in merged:
        model = intr.get("camera_model")
        if model is not None and str(model).upper() not in _PINHOLE_MODELS:
            raise ValueError(f"{path}: {label}: camera_model {model!r} is not a pinhole; undistort the images first")
        if intr.get("is_fisheye"):
            raise ValueError(f"{path}: {label}: is_fisheye is set; jaxgenus needs pinhole cameras (undistort first)")
        bad = {k: v for k in _DISTORTION_KEYS if k in intr and (v := finite_number(path, label, k, intr[k])) != 0.0}
        if bad:
            coeffs = ", ".join(f"{k}={v:.6g}" for k, v in bad.items())
            raise ValueError(f"{path}: {label}: nonzero distortion ({coeffs}); undistort the images first "
                             "(e.g. colmap image_undistorter) and write a pinhole transforms.json")
        if "fl_x" in intr:
            fx = finite_number(path, label, "fl_x", intr["fl_x"])
        elif "camera_angle_x" in intr:
            fx = 0.5 * width / math.tan(0.5 * finite_number(path, label, "camera_angle_x", intr["camera_angle_x"]))
        else:
            raise ValueError(f"{path}: {label}: no focal length (fl_x or camera_angle_x)")
        if "fl_y" in intr:
            fy = finite_number(path, label, "fl_y", intr["fl_y"])
        elif "camera_angle_y" in intr:
            fy = 0.5 * height / math.tan(0.5 * finite_number(path, label, "camera_angle_y", intr["camera_angle_y"]))
        else:
            fy = fx
        cx = finite_number(path, label, "cx", intr.get("cx", width / 2.0))
        cy = finite_number(path, label, "cy", intr.get("cy", height / 2.0))
        if "transform_matrix" not in fr:
            raise ValueError(f"{path}: {label}: missing transform_matrix")
        m = np.asarray(fr["transform_matrix"], dtype=np.float64) if isinstance(fr["transform_matrix"], list) else None
        if m is None or m.shape not in ((4, 4), (3, 4)):
            raise ValueError(f"{path}: {label}: transform_matrix must be 4x4 (or 3x4)")
        m = float_array(path, label, "transform_matrix", m[:3], (3, 4))
        rot_c2w, centre = m[:, :3], m[:, 3]
        R = _GL_TO_CV @ rot_c2w.T
        cams.append(FileCamera(label, fr.get("file_path"), R, -R @ centre, (fx, fy), (cx, cy)))
    return assemble_cameras(path, cams, height, width)
