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

`open_handles` then tests cuts one by one, as a topological derivative, and
keeps a cut only when it adds exactly one handle, keeps one piece and lowers
the image loss (normal error plus silhouette error, rendered in every view):

- free space first: the parts of the fit outside the silhouettes' visual hull
  without a closing, on a grid of about a pixel (a hole some silhouette sees
  through, too thin to outlast the closings that clear carving's spurious tunnels:
  a slot under an arch, a bent tunnel), each cut as it is, where it reaches a
  patch of disagreeing normals (where the normals agree with the fit, the part is
  carving's noise or a pocket, and a cut there moves the loss by rendering noise);
- then tunnels: two patches that face away from each other, each within 40
  degrees of the straight path between them, may be the mouths of one tunnel
  (of any length and direction, longer than any cut from one side); the fit
  fills it, so a straight prism is subtracted from mouth to mouth, its
  cross-section the outline both patches share across the path, at several
  sizes (the one with the lowest loss is kept);
- then holes: a cylinder along a patch's inward normal (manifold3d, exact) at
  the shallowest depth that adds a handle, of the patch's radius and 0.75 and
  0.5 of it (the patch spreads past the rim; the one with the lowest loss is
  kept); a hole into a tunnel opened before reaches it there.

A patch that is not a hole (a dent the fit missed, a wall) fails a test.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from jaxgenus.geometry import Cameras
from jaxgenus.geometry import Mesh, capacity_bucket, piece_count, pieces_larger_than
from jaxgenus.rendering import render

__all__ = ["HandleCandidate", "HoleTests", "handle_candidates", "hole_tests", "normal_image_loss", "open_handles",
           "view_losses"]


class HandleCandidate(NamedTuple):
    """A patch of the surface where the images show a hole: a disc and its evidence.

    `score`: the patch's area weighted by the fraction of the views in which it
    disagrees with the target normals; `points`: the patch's vertices `(K, 3)` (its
    shape, for a tunnel's cross-section); `misfit`: the share of the fit's whole normal
    misfit (`1 - cos` summed over every view's pixels) that lies on the patch.
    """

    centre: np.ndarray
    normal: np.ndarray
    radius: float
    score: float
    points: np.ndarray | None = None
    misfit: float = 0.0


def _render_normals(v, f, cams: Cameras) -> np.ndarray:
    # padded to a capacity bucket: every cut has its own face count, and one compiled render serves many
    mesh = Mesh.from_numpy(np.asarray(v, np.float32), np.asarray(f, np.int32), capacity=capacity_bucket(len(f)))
    return np.array(render(mesh, cams, channels=("alpha", "normal", "depth")))


def _cosine(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (a * b).sum(-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1) + 1e-9)


def view_losses(vertices, faces, cams: Cameras, targets) -> np.ndarray:
    """Per view `(N,)`: the mean `1 - cos` between rendered and target normals over the target's
    pixels plus the mean absolute alpha difference (`normal_image_loss` is their mean)."""
    out = _render_normals(vertices, faces, cams)
    t = np.asarray(targets, np.float32)
    cos = _cosine(2.0 * t[..., :3] - 1.0, out[..., 1:4])
    return (np.mean(np.where(t[..., 3] > 0.5, 1.0 - cos, 0.0), axis=(1, 2))
            + np.mean(np.abs(out[..., 0] - t[..., 3]), axis=(1, 2)))


def normal_image_loss(vertices, faces, cams: Cameras, targets) -> float:
    """Mean `1 - cos` between rendered and target normals over the target's pixels
    plus the mean absolute alpha difference, over all views. `targets`: `(N, H, W, 4)`
    normal images (RGB `(n + 1) / 2`, composited over a zero normal, A coverage)."""
    return float(np.mean(view_losses(vertices, faces, cams, targets)))


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
    miss = np.where(both, 1.0 - _cosine(2.0 * t[..., :3] - 1.0, out[..., 1:4]), 0.0)
    bad = both & (miss > 1.0 - np.cos(np.radians(angle_deg)))
    points = _pixel_points(cams, out[..., 4] / np.maximum(out[..., 0], 1e-6))
    tree = cKDTree(v)
    seen = np.zeros(len(v))
    votes = np.zeros(len(v))
    misfit = np.zeros(len(v))
    for k in range(len(t)):  # per view, so a vertex counts the views (not the pixels) that see it
        if both[k].any():
            nearest = tree.query(points[k][both[k]])[1]
            seen[np.unique(nearest)] += 1.0
            votes[np.unique(nearest[bad[k][both[k]]])] += 1.0
            np.add.at(misfit, nearest, miss[k][both[k]])
    misfit /= max(float(misfit.sum()), 1e-12)
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
                                     radius=float(np.sqrt(a / np.pi)), score=float((fraction[ids] * area[ids]).sum()),
                                     points=v[ids], misfit=float(misfit[ids].sum())))
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
        if cut.genus() == solid.genus() + 1 and piece_count(cut) == 1:
            return float(depth), cut
    return None


