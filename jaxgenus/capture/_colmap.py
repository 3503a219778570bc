"""COLMAP sparse models (text and binary), read for `jaxgenus.capture._camera_files.load_cameras`.

A sparse model is a folder with `cameras.{bin,txt}` and `images.{bin,txt}` (plus
`points3D`, and in COLMAP >= 3.12 `rigs` and `frames`, which are not needed
here: every registered image still carries its own world-to-camera pose). When
a folder has both, the binary pair is read, as COLMAP does.

Binary layout (little-endian; COLMAP's `reconstruction_io_binary.cc`):

* `cameras.bin`: `uint64` count, then per camera `uint32` camera_id,
  `int32` model_id, `uint64` width, `uint64` height and the model's
  `float64` parameters.
* `images.bin`: `uint64` count, then per image `uint32` image_id,
  `float64` qw qx qy qz, `float64` tx ty tz, `uint32` camera_id, the name as
  bytes ended by a NUL, `uint64` number of 2D points, then per point
  `float64` x, `float64` y, `int64` point3D_id (skipped here).

Text layout: `cameras.txt` has one line `CAMERA_ID MODEL WIDTH HEIGHT PARAMS...`
per camera; `images.txt` two lines per image, `IMAGE_ID QW QX QY QZ TX TY TZ
CAMERA_ID NAME` and the 2D points (possibly an empty line). `#` starts a comment.

The pose is `x_cam = R(q) x_world + t` with a Hamilton unit quaternion `q`, the
camera axes are OpenCV's, and the centre of the top-left pixel is at
`(0.5, 0.5)`: exactly jaxgenus's convention, so nothing is shifted or flipped.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import NamedTuple

import numpy as np

# model id -> (name, number of parameters, number of focal lengths, kind).
# kind "pinhole": focal lengths, principal point, then distortion coefficients that
# make it an exact pinhole when all are 0. kind "other": not a pinhole projection
# even with zero coefficients (fisheye models are equidistant, EQUIRECTANGULAR is a
# sphere), so always refused.
_MODELS = {
    0: ("SIMPLE_PINHOLE", 3, 1, "pinhole"),
    1: ("PINHOLE", 4, 2, "pinhole"),
    2: ("SIMPLE_RADIAL", 4, 1, "pinhole"),
    3: ("RADIAL", 5, 1, "pinhole"),
    4: ("OPENCV", 8, 2, "pinhole"),
    5: ("OPENCV_FISHEYE", 8, 2, "other"),
    6: ("FULL_OPENCV", 12, 2, "pinhole"),
    7: ("FOV", 5, 2, "pinhole"),
    8: ("SIMPLE_RADIAL_FISHEYE", 4, 1, "other"),
    9: ("RADIAL_FISHEYE", 5, 1, "other"),
    10: ("THIN_PRISM_FISHEYE", 12, 2, "other"),
    11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16, 2, "other"),
    12: ("SIMPLE_DIVISION", 4, 1, "pinhole"),
    13: ("DIVISION", 5, 2, "pinhole"),
    14: ("SIMPLE_FISHEYE", 3, 1, "other"),
    15: ("FISHEYE", 4, 2, "other"),
    16: ("EUCM", 6, 2, "other"),
    17: ("EQUIRECTANGULAR", 2, 0, "other"),
}
_ID_BY_NAME = {spec[0]: model_id for model_id, spec in _MODELS.items()}

_UNDISTORT = (
    "jaxgenus needs pinhole cameras: undistort the images first "
    "(colmap image_undistorter --image_path IMAGES --input_path SPARSE --output_path OUT) and load OUT/sparse"
)


class ColmapCamera(NamedTuple):
    """One camera of `cameras.{txt,bin}` as stored."""

    camera_id: int
    model: str
    width: int
    height: int
    params: tuple[float, ...]


class ColmapImage(NamedTuple):
    """One registered image of `images.{txt,bin}` as stored."""

    image_id: int
    qvec: tuple[float, float, float, float]  # qw qx qy qz
    tvec: tuple[float, float, float]
    camera_id: int
    name: str


class PinholeView(NamedTuple):
    """A COLMAP image as a pinhole camera in jaxgenus's convention."""

    label: str
    name: str
    rotation: np.ndarray  # (3, 3) world-to-camera
    translation: np.ndarray  # (3,)
    focal: tuple[float, float]
    principal_point: tuple[float, float]
    camera_id: int
    size: tuple[int, int]  # (height, width)


