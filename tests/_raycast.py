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
`raycast_lambert(cams, mesh, light_direction=..., ambient=..., albedo=...)` returns
photos of the mesh under one directional light instead: Lambertian shading of the
smooth (interpolated vertex) normal at each hit point, times an albedo that may
vary over the surface.

Rays are traced with embree (`trimesh.ray.ray_pyembree`, float32 inside) when it
is installed, else with trimesh's pure-numpy intersector. To keep float32 exact
enough for scenes far from the origin, the mesh and the ray origins are first
moved (in float64) so that the mesh's bounding box is centred at the origin;
a translation changes no ray's direction or hit.
"""

from __future__ import annotations

import numpy as np
import trimesh

__all__ = ["camera_arrays", "cell_albedo", "raycast", "raycast_lambert", "intersector"]


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


def _first_hits(cams, mesh, k: int):
    """Per view: `(tm, tri, points)` for the k x k sub-pixel rays of every pixel, row-major
    `(H k, W k)` flattened: the first face hit (-1: none) and the hit point (world units),
    on the mesh `tm` moved so that its bounding box is centred (its vertices shifted by -shift),
    and `shift`."""
    if k < 1:
        raise ValueError(f"supersample must be >= 1, got {k}")
    R, t, K, h, w = camera_arrays(cams)
    tm = _as_trimesh(mesh)
    shift = 0.5 * (tm.vertices.min(0) + tm.vertices.max(0))
    tm = trimesh.Trimesh(tm.vertices - shift, tm.faces, process=False)
    rays = intersector(tm)
    sub = (np.arange(k) + 0.5) / k
    u = (np.arange(w)[:, None] + sub[None, :]).reshape(-1)  # (W k,) column positions
    v = (np.arange(h)[:, None] + sub[None, :]).reshape(-1)  # (H k,) row positions
    uu, vv = np.meshgrid(u, v)  # (H k, W k): row-major like the image
    pix = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)], axis=1)  # homogeneous [u, v, 1]
    for n in range(len(R)):
        d = pix @ np.linalg.inv(K[n]).T @ R[n]  # rows: R^T K^-1 [u, v, 1]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        origin = np.broadcast_to(-R[n].T @ t[n] - shift, d.shape).copy()
        tri, ray, loc = rays.intersects_id(origin, d, multiple_hits=False, return_locations=True)
        first = np.full(len(d), -1, np.int64)
        points = np.zeros((len(d), 3))
        first[ray], points[ray] = tri, loc + shift
        yield tm, first, points, shift


def raycast(cams, mesh, *, supersample: int = 1) -> np.ndarray:
    """`(N, H, W, 4)` float32 RGBA of `mesh` seen by `cams`, by ray casting (see the module docstring).

    Args:
        cams: a `jaxgenus.Cameras` (read as numpy arrays).
        mesh: a `trimesh.Trimesh`, a `jaxgenus.Mesh` or a `(V, F)` pair; closed and
            outward-oriented for meaningful normals.
        supersample: k >= 1 rays per pixel side.
    """
    k = int(supersample)
    h, w = int(cams.height), int(cams.width)
    out = np.zeros((len(cams), h, w, 4), np.float32)
    for n, (tm, tri, _, _) in enumerate(_first_hits(cams, mesh, k)):
        hit = tri >= 0
        nrm = np.where(hit[:, None], np.asarray(tm.face_normals, np.float64)[np.where(hit, tri, 0)], 0.0)
        hit = hit.reshape(h, k, w, k).mean(axis=(1, 3))
        nsum = nrm.reshape(h, k, w, k, 3).sum(axis=(1, 3))
        count = hit * (k * k)
        mean = nsum / np.maximum(count, 1.0)[..., None]
        out[n, ..., :3] = np.where(count[..., None] > 0, 0.5 * (mean + 1.0), 0.0)
        out[n, ..., 3] = hit
    return out


def raycast_depth(cams, mesh) -> np.ndarray:
    """`(N, H, W)` float64: the camera-space depth (z) of the first hit at each pixel centre, 0 where none."""
    R, t, _, h, w = camera_arrays(cams)
    out = np.zeros((len(cams), int(h), int(w)))
    for n, (_, tri, points, _) in enumerate(_first_hits(cams, mesh, 1)):
        z = points @ R[n][2] + t[n][2]
        out[n] = np.where(tri >= 0, z, 0.0).reshape(int(h), int(w))
    return out


def raycast_lambert(cams, mesh, *, light_direction, ambient: float = 0.3, albedo=(0.7, 0.7, 0.7),
                    supersample: int = 1) -> np.ndarray:
    """`(N, H, W, 4)` float32 RGBA photos of a matte `mesh` under one directional light, by ray casting.

    A ray that hits has the colour `albedo(p) * (ambient + (1 - ambient) max(0, n . l))`:
    `l` the unit `light_direction` (world, towards the light, the same in every view),
    `n` the smooth normal at the hit point `p` (trimesh's vertex normals interpolated
    with the barycentric coordinates of `p`, renormalized), `albedo` an RGB triple or
    a function of the world points `(P, 3) -> (P, 3)`. RGB is the mean colour of the
    pixel's hit sub-rays, clipped to [0, 1] (0 where none hits); A the hit fraction.
    """
    k = int(supersample)
    h, w = int(cams.height), int(cams.width)
    light = np.asarray(light_direction, np.float64)
    light = light / np.linalg.norm(light)
    out = np.zeros((len(cams), h, w, 4), np.float32)
    for n, (tm, tri, points, shift) in enumerate(_first_hits(cams, mesh, k)):
        hit = tri >= 0
        colour = np.zeros((len(tri), 3))
        if hit.any():
            corners = tm.triangles[tri[hit]]
            bary = trimesh.triangles.points_to_barycentric(corners, points[hit] - shift)
            nrm = np.einsum("pk,pki->pi", bary, np.asarray(tm.vertex_normals)[tm.faces[tri[hit]]])
            nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
            shade = ambient + (1.0 - ambient) * np.maximum(nrm @ light, 0.0)
            rho = albedo(points[hit]) if callable(albedo) else np.broadcast_to(np.asarray(albedo, float), (hit.sum(), 3))
            colour[hit] = rho * shade[:, None]
        count = hit.reshape(h, k, w, k).sum(axis=(1, 3))
        csum = colour.reshape(h, k, w, k, 3).sum(axis=(1, 3))
        out[n, ..., :3] = np.clip(csum / np.maximum(count, 1)[..., None], 0.0, 1.0)
        out[n, ..., 3] = count / (k * k)
    return out


def cell_albedo(size: float):
    """An albedo for `raycast_lambert`: 3D cells of `size` (world units), each a hashed colour in
    [0.1, 0.9] per channel: a high-frequency texture that a per-vertex albedo cannot hold."""

    def albedo(p):
        c = np.floor(np.asarray(p, np.float64) / size).astype(np.int64)
        h = (c[:, 0] * 73856093) ^ (c[:, 1] * 19349663) ^ (c[:, 2] * 83492791)
        return np.stack([0.1 + 0.8 * (((h * (2 * k + 1) * 2654435761) >> 11) % 256) / 255.0 for k in range(3)], 1)

    return albedo
