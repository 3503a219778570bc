"""Voxel Betti numbers and the handle-placement measure (`jaxgenus.metrics.handle_placement`).

References: voxel sets whose Betti numbers are counted by hand, and closed
surfaces of known genus built by manifold3d (exact booleans) rather than by the
library; a wrongly placed handle is a torus turned about an axis in its plane.
"""

from __future__ import annotations

import numpy as np
import pytest

import jaxgenus as jg
from _hidden import covered_plate


def _grid(n=7):
    return np.zeros((n, n, n), bool)


def test_betti_numbers_of_hand_counted_voxel_sets():
    cube = _grid()
    cube[1:6, 1:6, 1:6] = True
    assert jg.metrics.betti_numbers(cube) == (1, 0, 0)
    cavity = cube.copy()
    cavity[3, 3, 3] = False
    assert jg.metrics.betti_numbers(cavity) == (1, 0, 1)
    tunnel = cube.copy()
    tunnel[3, 3, :] = False
    assert jg.metrics.betti_numbers(tunnel) == (1, 1, 0)
    big = _grid(10)
    big[1:9, 1:9, 1:9] = True
    big[4, 6, :] = False  # along z
    apart_tunnels = big.copy()
    apart_tunnels[:, 2, 4] = False  # along x, three voxels away from the first
    assert jg.metrics.betti_numbers(apart_tunnels) == (1, 2, 0)
    crossing = big.copy()
    crossing[:, 6, 4] = False  # along x through the first: one void with 4 openings
    assert jg.metrics.betti_numbers(crossing) == (1, 3, 0)
    ring = _grid()
    ring[1:4, 1:4, 2] = True
    ring[2, 2, 2] = False  # a square ring of 8 voxels
    assert jg.metrics.betti_numbers(ring) == (1, 1, 0)
    diagonal = _grid()
    diagonal[1, 1, 1] = diagonal[2, 2, 2] = True  # closed cubes sharing a corner touch
    assert jg.metrics.betti_numbers(diagonal) == (1, 0, 0)
    apart = _grid()
    apart[1, 1, 1] = apart[3, 3, 3] = True
    assert jg.metrics.betti_numbers(apart) == (2, 0, 0)
    assert jg.metrics.betti_numbers(_grid()) == (0, 0, 0)
    with pytest.raises(ValueError, match="occupancy"):
        jg.metrics.betti_numbers(np.zeros((4, 4), bool))


@pytest.mark.parametrize("genus", [0, 1, 3])
def test_primitives_are_resolved_and_placed_against_themselves(genus):
    mesh = jg.genus_primitive(genus, n_faces=4000)
    p = jg.metrics.handle_placement(mesh, mesh, resolution=64)
    assert p.object_resolved and p.object == (1, genus, 0) and p.placed


def test_covered_plate_has_genus_four_on_a_128_grid():
    v, f, genus = covered_plate()
    assert genus == 4
    p = jg.metrics.handle_placement((v, f), (v, f), resolution=128)
    assert p.object_resolved and p.object.b1 == 4 and p.placed


def test_a_handle_in_the_wrong_place_is_not_placed():
    """Same genus, same size, turned 90 degrees: the genus agrees, the placement does not."""
    v, f = jg.builtin_scene("torus").to_numpy()
    turned = v @ np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]).T
    p = jg.metrics.handle_placement((v, f), (turned, f), resolution=64)
    assert p.object_resolved and p.result.b1 == 1
    assert not p.placed and (p.union.b1 != 1 or p.intersection.b1 != 1 or p.intersection.b0 != 1)
    shifted = jg.metrics.handle_placement((v, f), (v + np.array([0.05, 0.0, 0.0]), f), resolution=64)
    assert shifted.placed  # a small offset keeps the hole where it was
    ball = jg.genus_primitive(0, n_faces=2000)
    missing = jg.metrics.handle_placement((v, f), ball, resolution=64)
    assert not missing.placed and missing.result.b1 == 0


def test_handle_placement_rejects_bad_input():
    v, f = jg.builtin_scene("torus").to_numpy()
    with pytest.raises(ValueError, match="result"):
        jg.metrics.handle_placement((v, f), (v[:, :2], f))
    with pytest.raises(ValueError, match="obj"):
        jg.metrics.handle_placement((np.full_like(v, np.nan), f), (v, f))
    with pytest.raises(ValueError, match="resolution"):
        jg.metrics.handle_placement((v, f), (v, f), resolution=4)