def _tunnel_cut(solid, a: HandleCandidate, b: HandleCandidate, *, max_angle_deg: float = 40.0,
                scales=(1.0, 0.85, 0.7, 0.55, 0.4)) -> list:
    """Straight tunnels from patch `a` to patch `b` cut from `solid` (a list, maybe empty).

    Only when the path leaves `a` inwards and reaches `b` from inside (each normal
    within `max_angle_deg` of the path). The cross-section is what both mouths share
    across the path (the intersection of the two patches' convex outlines), shrunk
    about its centre to `scales` of it (a patch also spreads past its mouth): every
    cut that adds exactly one handle and keeps one piece, as `(length, half_width, cut)`.
    """
    import manifold3d

    path = b.centre - a.centre
    length = float(np.linalg.norm(path))
    if length < 1e-6 or a.points is None or b.points is None or min(len(a.points), len(b.points)) < 3:
        return []
    d = path / length
    if min(-a.normal @ d, b.normal @ d) < np.cos(np.radians(max_angle_deg)):
        return []
    u = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(d, u)
    shared = manifold3d.CrossSection.hull_points((a.points - a.centre) @ np.column_stack([u, w]))
    shared = shared ^ manifold3d.CrossSection.hull_points((b.points - a.centre) @ np.column_stack([u, w]))
    if shared.is_empty() or shared.area() < 1e-8:
        return []
    lo, hi = (np.asarray(x, float) for x in np.split(np.asarray(shared.bounds(), float), 2))
    mid = 0.5 * (lo + hi)
    frame = np.column_stack([u, w, d, a.centre - 0.1 * d])
    cuts = []
    for scale in scales:
        section = shared.translate(tuple(-mid)).scale((scale, scale)).translate(tuple(mid))
        cut = solid - manifold3d.Manifold.extrude(section, length + 0.2).transform(frame)
        if cut.genus() == solid.genus() + 1 and piece_count(cut) == 1:
            cuts.append((length, float(np.sqrt(section.area() / np.pi)), cut))
    return cuts


#: The finest grid (cells along the hull's longest side) on which the silhouettes' free space is
#: carved from a fit (`_carved_parts`): about a pixel of 128^2 images; finer grids cost more than
#: the cut they sharpen.
CARVE_GRID = 128


def _carved_parts(solid, cams: Cameras, targets: np.ndarray, pixel: float) -> list:
    """The parts of `solid` that the silhouettes show empty, largest first: outside their visual
    hull without a closing, on a grid of about a `pixel` (`CARVE_GRID` cells at most), each larger
    than a cell. A fit that spans a hole some silhouette sees through fills it with such a part,
    whatever the hole's shape (a slot under an arch, a bent tunnel); so does a fit that bulges
    past a silhouette (then cutting the part adds no handle)."""
    import manifold3d

    from jaxgenus.capture import hull_occupancy, visual_hull, visual_hull_bounds

    alpha = targets[..., 3]
    try:
        lo, hi = visual_hull_bounds(alpha, cams)
    except ValueError:  # no hull at this grid: nothing the silhouettes show empty can be cut
        return []
    extent = float((hi - lo).max())
    resolution = int(np.clip(np.ceil(extent / pixel), 64, CARVE_GRID)) if pixel > 0 else 96
    occupancy = hull_occupancy(alpha, cams, resolution=resolution, bounds=(lo, hi))
    try:
        hv, hf = visual_hull(alpha, cams, occupancy=occupancy).to_numpy()
    except ValueError:
        return []
    hull = manifold3d.Manifold(manifold3d.Mesh(vert_properties=np.asarray(hv, np.float32),
                                               tri_verts=np.asarray(hf, np.uint32)))
    return pieces_larger_than(solid - hull, occupancy.cell ** 3)


def _carve_cut(solid, part):
    """`(record, points, cut)`: `solid` without `part` (grown 5 % about its centre, so that the cut
    clears the surface it came from) when that adds exactly one handle and keeps one piece; else None."""
    points = np.asarray(part.to_mesh().vert_properties, np.float64)[:, :3]
    centre = points.mean(0)
    tool = part.translate(tuple(-centre)).scale((1.05, 1.05, 1.05)).translate(tuple(centre))
    cut = solid - tool
    if cut.genus() != solid.genus() + 1 or piece_count(cut) != 1:
        return None
    record = {"cut": "carve", "centre": centre.tolist(), "normal": None, "radius": float(np.cbrt(0.75 * part.volume() / np.pi)),
              "depth": float(np.ptp(points, axis=0).max())}
    return record, points, cut


