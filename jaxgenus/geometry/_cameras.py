"""Batched pinhole cameras.

Convention (the one every jaxgenus function uses):

* **Extrinsics are world-to-camera**: `x_cam = R @ x_world + t`.
* **Camera frame is OpenCV's**: +x right, +y down, +z forward (the camera looks
  along +z; points in front of it have z > 0).
* **Pixels**: continuous pixel coordinates `(u, v)` with `u` along image columns
  and `v` along rows; pixel `(row i, col j)` covers `[j, j+1) x [i, i+1)` and its
  centre is `(j + 0.5, i + 0.5)`. The projection is
  `u = fx * x / z + cx`, `v = fy * y / z + cy`, so a camera whose principal point
  is `(W/2, H/2)` maps its optical axis to the image centre.
  (OpenCV puts pixel centres at integers, so `cx_ours = cx_opencv + 0.5`; the
  converters below handle it.)
* Every camera of a batch has the same image size `(height, width)` (static).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

_HI = jax.lax.Precision.HIGHEST  # full float32 products on every backend (no TF32 on GPUs)

__all__ = [
    "Cameras",
    "look_at",
    "sphere_cameras",
    "project",
    "cameras_from_opencv",
    "cameras_to_opencv",
    "cameras_from_opengl",
    "cameras_to_opengl",
    "cameras_from_blender",
]

# OpenGL/Blender cameras look along -z with +y up; OpenCV along +z with +y down.
_GL_TO_CV = np.diag([1.0, -1.0, -1.0])


class Cameras(eqx.Module):
    """A batch of N pinhole cameras sharing one image size (a PyTree).

    Attributes:
        rotation: `(N, 3, 3)` world-to-camera rotations.
        translation: `(N, 3)` world-to-camera translations.
        focal: `(N, 2)` focal lengths `(fx, fy)` in pixels.
        principal_point: `(N, 2)` `(cx, cy)` in pixels (pixel centres at +0.5).
        height, width: image size in pixels (static).
    """

    rotation: Float[Array, "N 3 3"]
    translation: Float[Array, "N 3"]
    focal: Float[Array, "N 2"]
    principal_point: Float[Array, "N 2"]
    height: int = eqx.field(static=True)
    width: int = eqx.field(static=True)

    def __check_init__(self):
        n = self.rotation.shape[0] if self.rotation.ndim == 3 else None
        if self.rotation.ndim != 3 or self.rotation.shape[1:] != (3, 3):
            raise ValueError(f"cameras.rotation must have shape (N, 3, 3), got {self.rotation.shape}")
        for name, arr, k in (
            ("translation", self.translation, 3),
            ("focal", self.focal, 2),
            ("principal_point", self.principal_point, 2),
        ):
            if arr.shape != (n, k):
                raise ValueError(f"cameras.{name} must have shape ({n}, {k}), got {arr.shape}")
        if int(self.height) <= 0 or int(self.width) <= 0:
            raise ValueError(f"image size must be positive, got ({self.height}, {self.width})")

    def __len__(self) -> int:
        return self.rotation.shape[0]

    @property
    def centers(self) -> Array:
        """`(N, 3)` camera centres in world coordinates, `-R^T t`."""
        return -jnp.einsum("nji,nj->ni", self.rotation, self.translation, precision=_HI)

    def __getitem__(self, index) -> "Cameras":
        """Select cameras by an integer array, slice or int (keeps the batch axis)."""
        if isinstance(index, int):
            index = slice(index, index + 1) if index != -1 else slice(-1, None)
        return Cameras(
            self.rotation[index],
            self.translation[index],
            self.focal[index],
            self.principal_point[index],
            self.height,
            self.width,
        )

    def intrinsic_matrices(self) -> Array:
        """`(N, 3, 3)` intrinsic matrices in this library's pixel convention."""
        n = self.focal.shape[0]
        k = jnp.zeros((n, 3, 3), self.focal.dtype)
        k = k.at[:, 0, 0].set(self.focal[:, 0]).at[:, 1, 1].set(self.focal[:, 1])
        k = k.at[:, 0, 2].set(self.principal_point[:, 0]).at[:, 1, 2].set(self.principal_point[:, 1])
        return k.at[:, 2, 2].set(1.0)


