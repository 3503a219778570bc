"""Handles from image evidence (`jaxgenus.open_handles`), against targets ray cast with trimesh.

The "fit" here is the covered plate without its three holes (genus 1, what a fit
at the visual hull's genus can reach at best), finely subdivided; the targets are
normal maps of the real plate (genus 4) ray cast by trimesh + embree, so neither
the holes' positions nor the images come from jaxgenus.
"""

from __future__ import annotations

import numpy as np
import pytest

import jaxgenus as jg
from _hidden import covered_plate, long_tunnel_plate
from _raycast import raycast


@pytest.fixture(scope="module")
def plate_scene():
    import trimesh

    v, f, genus = covered_plate()
    v1, f1, genus1 = covered_plate(holes=False)
    assert (genus, genus1) == (4, 1)
    fit_v, fit_f = trimesh.remesh.subdivide_to_size(v1, f1, 0.03)
    cams = jg.sphere_cameras(24, radius=3.0, fov_deg=40.0, resolution=128)
    truth = jg.Mesh.from_numpy(v.astype(np.float32), f.astype(np.int32))
    covered = jg.Mesh.from_numpy(v1.astype(np.float32), f1.astype(np.int32))
    return dict(truth=truth, fit=(fit_v, fit_f), cams=cams, holes=raycast(cams, truth),
                no_holes=raycast(cams, covered))


def test_candidates_find_the_three_holes(plate_scene):
    fit_v, fit_f = plate_scene["fit"]
    found = jg.handle_candidates(fit_v, fit_f, plate_scene["cams"], plate_scene["holes"])
    v, _, _ = covered_plate()
    scale = 1.0 / np.linalg.norm(np.array([2.0, 1.2, 0.62]) / 2)  # the plate's normalization (see _hidden)
    true_centres = (np.array([[0.5, 0.6, 0.62], [1.0, 0.6, 0.62], [1.5, 0.6, 0.62]]) - [1.0, 0.6, 0.31]) * scale
    best = np.array([c.centre for c in found[:3]])
    assert len(found) >= 3
    # each of the three strongest candidates lies on the plate's top over a different true hole
    nearest = np.argmin(np.linalg.norm(best[:, None] - true_centres[None], axis=-1), axis=1)
    assert sorted(nearest.tolist()) == [0, 1, 2]
    # ... with its centre inside that hole (radius 0.13 before scaling: 0.108)
    assert np.max(np.linalg.norm(best - true_centres[nearest], axis=-1)) < 0.13 * scale
    for c in found[:3]:
        assert 0.5 * 0.13 * scale < c.radius < 1.6 * 0.13 * scale
        assert c.normal[2] > 0.9  # the plate's top faces +z


def test_open_handles_places_the_object_handles(plate_scene):
    fit_v, fit_f = plate_scene["fit"]
    v, f, opened = jg.open_handles(fit_v, fit_f, plate_scene["cams"], plate_scene["holes"], 3)
    assert len(opened) == 3
    assert all(r["loss_after"] < r["loss_before"] for r in opened)
    mesh = jg.Mesh.from_numpy(v.astype(np.float32), f.astype(np.int32))
    assert jg.genus(mesh) == 4
    place = jg.metrics.handle_placement(plate_scene["truth"], mesh, resolution=128, genus=4)
    assert place.object_resolved and place.placed, place
    # the inputs are not modified
    assert fit_v.shape[1] == 3 and jg.genus(jg.Mesh.from_numpy(fit_v.astype(np.float32), fit_f.astype(np.int32))) == 1


def test_no_holes_in_the_images_opens_none(plate_scene):
    fit_v, fit_f = plate_scene["fit"]
    v, f, opened = jg.open_handles(fit_v, fit_f, plate_scene["cams"], plate_scene["no_holes"], 3)
    assert opened == []
    assert len(f) == len(fit_f)


