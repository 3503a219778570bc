"""Camera files from other tools: `load_cameras(path, *, image_size=None)`.

Every reader returns `Cameras` in jaxgenus's convention (see `_cameras.py`):
world-to-camera `x_cam = R x + t`, OpenCV camera axes (+x right, +y down,
+z forward), and pixel `(row i, col j)` covering `[j, j+1) x [i, i+1)`, i.e. the
centre of the top-left pixel is `(0.5, 0.5)`. Tools differ on that last point:

==================  ==============================  ===============================
format              top-left pixel centre           what is done to cx, cy
==================  ==============================  ===============================
OpenCV JSON         (0, 0)  (OpenCV)                + 0.5
IDR/NeuS npz        (0, 0)  (IDR casts rays at      + 0.5
                    integer pixel coordinates)
Middlebury par.txt  (0, 0)                          + 0.5
COLMAP              (0.5, 0.5)                      none
transforms.json     (0.5, 0.5) (as nerfstudio and   none
                    instant-ngp read it)
==================  ==============================  ===============================

Formats (detected from the path: name, extension, then contents):

* **OpenCV JSON** (jaxgenus's own): `{"height", "width", "cameras": [{"K", "R",
  "t", "name"?}]}`, `K` 3x3, world-to-camera `R` 3x3 and `t` (3,). Names when
  every camera has a `name`.
* **COLMAP sparse model**: a folder with `cameras.{bin,txt}` + `images.{bin,txt}`
  (binary preferred), a folder with `sparse/0`, `sparse` or `0` holding one, or
  the path of one of the model files. Registered images, sorted by name; names
  are the image names. Cameras PINHOLE and SIMPLE_PINHOLE; the distortion models
  (SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV, FOV, SIMPLE_DIVISION, DIVISION)
  only when every distortion coefficient is exactly 0; fisheye, EUCM and
  equirectangular models never (run `colmap image_undistorter` first).
* **NeRF `transforms.json`** (Blender synthetic, instant-ngp, nerfstudio):
  `frames[i].transform_matrix` is camera-to-world with OpenGL camera axes
  (+y up, looking along -z), converted as `R = diag(1,-1,-1) R_c2w^T`,
  `t = -R c`. Intrinsics `fl_x`/`fl_y`/`cx`/`cy` or `camera_angle_x`
  (`camera_angle_y`), `w`/`h`, at the top level or per frame (a frame's value
  wins; a frame giving any focal key replaces all top-level focal keys). `fl_y`
  defaults to `fl_x`, `cx, cy` to `(w/2, h/2)`. Without `w`/`h` the size comes
  from `image_size` or the first frame's image (`file_path`, relative to the
  JSON's folder, `.png`/`.jpg` tried when it has no extension). Nonzero
  distortion keys (`k1`..`k6`, `p1`, `p2`), `is_fisheye` and a `camera_model`
  other than OPENCV/PINHOLE/SIMPLE_PINHOLE are refused. Names are `file_path`;
  frames keep the file's order. Poses are used as written (instant-ngp's
  `scale`/`offset` and nerfstudio's `applied_transform` are not applied again).
* **IDR/NeuS `cameras*.npz`**: `world_mat_i` (4x4 or 3x4; rows 0-2 are
  `P = K [R | t]` up to a nonzero, possibly negative, scale) decomposed by RQ
  with `diag(K) > 0` and `det R = +1`. Cameras in index order, names None. The
  returned cameras live in the frame of `world_mat`; `scale_mat_i` (where
  `x_world = scale_mat @ x_normalized`, IDR/NeuS's unit-sphere normalization) is
  ignored: jaxgenus picks its own normalization. The size comes from
  `image_size`, else the first image of an `image/` or `images/` folder beside
  the file.
* **Middlebury `*_par.txt`**: the number of images, then per image
  `name k11..k33 r11..r33 t1 t2 t3` (`x_cam = R x + t`). Names are the image
  names, in file order; the size comes from `image_size` or the first image,
  opened next to the file.

Checks (one-line ValueError naming the file and the camera): rotation
orthonormal with det +1 (1e-4), finite numbers, positive focal lengths,
`K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]` with a skew `s` small enough to move
no pixel of the image by more than 0.05 px (then dropped), one image size for
all cameras, `image_size` equal to the file's own size where it has one, at
least one camera, a known format.

The readers: COLMAP's model files in `_colmap` (turned into cameras here),
transforms.json in `_nerf_cameras`, OpenCV JSON, IDR/NeuS and Middlebury in
`_krt_cameras`; the checks they share in `_camera_checks`. This module detects
the format and calls the reader.
"""