def _as_batch(x, shape, name):
    a = jnp.asarray(x, dtype=jnp.result_type(float))
    if a.shape == shape:
        a = a[None]
    if a.shape[1:] != shape:
        raise ValueError(f"{name} must have shape {shape} or (N, *{shape}), got {a.shape}")
    return a


def _resolution(resolution) -> tuple[int, int]:
    if isinstance(resolution, (int, np.integer)):
        h = w = int(resolution)
    else:
        h, w = (int(r) for r in resolution)
    if h <= 0 or w <= 0:
        raise ValueError(f"resolution must be positive, got {resolution}")
    return h, w


def _focal_from_fov(fov_deg, height):
    fov = float(fov_deg)
    if not 0.0 < fov < 180.0:
        raise ValueError(f"fov_deg must be in (0, 180), got {fov_deg}")
    return 0.5 * height / np.tan(np.deg2rad(fov) / 2.0)


def look_at(eye, target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), *, fov_deg=40.0, resolution=128) -> Cameras:
    """Cameras at `eye` (`(3,)` or `(N, 3)`) looking at `target`, with `up` pointing up in the image.

    `fov_deg` is the vertical field of view; `resolution` is an int (square) or
    `(height, width)`. The principal point is the image centre. Where `up` is
    parallel to the viewing direction another up vector is chosen.
    """
    h, w = _resolution(resolution)
    eye = _as_batch(eye, (3,), "eye")
    n = eye.shape[0]
    target = jnp.broadcast_to(_as_batch(target, (3,), "target"), (n, 3))
    up = jnp.broadcast_to(_as_batch(up, (3,), "up"), (n, 3))
    fwd = target - eye
    fnorm = jnp.linalg.norm(fwd, axis=-1, keepdims=True)
    if not bool(jnp.all(fnorm > 0)):
        raise ValueError("eye and target must differ")
    z = fwd / fnorm
    # image +y is down, so the camera's y axis is -up projected off z
    def _right(u):
        x = jnp.cross(z, u)
        return x, jnp.linalg.norm(x, axis=-1, keepdims=True)

    x, xn = _right(up)
    alt = jnp.where(jnp.abs(z[:, 2:3]) < 0.9, jnp.array([0.0, 0.0, 1.0]), jnp.array([1.0, 0.0, 0.0]))
    x2, xn2 = _right(alt)
    bad = xn < 1e-6 * jnp.linalg.norm(up, axis=-1, keepdims=True)
    x = jnp.where(bad, x2 / xn2, x / jnp.where(bad, 1.0, xn))
    y = jnp.cross(z, x)
    rot = jnp.stack([x, y, z], axis=1)
    trans = -jnp.einsum("nij,nj->ni", rot, eye, precision=_HI)
    f = _focal_from_fov(fov_deg, h)
    focal = jnp.full((n, 2), f, rot.dtype)
    pp = jnp.broadcast_to(jnp.array([w / 2.0, h / 2.0], rot.dtype), (n, 2))
    return Cameras(rot, trans, focal, pp, h, w)


def fibonacci_sphere(n: int) -> np.ndarray:
    """`(n, 3)` near-uniform unit directions (golden-angle spiral)."""
    if int(n) < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    i = np.arange(n) + 0.5
    zc = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(0.0, 1.0 - zc * zc))
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([r * np.cos(phi), zc, r * np.sin(phi)], axis=1)


def sphere_cameras(n: int, *, radius: float = 3.0, fov_deg: float = 40.0, resolution=128) -> Cameras:
    """`n` cameras on a sphere of `radius` (Fibonacci directions) looking at the origin."""
    if not radius > 0:
        raise ValueError(f"radius must be > 0, got {radius}")
    eyes = radius * fibonacci_sphere(n)
    return look_at(eyes, (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), fov_deg=fov_deg, resolution=resolution)


