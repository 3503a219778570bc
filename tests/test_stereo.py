"""Plane-sweep stereo and free-space carving (jaxgenus.capture._stereo) against photos and depths ray cast
by trimesh, not by our renderer."""

import manifold3d
import numpy as np
import pytest
import trimesh

import jaxgenus as jg
from jaxgenus.capture import carved_occupancy, consistent_depths, hull_occupancy, stereo_depths, visual_hull_bounds
from jaxgenus.optim import view_neighbours
from _raycast import cell_albedo, raycast_depth, raycast_lambert

LIGHT = np.array([0.4, 0.8, 0.45]) / np.linalg.norm([0.4, 0.8, 0.45])


def cup() -> trimesh.Trimesh:
    """A block with a round pit in its top (closed at the bottom): no silhouette shows the pit."""
    block = manifold3d.Manifold.cube([1.6, 1.6, 1.0], center=True)
    pit = manifold3d.Manifold.cylinder(0.8, 0.45, 0.45, 48).translate([0.0, 0.0, -0.2])
    m = (block - pit).to_mesh()
    return trimesh.Trimesh(np.asarray(m.vert_properties)[:, :3], np.asarray(m.tri_verts), process=False)


@pytest.fixture(scope="module")
def scene():
    tm = cup()
    cams = jg.sphere_cameras(60, radius=3.5, fov_deg=40.0, resolution=80)
    photos = np.asarray(raycast_lambert(cams, tm, light_direction=LIGHT, ambient=0.3, albedo=cell_albedo(0.08)),
                        np.float32)
    photos[..., :3] *= photos[..., 3:4]  # premultiplied, as check_targets returns them
    lo, hi = visual_hull_bounds(photos[..., 3], cams)
    table = view_neighbours(cams, points=np.asarray(tm.vertices))
    return tm, cams, photos, (lo, hi), table, stereo_depths(photos, cams, table, (lo, hi))


def test_depths_match_the_ray_cast_depths(scene):
    tm, cams, photos, bounds, table, sd = scene
    truth = raycast_depth(cams, tm)
    kept = np.isfinite(sd.depth) & (truth > 0)
    assert kept.sum() > 0.25 * (truth > 0).sum()
    err = np.abs(sd.depth[kept] - truth[kept]) / truth[kept]
    assert np.median(err) < 0.01 and np.mean(err < 0.05) > 0.75, (np.median(err), np.mean(err < 0.05))
    agreed = consistent_depths(sd, cams, table)
    both = np.isfinite(agreed.depth) & (truth > 0)
    err2 = np.abs(agreed.depth[both] - truth[both]) / truth[both]
    assert both.sum() > 0.15 * kept.sum() and np.mean(err2 < 0.05) > 0.95, (both.sum() / kept.sum(), np.mean(err2 < 0.05))


def test_carving_opens_the_pit_and_keeps_the_solid(scene):
    tm, cams, photos, bounds, table, sd = scene
    occ = hull_occupancy(photos[..., 3], cams, resolution=32, bounds=bounds)
    sd = consistent_depths(sd, cams, table)
    carved, share = carved_occupancy(occ, sd, cams, margin=2 * occ.cell)
    grid = occ.lo + occ.cell * np.stack(np.meshgrid(*[np.arange(s) for s in occ.values.shape], indexing="ij"), -1)
    grid = grid.reshape(-1, 3)
    was, now = occ.values.ravel() >= 0.5, carved.values.ravel() >= 0.5
    depth_in = trimesh.proximity.ProximityQuery(tm).signed_distance(grid)  # > 0 inside the cup
    pit = was & (np.hypot(grid[:, 0], grid[:, 1]) < 0.4) & (grid[:, 2] > -0.1) & (grid[:, 2] < 0.4)
    solid = was & (depth_in > 2 * occ.cell)
    assert pit.sum() > 20 and np.mean(~now[pit]) > 0.5, np.mean(~now[pit])  # the silhouettes kept it; the photos empty it
    assert np.mean(~now[solid]) < 0.01 and 0 < share < 0.5
    assert occ.values is not carved.values and np.array_equal(occ.values.ravel() >= 0.5, was)  # the input is kept