from __future__ import annotations

import json
from pathlib import Path

from jaxgenus.capture import _colmap
from jaxgenus.capture._camera_checks import FileCamera, assemble_cameras, check_image_size, resolve_size
from jaxgenus.geometry import Cameras
from jaxgenus.capture._krt_cameras import idr_indices, read_idr, read_idr_region, read_middlebury, read_opencv_json
from jaxgenus.capture._nerf_cameras import read_transforms

__all__ = ["load_cameras", "load_region"]

_COLMAP_STEMS = ("cameras", "images", "points3D", "rigs", "frames")
_EXPECTED = (
    "expected a COLMAP sparse model (a folder with cameras/images .bin or .txt, or sparse/0 in it), "
    "a NeRF transforms.json, an OpenCV cameras .json ({height, width, cameras: [{K, R, t}]}), "
    "an IDR/NeuS cameras.npz (world_mat_i) or a Middlebury *_par.txt"
)


def load_cameras(path, *, image_size=None) -> tuple[Cameras, list[str] | None]:
    """Read cameras from a camera file or folder of another tool.

    Args:
        path: an OpenCV cameras `.json`, a NeRF `transforms.json`, a COLMAP
            sparse model (folder or one of its files), an IDR/NeuS `cameras.npz`
            or a Middlebury `*_par.txt`; a folder is searched for one of these
            (several found is an error).
        image_size: `(height, width)` in pixels. Needed where the file has no
            size and no image to read it from (IDR/NeuS, Blender sets without
            their images); where the file has a size it must agree.

    Returns:
        `(cameras, names)`: `Cameras` in jaxgenus's convention and the image
        names in camera order (None where the format has none). See the module
        docstring for each format's fields, pixel and axis conventions.

    Raises:
        FileNotFoundError: `path` does not exist.
        ValueError: an unknown format, or a file that cannot be read as
            pinhole cameras (a one-line message naming the file and camera).
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such file or directory")
    size = check_image_size(image_size)
    kind, target, payload = _detect(p)
    if kind == "colmap":
        return _read_colmap(*target, size)
    if kind == "opencv_json":
        return read_opencv_json(target, payload, size)
    if kind == "transforms":
        return read_transforms(target, payload, size)
    if kind == "idr":
        return read_idr(target, size)
    return read_middlebury(target, size)


def load_region(path) -> tuple[np.ndarray, float] | None:
    """The sphere `(centre (3,), radius)` in world units that a camera file declares the object to lie
    in, or None where it declares none. Only IDR/NeuS `cameras*.npz` do (`scale_mat_i`, the unit
    sphere of their normalization; DTU, BlendedMVS in that layout): `reconstruct(..., region=)`.

    Raises:
        FileNotFoundError: `path` does not exist.
        ValueError: an unknown format, or a `scale_mat_i` that is not a scale and a translation.
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such file or directory")
    kind, target, _ = _detect(p)
    return read_idr_region(target) if kind == "idr" else None


# -------------------------------------------------------------------------- detection