def test_open_handles_rejects_bad_input(plate_scene):
    fit_v, fit_f = plate_scene["fit"]
    cams, targets = plate_scene["cams"], plate_scene["holes"]
    with pytest.raises(ValueError, match="targets"):
        jg.open_handles(fit_v, fit_f, cams, targets[:5], 3)
    with pytest.raises(ValueError, match="targets"):
        jg.open_handles(fit_v, fit_f, cams, targets[..., :3], 3)
    with pytest.raises(ValueError, match="count"):
        jg.open_handles(fit_v, fit_f, cams, targets, -1)
    with pytest.raises(ValueError, match="vertices"):
        jg.open_handles(fit_v[:, :2], fit_f, cams, targets, 1)


def test_reconstruct_takes_the_hidden_handles_from_the_images_in_user_units():
    """End to end, in millimetres off the origin: the run fits the hull's genus, opens the
    plate's holes where the images show them and records them in the user's units."""
    import jax

    v, f, genus = covered_plate()
    scale, shift = 250.0, np.array([100.0, -30.0, 40.0])
    truth = jg.Mesh.from_numpy((v * scale + shift).astype(np.float32), f.astype(np.int32))
    unit = jg.sphere_cameras(24, radius=3.0, fov_deg=40.0, resolution=128)
    eyes = -np.einsum("nji,nj->ni", np.asarray(unit.rotation), np.asarray(unit.translation))
    cams = jg.look_at(eyes * scale + shift, shift, (0.0, 1.0, 0.0), fov_deg=40.0, resolution=128)
    images = raycast(cams, truth)
    opts = jg.ReconstructOptions(n_cycles=2, steps_per_cycle=60)
    rec = jg.reconstruct(images, cams, genus, targets="normals", options=opts, key=jax.random.key(0))
    sources = [h["source"] for h in rec.history["handles"]]
    assert rec.genus == 4 and rec.history["start"].startswith("fit+images"), rec.history["start"]
    assert sources.count("hull") == 1 and sources.count("images") + sources.count("drilled") == 3
    assert sources.count("images") == 3, sources
    assert not any("drilled" in w for w in rec.history["warnings"])
    true_centres = np.array([[0.5, 0.6, 0.62], [1.0, 0.6, 0.62], [1.5, 0.6, 0.62]]) - [1.0, 0.6, 0.31]
    true_centres = true_centres * scale / np.linalg.norm([1.0, 0.6, 0.31]) + shift
    for h in rec.history["handles"][1:]:
        assert np.min(np.linalg.norm(true_centres - h["centre"], axis=1)) < 0.13 * 0.83 * scale
        assert 0.05 * scale < h["radius"] < 0.2 * scale and h["loss_after"] < h["loss_before"]
    place = jg.metrics.handle_placement(truth, rec.mesh, resolution=128, genus=4)
    assert place.placed, place


def test_a_long_tunnel_no_silhouette_shows_and_the_holes_into_it_are_opened():
    """The long-tunnel plate (genus 4; visual hull genus 0): the "fit" is the block with the
    tunnel and holes filled. The tunnel (1.6 long) is longer than any cut from one side; it
    is opened between its two mouths, then the three holes down into it."""
    import trimesh

    v, f, genus = long_tunnel_plate()
    v0, f0, genus0 = long_tunnel_plate(holes=False, filled=True)
    assert (genus, genus0) == (4, 0)
    fit_v, fit_f = trimesh.remesh.subdivide_to_size(v0, f0, 0.03)
    cams = jg.sphere_cameras(24, radius=3.0, fov_deg=40.0, resolution=128)
    truth = jg.Mesh.from_numpy(v.astype(np.float32), f.astype(np.int32))
    cut_v, cut_f, opened = jg.open_handles(fit_v, fit_f, cams, raycast(cams, truth), 4)
    assert [r["cut"] for r in opened] == ["tunnel", "hole", "hole", "hole"], opened
    tunnel = opened[0]
    axis = np.array([np.cos(np.radians(30.0)), np.sin(np.radians(30.0)), 0.0])  # the tunnel's axis (see _hidden)
    assert abs(np.dot(tunnel["normal"], axis)) > 0.95 and tunnel["depth"] > 1.2
    mesh = jg.Mesh.from_numpy(cut_v.astype(np.float32), cut_f.astype(np.int32))
    place = jg.metrics.handle_placement(truth, mesh, resolution=128, genus=4)
    assert place.object_resolved and place.placed, place
