"""An independent reference renderer for the tests: one ray per (sub-)pixel, with trimesh.

It shares nothing with jaxgenus's renderer; only the camera convention is the
library's (see `jaxgenus/_cameras.py`):

* world-to-camera `x_cam = R x + t`, OpenCV camera axes (+z forward, +y down);
* pixel `(row i, col j)` covers `[j, j+1) x [i, i+1)`, its centre is `(j + 0.5, i + 0.5)`;
* a pixel position `(u, v)` looks along `R^T K^-1 [u, v, 1]` from the camera centre `-R^T t`.

`raycast(cams, mesh, supersample=k)` returns `(N, H, W, 4)` float32 RGBA like
`jaxgenus.render_targets`: A is the fraction of the k x k sub-pixel rays
(centres at `j + (s + 0.5) / k`) that hit the mesh (k = 1: one ray through the
pixel centre, A in {0, 1}); RGB is `(n + 1) / 2` of the mean world normal of the
faces first hit by those rays (not renormalised), 0 where no ray hits.

Rays are traced with embree (`trimesh.ray.ray_pyembree`, float32 inside) when it
is installed, else with trimesh's pure-numpy intersector. To keep float32 exact
enough for scenes far from the origin, the mesh and the ray origins are first
moved (in float64) so that the mesh's bounding box is centred at the origin;
a translation changes no ray's direction or hit.
"""

from __future__ import annotations

import numpy as np
import trimesh

__all__ = ["camera_arrays", "raycast", "intersector"]


def camera_arrays(cams):
    """`(R (N,3,3), t (N,3), K (N,3,3), height, width)` of a `jaxgenus.Cameras`, as float64 numpy."""
    R = np.asarray(cams.rotation, np.float64)
    t = np.asarray(cams.translation, np.float64)
    f = np.asarray(cams.focal, np.float64)
    c = np.asarray(cams.principal_point, np.float64)
    K = np.zeros((len(R), 3, 3))
    K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = f[:, 0], f[:, 1], c[:, 0], c[:, 1], 1.0
    return R, t, K, int(cams.height), int(cams.width)


def _as_trimesh(mesh) -> trimesh.Trimesh:
    if isinstance(mesh, trimesh.Trimesh):
        v, f = mesh.vertices, mesh.faces
    elif hasattr(mesh, "to_numpy"):  # a jaxgenus.Mesh: only its arrays are used
        v, f = mesh.to_numpy()
    else:
        v, f = mesh
    return trimesh.Trimesh(np.asarray(v, np.float64), np.asarray(f, np.int64), process=False)


def intersector(mesh: trimesh.Trimesh):
    """embree's ray intersector for `mesh` when available, else trimesh's numpy one."""
    try:
        from trimesh.ray.ray_pyembree import RayMeshIntersector

        return RayMeshIntersector(mesh)
    except ImportError:  # pragma: no cover - embreex is a dependency on x86_64
        from trimesh.ray.ray_triangle import RayMeshIntersector

        return RayMeshIntersector(mesh)


def raycast(cams, mesh, *, supersample: int = 1) -> np.ndarray:
    """`(N, H, W, 4)` float32 RGBA of `mesh` seen by `cams`, by ray casting (see the module docstring).

    Args:
        cams: a `jaxgenus.Cameras` (read as numpy arrays).
        mesh: a `trimesh.Trimesh`, a `jaxgenus.Mesh` or a `(V, F)` pair; closed and
            outward-oriented for meaningful normals.
        supersample: k >= 1 rays per pixel side.
    """
    k = int(supersample)
    if k < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    R, t, K, h, w = camera_arrays(cams)
    tm = _as_trimesh(mesh)
    shift = 0.5 * (tm.vertices.min(0) + tm.vertices.max(0))
    tm = trimesh.Trimesh(tm.vertices - shift, tm.faces, process=False)
    normals = np.asarray(tm.face_normals, np.float64)
    rays = intersector(tm)

    sub = (np.arange(k) + 0.5) / k
    u = (np.arange(w)[:, None] + sub[None, :]).reshape(-1)  # (W k,) column positions
    v = (np.arange(h)[:, None] + sub[None, :]).reshape(-1)  # (H k,) row positions
    uu, vv = np.meshgrid(u, v)  # (H k, W k): row-major like the image
    pix = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)], axis=1)  # homogeneous [u, v, 1]

    out = np.zeros((len(R), h, w, 4), np.float32)
    for n in range(len(R)):
        d = pix @ np.linalg.inv(K[n]).T @ R[n]  # rows: R^T K^-1 [u, v, 1]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        origin = -R[n].T @ t[n] - shift
        tri = rays.intersects_first(np.broadcast_to(origin, d.shape).copy(), d)
        hit = tri >= 0
        nrm = np.where(hit[:, None], normals[np.where(hit, tri, 0)], 0.0)
        hit = hit.reshape(h, k, w, k).mean(axis=(1, 3))
        nsum = nrm.reshape(h, k, w, k, 3).sum(axis=(1, 3))
        count = hit * (k * k)
        mean = nsum / np.maximum(count, 1.0)[..., None]
        out[n, ..., :3] = np.where(count[..., None] > 0, 0.5 * (mean + 1.0), 0.0)
        out[n, ..., 3] = hit
    return out