def model_files(directory: Path) -> tuple[Path, Path] | None:
    """`(cameras, images)` files of the model in `directory` (binary first), or None."""
    for ext in (".bin", ".txt"):
        cams, imgs = directory / f"cameras{ext}", directory / f"images{ext}"
        if cams.is_file() and imgs.is_file():
            return cams, imgs
    return None


def qvec_to_rotation(q) -> np.ndarray:
    """Rotation matrix of the Hamilton unit quaternion `(w, x, y, z)`."""
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


# ---------------------------------------------------------------------------- binary


class _Bytes:
    """Bounds-checked little-endian reads from a whole file."""

    def __init__(self, path: Path):
        self.path = path
        self.data = path.read_bytes()
        self.pos = 0

    def take(self, fmt: str):
        size = struct.calcsize(fmt)
        if self.pos + size > len(self.data):
            raise ValueError(
                f"{self.path}: truncated COLMAP binary file (needs {size} bytes at offset {self.pos}, "
                f"{len(self.data) - self.pos} left)"
            )
        out = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += size
        return out

    def skip(self, size: int):
        if self.pos + size > len(self.data):
            raise ValueError(f"{self.path}: truncated COLMAP binary file (at offset {self.pos})")
        self.pos += size

    def name(self) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise ValueError(f"{self.path}: truncated COLMAP binary file (image name without NUL at {self.pos})")
        raw = self.data[self.pos : end]
        self.pos = end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            return raw.decode("latin-1")

    def done(self):
        if self.pos != len(self.data):
            raise ValueError(
                f"{self.path}: {len(self.data) - self.pos} unexpected bytes after the last record "
                "(not a COLMAP binary file?)"
            )


def read_cameras_binary(path: Path) -> dict[int, ColmapCamera]:
    f = _Bytes(path)
    (count,) = f.take("<Q")
    cams = {}
    for _ in range(count):
        camera_id, model_id, width, height = f.take("<IiQQ")
        if model_id not in _MODELS:
            raise ValueError(f"{path}: camera {camera_id}: unknown COLMAP camera model id {model_id}")
        name, n_params, _, _ = _MODELS[model_id]
        params = f.take(f"<{n_params}d")
        cams[camera_id] = ColmapCamera(camera_id, name, int(width), int(height), tuple(params))
    f.done()
    return cams


def read_images_binary(path: Path) -> list[ColmapImage]:
    f = _Bytes(path)
    (count,) = f.take("<Q")
    images = []
    for _ in range(count):
        image_id, *qt, camera_id = f.take("<I7dI")
        name = f.name()
        (n_points,) = f.take("<Q")
        f.skip(24 * n_points)  # float64 x, float64 y, int64 point3D_id
        images.append(ColmapImage(image_id, tuple(qt[:4]), tuple(qt[4:]), camera_id, name))
    f.done()
    return images


# ------------------------------------------------------------------------------ text


def _data_lines(path: Path):
    """`(line number, stripped line)` of every line (comments and blanks included)."""
    return [(i + 1, line.strip()) for i, line in enumerate(path.read_text().splitlines())]


def read_cameras_text(path: Path) -> dict[int, ColmapCamera]:
    cams = {}
    for lineno, line in _data_lines(path):
        if not line or line.startswith("#"):
            continue
        tok = line.split()
        try:
            camera_id, model, width, height = int(tok[0]), tok[1], int(tok[2]), int(tok[3])
            params = tuple(float(x) for x in tok[4:])
        except (IndexError, ValueError):
            raise ValueError(f"{path}:{lineno}: cannot read camera line {line[:80]!r}") from None
        if model not in _ID_BY_NAME:
            raise ValueError(f"{path}: camera {camera_id}: unknown COLMAP camera model {model!r}")
        n_params = _MODELS[_ID_BY_NAME[model]][1]
        if len(params) != n_params:
            raise ValueError(
                f"{path}: camera {camera_id}: model {model} takes {n_params} parameters, got {len(params)}"
            )
        cams[camera_id] = ColmapCamera(camera_id, model, width, height, params)
    return cams