def test_textureless_or_unpaired_views_give_no_depth(scene):
    _, cams, photos, bounds, table, _ = scene
    cams, photos, table = cams[:12], photos[:12], np.minimum(table[:12], 11)
    flat = photos.copy()
    flat[..., :3] = 0.5 * flat[..., 3:4]  # one grey: nothing to match
    assert np.isnan(stereo_depths(flat, cams, table, bounds).depth).all()
    alone = np.arange(len(cams))[:, None]  # every view paired with itself only
    assert np.isnan(stereo_depths(photos, cams, alone, bounds).depth).all()
    with pytest.raises(ValueError, match="neighbours"):
        stereo_depths(photos, cams, table[:3], bounds)


def test_neighbours_by_overlap_pair_views_of_a_part():
    """Cameras that each see one end of a long object (not its centre) are paired by what they share."""
    cams = jg.sphere_cameras(24, radius=3.0, fov_deg=40.0, resolution=64)
    pts = np.random.default_rng(0).uniform(-1, 1, (500, 3)) * [4.0, 0.3, 0.3]
    table = view_neighbours(cams, points=pts)
    assert not (table == np.arange(24)[:, None]).all(1).any()
    with pytest.raises(ValueError, match="points"):
        view_neighbours(cams, points=np.full((3, 3), np.nan))



def test_stereo_depth_cost_is_lowest_at_the_target_and_its_gradient_matches_finite_differences():
    import jax
    import jax.numpy as jnp
    from jaxgenus.optim import stereo_depth_cost
    from _meshes import torus, torus_trimesh

    cams = jg.sphere_cameras(6, radius=3.0, fov_deg=40.0, resolution=48)
    truth = raycast_depth(cams, torus_trimesh(1.0, 0.35, 64, 32))  # the depths stereo would find
    target = np.where(truth > 0, truth, np.nan)

    def cost(mesh, c, t):
        r = jg.render(mesh, c, channels=("alpha", "depth"))
        return stereo_depth_cost(r[..., 1], r[..., 0], t)

    values = {s: float(cost(torus(1.0, 0.35 * s, 64, 32), cams, jnp.asarray(target))) for s in (0.9, 1.0, 1.1)}
    assert values[1.0] < 0.5 * min(values[0.9], values[1.1]), values
    assert float(stereo_depth_cost(jnp.ones((2, 8, 8)), jnp.ones((2, 8, 8)), jnp.full((2, 8, 8), jnp.nan))) == 0.0
    with jax.enable_x64(True):
        m = torus(1.0, 0.35 * 1.04, 32, 16, dtype=jnp.float64)
        c64 = jax.tree.map(lambda a: jnp.asarray(a, jnp.float64), cams)
        t64 = jnp.asarray(target, jnp.float64)

        def f(v):
            return cost(jg.Mesh(vertices=v, faces=m.faces, n_vertices=m.n_vertices, n_faces=m.n_faces), c64, t64)

        g = jax.grad(f)(m.vertices)
        assert bool(jnp.all(jnp.isfinite(g)))
        rng = np.random.default_rng(0)
        for _ in range(3):  # directional derivatives along smooth random fields
            d = jnp.asarray(np.sin(m.vertices @ rng.normal(size=(3, 3))) * 1e-3)
            h = 1e-5  # the pixels counted (held constant) must not change between the two evaluations
            fd = (f(m.vertices + h * d) - f(m.vertices - h * d)) / (2 * h)
            an = jnp.sum(g * d)
            assert abs(float(fd - an)) <= 0.1 * abs(float(fd)) + 1e-6, (float(fd), float(an))
