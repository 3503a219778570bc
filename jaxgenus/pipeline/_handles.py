"""Handles from image evidence: open the holes that the silhouettes do not show.

A visual hull misses a hole that is seen only against other parts of the
object (eyelets, holes through a plate over a base). A fit at the hull's genus
cannot follow such a hole, so there its rendered normals disagree with the
target normals: the hole's walls and the surface seen through it face
otherwise than the surface the fit spans over them. `handle_candidates`
back-projects the pixels that disagree (by more than `angle_deg`) onto the fitted
surface, per vertex as a fraction of the views that see it, and returns the
connected patches of vertices where that fraction is high, largest first: each
a disc (centre, normal, radius from its area).

`open_handles` then tests the candidates one by one, as a topological
derivative: a cylinder along the patch's inward normal is subtracted
(manifold3d, exact) at the shallowest depth that adds exactly one handle and
keeps one piece, and the cut is kept only when it lowers the image loss (normal
error plus silhouette error, rendered in every view). A patch that is not a
hole (a dent the fit missed, a wall) fails one of the two tests.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from jaxgenus.geometry import Cameras
from jaxgenus.geometry import Mesh
from jaxgenus.rendering import render

__all__ = ["HandleCandidate", "handle_candidates", "normal_image_loss", "open_handles"]


class HandleCandidate(NamedTuple):
    """A patch of the surface where the images show a hole: a disc and its evidence.

    `score`: the patch's area weighted by the fraction of the views in which it
    disagrees with the target normals.
    """

    centre: np.ndarray
    normal: np.ndarray
    radius: float
    score: float


def _render_normals(v, f, cams: Cameras) -> np.ndarray:
    mesh = Mesh.from_numpy(np.asarray(v, np.float32), np.asarray(f, np.int32))
    return np.array(render(mesh, cams, channels=("alpha", "normal", "depth")))


def _cosine(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (a * b).sum(-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1) + 1e-9)


def normal_image_loss(vertices, faces, cams: Cameras, targets) -> float:
    """Mean `1 - cos` between rendered and target normals over the target's pixels
    plus the mean absolute alpha difference, over all views. `targets`: `(N, H, W, 4)`
    normal images (RGB `(n + 1) / 2`, composited over a zero normal, A coverage)."""
    out = _render_normals(vertices, faces, cams)
    t = np.asarray(targets, np.float32)
    cos = _cosine(2.0 * t[..., :3] - 1.0, out[..., 1:4])
    return float(np.mean(np.where(t[..., 3] > 0.5, 1.0 - cos, 0.0)) + np.mean(np.abs(out[..., 0] - t[..., 3])))


def _pixel_points(cams: Cameras, depth: np.ndarray) -> np.ndarray:
    """World points `(N, H, W, 3)` of the pixel centres at camera-space `depth`."""
    n, h, w = depth.shape
    rot = np.asarray(cams.rotation, np.float64)
    trans = np.asarray(cams.translation, np.float64)
    focal = np.broadcast_to(np.asarray(cams.focal, np.float64).reshape(n, -1), (n, 2))
    pp = np.asarray(cams.principal_point, np.float64)
    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    x = (cols[None] - pp[:, 0, None, None]) / focal[:, 0, None, None] * depth
    y = (rows[None] - pp[:, 1, None, None]) / focal[:, 1, None, None] * depth
    cam = np.stack([x, y, depth], -1) - trans[:, None, None, :]
    return np.einsum("nhwi,nij->nhwj", cam, rot)  # R^T (x_cam - t)


def _checked(vertices, faces, cams: Cameras, targets):
    """`(vertices float64, faces int64, targets float32)`, copies, or a ValueError naming the argument."""
    v = np.array(vertices, np.float64)
    f = np.array(faces, np.int64)
    t = np.array(targets, np.float32)
    if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
        raise ValueError(f"vertices: expected finite (V, 3) coordinates, got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0 or f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"faces: expected (F, 3) indices into {len(v)} vertices, got shape {f.shape}")
    want = (len(cams), int(cams.height), int(cams.width), 4)
    if t.shape != want or not np.isfinite(t).all():
        raise ValueError(f"targets: expected finite RGBA normal images of shape {want} (one per camera), "
                         f"got {t.shape}")
    return v, f, t


def handle_candidates(vertices, faces, cams: Cameras, targets, *, angle_deg: float = 30.0,
                      min_fraction: float = 0.3, min_views: int = 3, min_vertices: int = 4) -> list[HandleCandidate]:
    """Patches of a fitted surface whose rendered normals disagree with the target normals
    (module doc), largest score first. `targets` as in `normal_image_loss`."""
    v, f, t = _checked(vertices, faces, cams, targets)
    out = _render_normals(v, f, cams)
    both = (t[..., 3] > 0.5) & (out[..., 0] > 0.5)
    bad = both & (_cosine(2.0 * t[..., :3] - 1.0, out[..., 1:4]) < np.cos(np.radians(angle_deg)))
    points = _pixel_points(cams, out[..., 4] / np.maximum(out[..., 0], 1e-6))
    tree = cKDTree(v)
    seen = np.zeros(len(v))
    votes = np.zeros(len(v))
    for k in range(len(t)):  # per view, so a vertex counts the views (not the pixels) that see it
        for mask, acc in ((both[k], seen), (bad[k], votes)):
            if mask.any():
                acc[np.unique(tree.query(points[k][mask])[1])] += 1.0
    fraction = votes / np.maximum(seen, 1.0)
    flag = (fraction >= min_fraction) & (seen >= min_views)
    edges = np.unique(np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    edges = edges[flag[edges[:, 0]] & flag[edges[:, 1]]]
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(len(v), len(v)))
    _, label = connected_components(graph, directed=False)
    e1, e2 = v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
    cross = np.cross(e1, e2)
    area = np.zeros(len(v))
    np.add.at(area, f.ravel(), np.repeat(0.5 * np.linalg.norm(cross, axis=1) / 3.0, 3))
    normal = np.zeros_like(v)
    np.add.at(normal, f.ravel(), np.repeat(cross, 3, axis=0))
    found = []
    for c in np.unique(label[flag]):
        ids = np.flatnonzero((label == c) & flag)
        if len(ids) < min_vertices:
            continue
        nrm = normal[ids].sum(0)
        a = float(area[ids].sum())
        found.append(HandleCandidate(centre=v[ids].mean(0), normal=nrm / max(np.linalg.norm(nrm), 1e-12),
                                     radius=float(np.sqrt(a / np.pi)), score=float((fraction[ids] * area[ids]).sum())))
    return sorted(found, key=lambda h: -h.score)


def _cylinder_cut(solid, candidate: HandleCandidate, depths):
    """The shallowest cut of `solid` along the candidate that adds exactly one handle, or None."""
    import manifold3d

    n = candidate.normal
    u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    frame = np.column_stack([u, np.cross(-n, u), -n, candidate.centre + 0.1 * n])  # local z: inwards
    for depth in depths:
        tool = manifold3d.Manifold.cylinder(float(depth) + 0.1, candidate.radius, candidate.radius, 32)
        cut = solid - tool.transform(frame)
        if cut.genus() == solid.genus() + 1 and len(cut.decompose()) == 1:
            return float(depth), cut
    return None


def open_handles(vertices, faces, cams: Cameras, targets, count: int, *, max_tries: int | None = None,
                 depths=None):
    """Open up to `count` handles where the images show holes (module doc).

    Returns `(vertices, faces, records)`: the cut surface (the input when nothing
    was opened) and per opened handle `{"centre", "normal", "radius", "depth",
    "loss_before", "loss_after"}`. `max_tries` candidates are tested (default
    `2 count + 4`); `depths` are the cut depths tried (default 0.05 to 1.0).
    """
    import manifold3d

    if int(count) != count or count < 0:
        raise ValueError(f"count: expected a number of handles >= 0, got {count!r}")
    v, f, targets = _checked(vertices, faces, cams, targets)
    v = v.astype(np.float32)
    solid = manifold3d.Manifold(manifold3d.Mesh(vert_properties=v, tri_verts=f.astype(np.uint32)))
    if solid.status() != manifold3d.Error.NoError:
        raise ValueError(f"faces: not a closed oriented manifold surface (manifold3d: {solid.status()})")
    if count == 0:
        return v, f, []
    depths = np.arange(0.05, 1.0001, 0.05) if depths is None else depths
    tries = 2 * count + 4 if max_tries is None else max_tries
    loss = normal_image_loss(v, f, cams, targets)
    records = []
    for cand in handle_candidates(v, f, cams, targets)[:tries]:
        if len(records) == count:
            break
        hit = _cylinder_cut(solid, cand, depths)
        if hit is None:
            continue
        out = hit[1].to_mesh()
        cv, cf = np.asarray(out.vert_properties, np.float32)[:, :3], np.asarray(out.tri_verts, np.int64)
        after = normal_image_loss(cv, cf, cams, targets)
        if after < loss:
            records.append({"centre": cand.centre.tolist(), "normal": cand.normal.tolist(), "radius": cand.radius,
                            "depth": hit[0], "loss_before": loss, "loss_after": after})
            solid, v, f, loss = hit[1], cv, cf, after
    return v, f, records