def _is_points_line(line: str) -> bool:
    try:
        [float(x) for x in line.split()]
    except ValueError:
        return False
    return True


def read_images_text(path: Path) -> list[ColmapImage]:
    lines = _data_lines(path)
    images = []
    i = 0
    while i < len(lines):
        lineno, line = lines[i]
        i += 1
        if not line or line.startswith("#"):
            continue
        tok = line.split()
        try:
            image_id = int(tok[0])
            q = tuple(float(x) for x in tok[1:5])
            t = tuple(float(x) for x in tok[5:8])
            camera_id = int(tok[8])
            name = " ".join(tok[9:])
        except (IndexError, ValueError):
            raise ValueError(f"{path}:{lineno}: cannot read image line {line[:80]!r}") from None
        if len(q) != 4 or len(t) != 3 or not name:
            raise ValueError(f"{path}:{lineno}: cannot read image line {line[:80]!r}")
        images.append(ColmapImage(image_id, q, t, camera_id, name))
        # The POINTS2D line follows (empty when the image has none). Hand-written
        # files sometimes leave it out: only consume it if it is numbers (or blank).
        if i < len(lines) and _is_points_line(lines[i][1]):
            i += 1
    return images


# ------------------------------------------------------------------------- the model


def _pinhole(cam: ColmapCamera, cameras_file: Path):
    """`(fx, fy, cx, cy)` of a camera that is an exact pinhole, else a ValueError."""
    _, _, n_focal, kind = _MODELS[_ID_BY_NAME[cam.model]]
    where = f"{cameras_file}: camera {cam.camera_id} ({cam.model})"
    if kind != "pinhole":
        raise ValueError(f"{where} is not a pinhole projection (fisheye/spherical model); {_UNDISTORT}")
    p = cam.params
    if n_focal == 1:
        fx = fy = p[0]
        cx, cy = p[1], p[2]
    else:
        fx, fy, cx, cy = p[0], p[1], p[2], p[3]
    extra = p[n_focal + 2 :]
    if any(e != 0.0 for e in extra):
        coeffs = ", ".join(f"{e:.6g}" for e in extra)
        raise ValueError(f"{where} has nonzero distortion coefficients ({coeffs}); {_UNDISTORT}")
    return fx, fy, cx, cy


def read_model(cameras_file: Path, images_file: Path) -> list[PinholeView]:
    """The registered images of a COLMAP model as pinhole views, sorted by image name.

    Raises ValueError (naming the file, camera id and model) for a camera with
    distortion or a non-pinhole model, a missing camera, or a bad quaternion.
    Image-size consistency is checked by the caller.
    """
    binary = cameras_file.suffix == ".bin"
    cams = (read_cameras_binary if binary else read_cameras_text)(cameras_file)
    images = (read_images_binary if binary else read_images_text)(images_file)
    views = []
    intrinsics = {}
    for im in sorted(images, key=lambda im: (im.name, im.image_id)):
        label = f"image {im.name!r} (IMAGE_ID {im.image_id})"
        if im.camera_id not in cams:
            raise ValueError(f"{images_file}: {label} uses CAMERA_ID {im.camera_id}, not in {cameras_file.name}")
        cam = cams[im.camera_id]
        if im.camera_id not in intrinsics:
            intrinsics[im.camera_id] = _pinhole(cam, cameras_file)
        fx, fy, cx, cy = intrinsics[im.camera_id]
        q = np.asarray(im.qvec, np.float64)
        norm = float(np.linalg.norm(q))
        if not np.isfinite(norm) or abs(norm - 1.0) > 1e-3:
            raise ValueError(
                f"{images_file}: {label}: quaternion {tuple(im.qvec)} is not a unit quaternion (norm {norm:.6g})"
            )
        views.append(
            PinholeView(
                label=label,
                name=im.name,
                rotation=qvec_to_rotation(q / norm),
                translation=np.asarray(im.tvec, np.float64),
                focal=(fx, fy),
                principal_point=(cx, cy),  # COLMAP's pixel convention is ours: no shift
                camera_id=im.camera_id,
                size=(cam.height, cam.width),
            )
        )
    return views