def _patches_reached(points: np.ndarray, found: list[HandleCandidate]) -> list[int]:
    """Indices of the candidate patches `found` whose centre lies within their radius of `points`."""
    tree = cKDTree(points)
    return [i for i, c in enumerate(found) if tree.query(c.centre)[0] <= c.radius]


def _tunnel_pairs(candidates: list[HandleCandidate]) -> list[tuple[int, int]]:
    """Index pairs `(entry, exit)` of candidates that may be the two mouths of one tunnel
    (facing away from each other), strongest first."""
    pairs = []
    for i, a in enumerate(candidates):
        for j in range(i + 1, len(candidates)):
            b = candidates[j]
            if a.normal @ b.normal < 0.0:
                pairs.append((i, j) if -a.normal @ (b.centre - a.centre) > 0.0 else (j, i))
    return sorted(pairs, key=lambda p: -(candidates[p[0]].score + candidates[p[1]].score))


def _test_record(centre, cut: str, after: np.ndarray, before: np.ndarray, misfit: float) -> dict:
    """One entry of `HoleTests.tested`: a cut kept when it lowers the mean of the per-view losses."""
    loss = max(float(before.mean()), 1e-12)
    delta = after - before
    tol = 1e-6 * loss
    return {"centre": np.asarray(centre, float).tolist(), "cut": cut, "kept": float(after.mean()) < float(before.mean()),
            "change": float(after.mean() / loss - 1.0), "better": int((delta < -tol).sum()),
            "worse": int((delta > tol).sum()), "gain": float(-delta[delta < 0].sum() / loss),
            "rise": float(delta[delta > 0].sum() / loss), "misfit": float(misfit)}


#: Candidates tested when `hole_tests` opens as many holes as the images confirm: each costs up to
#: 60 booleans and a render of every view (and each pair of them a tunnel test), so only the
#: strongest; the holes an object shows are the strongest candidates (docs/hidden_handles.md).
UNBOUNDED_TRIES = 16


class HoleTests(NamedTuple):
    """What `hole_tests` found: the cut surface, the cuts kept and every cut tested.

    `opened`: per kept cut, a record as `open_handles` returns it. `tested`: per candidate
    tested with at least one cut that adds exactly one handle, `{"centre", "cut", "kept", "change",
    "better", "worse", "gain", "rise", "misfit"}`: the best cut's relative change of the image loss
    (negative: lower), the number of views in which it lowered and raised the loss, and the sums
    of those drops and rises (relative to the loss), the candidate's `misfit` share. A real hole lowers it in the views that see
    the hole; a cut where there is none shows background or a wall in some views and raises it
    there. A kept free-space cut explains the patches it reaches. `unexplained`: the largest share of the fit's normal misfit on one candidate patch
    that no kept cut explains (tested or not): a disagreement the tests leave open.
    """

    vertices: np.ndarray
    faces: np.ndarray
    opened: list
    tested: list
    unexplained: float = 0.0


def open_handles(vertices, faces, cams: Cameras, targets, count: int, *, max_tries: int | None = None,
                 depths=None, min_radius: float = 0.0, free_space: bool = True):
    """Open up to `count` handles where the images show holes (module doc).

    Returns `(vertices, faces, records)`: the cut surface (the input when nothing
    was opened) and per opened handle `{"cut", "centre", "normal", "radius", "depth",
    "loss_before", "loss_after"}`: `cut` is `"carve"` (a part of the fit the silhouettes
    show empty: `centre` its centre, `normal` None, `radius` that of a ball of its volume, `depth` its
    longest extent), `"tunnel"` (then `centre` and `"end"` are
    its mouths, `normal` its direction, `depth` its length, `radius` that of a
    disc of its cross-section's area) or `"hole"`. The `max_tries` strongest candidates are used (default
    as `hole_tests`); `depths` are the hole depths tried (default 0.05 to 1.0); `min_radius`,
    `free_space` as in `hole_tests`.
    """
    if isinstance(count, bool) or int(count) != count or count < 0:
        raise ValueError(f"count: expected a number of handles >= 0, got {count!r}")
    tests = hole_tests(vertices, faces, cams, targets, int(count), max_tries=max_tries, depths=depths,
                       min_radius=min_radius, free_space=free_space)
    return tests.vertices, tests.faces, tests.opened