def project(cameras: Cameras, points: Float[Array, "P 3"], *, return_depth: bool = False):
    """Project world `points (P, 3)` to pixel coordinates `(N, P, 2)` for every camera.

    With `return_depth=True` also returns the camera-space depth `z (N, P)`.
    Points at or behind a camera centre (z <= 0) get NaN-free but meaningless
    pixel coordinates (the division uses z clamped to a tiny positive value);
    check the depth to mask them.
    """
    points = jnp.asarray(points)
    if points.ndim != 2 or points.shape[-1] != 3:
        raise ValueError(f"points must have shape (P, 3), got {points.shape}")
    xc = jnp.einsum("nij,pj->npi", cameras.rotation, points, precision=_HI) + cameras.translation[:, None, :]
    z = xc[..., 2]
    tiny = jnp.finfo(xc.dtype).tiny ** 0.5
    zs = jnp.where(z > tiny, z, tiny)
    uv = xc[..., :2] / zs[..., None] * cameras.focal[:, None, :] + cameras.principal_point[:, None, :]
    return (uv, z) if return_depth else uv


def cameras_from_opencv(K, R, t, *, height: int, width: int) -> Cameras:
    """From OpenCV intrinsics `K (N,3,3)` and world-to-camera `R (N,3,3)`, `t (N,3)`.

    OpenCV puts pixel centres at integer coordinates; we add 0.5 to the principal point.
    """
    K = _as_batch(K, (3, 3), "K")
    R = _as_batch(R, (3, 3), "R")
    t = _as_batch(jnp.reshape(jnp.asarray(t), (-1, 3)) if jnp.asarray(t).ndim else t, (3,), "t")
    if not (K.shape[0] == R.shape[0] == t.shape[0]):
        raise ValueError(f"K, R and t must have the same batch size, got {K.shape[0]}, {R.shape[0]}, {t.shape[0]}")
    focal = jnp.stack([K[:, 0, 0], K[:, 1, 1]], axis=-1)
    pp = jnp.stack([K[:, 0, 2], K[:, 1, 2]], axis=-1) + 0.5
    return Cameras(R, t, focal, pp, int(height), int(width))


def cameras_to_opencv(cameras: Cameras):
    """Inverse of `cameras_from_opencv`: returns `(K, R, t)`."""
    k = cameras.intrinsic_matrices()
    k = k.at[:, 0, 2].add(-0.5).at[:, 1, 2].add(-0.5)
    return k, cameras.rotation, cameras.translation


def cameras_from_opengl(view, fov_y_deg, *, height: int, width: int) -> Cameras:
    """From OpenGL world-to-camera `view (N,4,4)` (camera looks along -z, +y up) and a vertical fov.

    The principal point is the image centre (a symmetric frustum).
    """
    view = _as_batch(view, (4, 4), "view")
    flip = jnp.asarray(_GL_TO_CV, view.dtype)
    rot = jnp.einsum("ij,njk->nik", flip, view[:, :3, :3], precision=_HI)
    trans = jnp.einsum("ij,nj->ni", flip, view[:, :3, 3], precision=_HI)
    f = _focal_from_fov(fov_y_deg, height)
    n = view.shape[0]
    focal = jnp.full((n, 2), f, view.dtype)
    pp = jnp.broadcast_to(jnp.array([width / 2.0, height / 2.0], view.dtype), (n, 2))
    return Cameras(rot, trans, focal, pp, int(height), int(width))


def cameras_to_opengl(cameras: Cameras):
    """Inverse of `cameras_from_opengl`: returns `(view (N,4,4), fov_y_deg (N,))`.

    Requires square pixels (fx == fy) and a centred principal point, which an
    OpenGL symmetric frustum assumes.
    """
    flip = jnp.asarray(_GL_TO_CV, cameras.rotation.dtype)
    n = len(cameras)
    view = jnp.zeros((n, 4, 4), cameras.rotation.dtype).at[:, 3, 3].set(1.0)
    view = view.at[:, :3, :3].set(jnp.einsum("ij,njk->nik", flip, cameras.rotation, precision=_HI))
    view = view.at[:, :3, 3].set(jnp.einsum("ij,nj->ni", flip, cameras.translation, precision=_HI))
    fov = jnp.rad2deg(2.0 * jnp.arctan(0.5 * cameras.height / cameras.focal[:, 1]))
    return view, fov


def cameras_from_blender(matrix_world, fov_y_deg, *, height: int, width: int) -> Cameras:
    """From Blender camera-to-world `matrix_world (N,4,4)` (OpenGL camera axes) and a vertical fov."""
    m = _as_batch(matrix_world, (4, 4), "matrix_world")
    return cameras_from_opengl(jnp.linalg.inv(m), fov_y_deg, height=height, width=width)