def _detect(p: Path):
    """`(kind, target, payload)`: the format and the file(s) to read."""
    if p.is_dir():
        return _detect_dir(p)
    suffix = p.suffix.lower()
    if suffix in (".bin", ".txt") and p.stem in _COLMAP_STEMS:
        cams, imgs = p.parent / f"cameras{suffix}", p.parent / f"images{suffix}"
        missing = [f.name for f in (cams, imgs) if not f.is_file()]
        if missing:
            raise ValueError(f"{p}: a COLMAP model needs {' and '.join(missing)} beside it")
        return "colmap", (cams, imgs), None
    if suffix == ".json":
        spec = _read_json(p)
        has_frames = isinstance(spec, dict) and isinstance(spec.get("frames"), list)
        has_cameras = isinstance(spec, dict) and isinstance(spec.get("cameras"), list)
        if has_frames and not has_cameras:
            return "transforms", p, spec
        if has_cameras and not has_frames:
            return "opencv_json", p, spec
        raise ValueError(f"cannot tell the camera format of {p}: a JSON object with a 'frames' list "
                         "(transforms.json) or a 'cameras' list (OpenCV JSON) was expected")
    if suffix == ".npz":
        if idr_indices(p):
            return "idr", p, None
        raise ValueError(
            f"cannot tell the camera format of {p}: an .npz with world_mat_0, world_mat_1, ... was expected"
        )
    if p.name.endswith("_par.txt") or (suffix == ".txt" and _looks_middlebury(p)):
        return "middlebury", p, None
    raise ValueError(f"cannot tell the camera format of {p}: {_EXPECTED}")


def _detect_dir(d: Path):
    found = []
    for sub in (d, d / "0", d / "sparse", d / "sparse" / "0"):
        files = _colmap.model_files(sub) if sub.is_dir() else None
        if files is not None:
            found.append(("colmap", files, sub))
            break  # the first COLMAP model on this list is the one meant
    for f in sorted(d.iterdir()):
        if not f.is_file():
            continue
        if f.name == "transforms.json":
            found.append(("transforms", f, f))
        elif f.suffix == ".npz" and f.name.startswith("cameras") and idr_indices(f):
            found.append(("idr", f, f))
        elif f.name.endswith("_par.txt"):
            found.append(("middlebury", f, f))
    if not found:
        raise ValueError(f"cannot tell the camera format of {d}: {_EXPECTED}")
    if len(found) > 1:
        listed = ", ".join(str(where) for _, _, where in found)
        raise ValueError(f"{d} holds several camera files ({listed}); pass the one to use")
    kind, target, _ = found[0]
    return kind, target, (_read_json(target) if kind == "transforms" else None)


def _read_json(p: Path):
    try:
        return json.loads(p.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ValueError(f"{p}: not valid JSON ({err})") from None


def _looks_middlebury(p: Path) -> bool:
    try:
        lines = [ln.split() for ln in p.read_text().splitlines()[:3] if ln.strip()]
    except (OSError, UnicodeDecodeError):
        return False
    return len(lines) >= 2 and len(lines[0]) == 1 and lines[0][0].isdigit() and len(lines[1]) == 22


# ---------------------------------------------------------------------------- readers


def _read_colmap(cameras_file: Path, images_file: Path, image_size):
    views = _colmap.read_model(cameras_file, images_file)
    if not views:
        raise ValueError(f"{images_file}: no registered images in the COLMAP model")
    sizes = {}
    for v in views:
        sizes.setdefault(v.size, v)
    if len(sizes) > 1:
        listed = ", ".join(f"camera {v.camera_id} ({v.name!r}) {w}x{h}" for (h, w), v in sizes.items())
        raise ValueError(f"{cameras_file}: images have different sizes ({listed}); jaxgenus needs one image size")
    height, width = resolve_size(cameras_file, views[0].size, image_size)
    cams = [FileCamera(v.label, v.name, v.rotation, v.translation, v.focal, v.principal_point) for v in views]
    return assemble_cameras(cameras_file, cams, height, width)