def hole_tests(vertices, faces, cams: Cameras, targets, count: int | None = None, *,
               max_tries: int | None = None, depths=None, min_radius: float = 0.0,
               free_space: bool = True) -> HoleTests:
    """Test cuts where the images show holes and keep those that lower the image loss (module
    doc), up to `count` (None: as many as the images confirm). The `max_tries` strongest
    candidates are tested (default `UNBOUNDED_TRIES`, or `2 count + 4` when that is more: the
    same candidates whether the genus is given or estimated).
    Cuts narrower than `min_radius` (the images' pixel: a hole they cannot show) are not tried.
    `free_space=False`: no cut of what the silhouettes show empty (only the normal images' patches)."""
    import manifold3d

    if count is not None and (isinstance(count, bool) or int(count) != count or count < 0):
        raise ValueError(f"count: expected a number of handles >= 0 or None, got {count!r}")
    v, f, targets = _checked(vertices, faces, cams, targets)
    v = v.astype(np.float32)
    solid = manifold3d.Manifold(manifold3d.Mesh(vert_properties=v, tri_verts=f.astype(np.uint32)))
    if solid.status() != manifold3d.Error.NoError:
        raise ValueError(f"faces: not a closed oriented manifold surface (manifold3d: {solid.status()})")
    if count == 0:
        return HoleTests(v, f, [], [])
    depths = np.arange(0.05, 1.0001, 0.05) if depths is None else depths
    hole_scales = (1.0, 0.75, 0.5)
    found = handle_candidates(v, f, cams, targets)
    if max_tries is None:
        max_tries = UNBOUNDED_TRIES if count is None else max(UNBOUNDED_TRIES, 2 * count + 4)
    candidates = found[:max_tries]
    limit = None if count is None else count  # None: every cut the images confirm
    per_view = view_losses(v, f, cams, targets)
    loss = float(np.mean(per_view))
    records, tested = [], []

    def keep(options, centre, misfit):
        """Keep the option `(cut, record)` that lowers the loss most, if any does; record the test."""
        nonlocal solid, v, f, loss, per_view
        best = None
        for cut, record in options:
            if record["radius"] < min_radius:
                continue
            out = cut.to_mesh()
            cv, cf = np.asarray(out.vert_properties, np.float32)[:, :3], np.asarray(out.tri_verts, np.int64)
            after = view_losses(cv, cf, cams, targets)
            if best is None or after.mean() < best[0].mean():
                best = (after, cut, cv, cf, record)
        if best is None:
            return False
        after = best[0]
        tested.append(_test_record(centre, best[4]["cut"], after, per_view, misfit))
        if not tested[-1]["kept"]:
            return False
        records.append({**best[4], "loss_before": loss, "loss_after": float(after.mean())})
        per_view, solid, v, f = best[:4]
        loss = float(per_view.mean())
        return True

    used, carved, tries = set(), set(), 0
    for part in _carved_parts(solid, cams, targets, min_radius) if free_space else ():
        if len(records) == limit or tries == max_tries:
            break
        hit = _carve_cut(solid, part)  # a bulge past a silhouette adds no handle and is not a try
        near = _patches_reached(hit[1], found) if hit is not None else []
        if not near:  # nor is a part where the normal images agree with the fit: no sign of a hole
            continue
        tries += 1
        # the patches a kept carve reaches count as explained, but a hole there is still tested: a part
        # carved from under a plate reaches the patches of holes that need their own cut
        if keep([(hit[2], hit[0])], hit[0]["centre"], sum(found[i].misfit for i in near)):
            carved.update(near)
    for i, j in _tunnel_pairs(candidates):  # tunnels between two mouths first: a hole into one then finds it
        if len(records) == limit:
            break
        if i in used or j in used:
            continue
        a, b = candidates[i], candidates[j]
        options = [(cut, {"cut": "tunnel", "centre": a.centre.tolist(), "end": b.centre.tolist(),
                          "normal": ((b.centre - a.centre) / length).tolist(), "radius": half,
                          "depth": length}) for length, half, cut in _tunnel_cut(solid, a, b)]
        if keep(options, 0.5 * (a.centre + b.centre), a.misfit + b.misfit):
            used.update((i, j))
    for i, cand in enumerate(candidates):
        if len(records) == limit:
            break
        if i in used:
            continue
        options = []
        for scale in hole_scales:  # a patch spreads past its hole's rim: narrower cuts too
            hit = _cylinder_cut(solid, cand._replace(radius=cand.radius * scale), depths)
            if hit is not None:
                options.append((hit[1], {"cut": "hole", "centre": cand.centre.tolist(), "normal": cand.normal.tolist(),
                                         "radius": cand.radius * scale, "depth": hit[0]}))
        if keep(options, cand.centre, cand.misfit):
            used.add(i)
    open_share = max((c.misfit for i, c in enumerate(found) if i not in used | carved), default=0.0)
    return HoleTests(v, f, records, tested, float(open_share))
