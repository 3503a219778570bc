import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

import jaxgenus as jg
from conftest import shared_mesh_table, shared_meshes_dir
from _meshes import torus, torus_trimesh


def _trimesh_chi(v, f):
    return trimesh.Trimesh(v, f, process=False).euler_number


@pytest.mark.parametrize("capacity", [None, 2000, (700, 1500)])
def test_torus_and_sphere_counts(capacity):
    mesh, m = torus(capacity=capacity), torus_trimesh()
    assert jg.euler_characteristic(mesh) == m.euler_number == 0
    assert jg.genus(mesh) == 1
    assert jg.is_closed_manifold(mesh)
    s = trimesh.creation.icosphere(2)
    sm = jg.Mesh.from_numpy(s.vertices, s.faces, capacity=1000)
    assert jg.euler_characteristic(sm) == 2 and jg.genus(sm) == 0


def test_components_and_per_component_genus():
    t = trimesh.creation.torus(1.0, 0.3, major_sections=16, minor_sections=8)
    s = trimesh.creation.icosphere(1)
    v = np.concatenate([t.vertices, s.vertices + 5.0])
    f = np.concatenate([t.faces, s.faces + len(t.vertices)])
    mesh = jg.Mesh.from_numpy(v, f, capacity=2048)
    n, labels = jg.geometry.connected_components(mesh)
    assert n == 2
    assert np.all(labels[: len(t.faces)] == labels[0]) and np.all(labels[len(t.faces) :] != labels[0])
    assert sorted(jg.component_genera(mesh)) == [0, 1]
    assert jg.genus(mesh) == 1
    assert jg.euler_characteristic(mesh) == 2


def test_open_mesh_is_reported():
    mesh = torus()
    v, f = mesh.to_numpy()
    open_mesh = jg.Mesh.from_numpy(v, f[1:])
    assert not jg.is_closed_manifold(open_mesh)
    with pytest.raises(ValueError, match="boundary"):
        jg.genus(open_mesh)
    r = jg.mesh_report(open_mesh)
    assert int(r.boundary_edges) == 3 and not bool(r.is_closed_manifold)


def test_nonmanifold_edge_is_reported():
    s = trimesh.creation.icosphere(1)
    v = np.concatenate([s.vertices, [[0.0, 0.0, 3.0]]])
    a, b = s.faces[0][:2]
    f = np.concatenate([s.faces, [[a, b, len(s.vertices)], [b, a, len(s.vertices)]]])
    mesh = jg.Mesh.from_numpy(v, f)
    assert int(jg.mesh_report(mesh).nonmanifold_edges) == 1
    with pytest.raises(ValueError, match="non-manifold edges"):
        jg.genus(mesh)


def test_nonmanifold_vertex_is_reported():
    # two tetrahedra sharing one vertex: edge-manifold, closed, but not vertex-manifold
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, 0, 0], [0, -1, 0], [0, 0, -1]], float)
    tet = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    tet2 = np.array([[0, 5, 4], [0, 4, 6], [0, 6, 5], [4, 5, 6]])
    mesh = jg.Mesh.from_numpy(v, np.concatenate([tet, tet2]))
    r = jg.mesh_report(mesh)
    assert int(r.nonmanifold_vertices) == 1 and int(r.boundary_edges) == 0
    assert not jg.is_closed_manifold(mesh)
    with pytest.raises(ValueError, match="non-manifold vertices"):
        jg.genus(mesh)


def test_flipped_face_is_reported():
    mesh = torus()
    v, f = mesh.to_numpy()
    f = f.copy()
    f[5] = f[5, ::-1]
    bad = jg.Mesh.from_numpy(v, f)
    assert int(jg.mesh_report(bad).flipped_edges) == 3
    with pytest.raises(ValueError, match="inconsistently oriented"):
        jg.genus(bad)


def test_invalid_counts_give_status_not_crash():
    mesh = torus(capacity=2000)
    broken = jg.Mesh(mesh.vertices, mesh.faces, jnp.int32(10), mesh.n_faces)  # indices beyond n_vertices
    assert int(jg.mesh_report(broken).status) == 1
    too_many = jg.Mesh(mesh.vertices, mesh.faces, mesh.n_vertices, jnp.int32(5000))
    assert int(jg.mesh_report(too_many).status) == 1
    with pytest.raises(ValueError, match="mesh"):
        jg.genus(too_many)


def test_ffi_under_jit_scan_and_vmap():
    mesh = torus(capacity=2000)

    @jax.jit
    def run(m):
        def body(carry, _):
            # grow the live face count by nothing; move vertices; check topology each step
            m2 = jg.Mesh(carry.vertices * 1.01, carry.faces, carry.n_vertices, carry.n_faces)
            r = jg.mesh_report(m2)
            return m2, (r.euler_characteristic, r.is_closed_manifold)

        return jax.lax.scan(body, m, None, length=4)

    _, (chis, ok) = run(mesh)
    assert chis.tolist() == [0, 0, 0, 0] and bool(jnp.all(ok))
    # traced counts: dropping faces inside jit changes the report
    r = jax.jit(lambda m, k: jg.mesh_report(jg.Mesh(m.vertices, m.faces, m.n_vertices, m.n_faces - k)))(mesh, 1)
    assert int(r.boundary_edges) == 3
    batched = jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), mesh)
    rb = jax.vmap(jg.mesh_report)(batched)
    assert rb.euler_characteristic.tolist() == [0, 0]


def test_padding_is_harmless_and_input_untouched():
    mesh, m = torus(capacity=4096), torus_trimesh()
    v0 = np.array(mesh.vertices)
    r = jg.mesh_report(mesh)
    assert int(r.n_faces) == len(m.faces) and int(r.n_vertices) == len(m.vertices)
    assert np.all(np.asarray(r.face_component)[len(m.faces) :] == -1)
    np.testing.assert_array_equal(v0, np.asarray(mesh.vertices))


@pytest.mark.parametrize("name,expected", shared_mesh_table() or [pytest.param("none", 0, marks=pytest.mark.skip("../shared/meshes absent"))])
def test_shared_meshes_genus(name, expected):
    mesh = jg.load_mesh(shared_meshes_dir() / name)
    v, f = mesh.to_numpy()
    assert jg.euler_characteristic(mesh) == _trimesh_chi(v, f) == 2 - 2 * expected
    assert jg.genus(mesh) == expected
    assert jg.is_closed_manifold(mesh)


def test_pieces_of_a_solid_are_those_manifold3d_decomposes():
    """`piece_count` and `pieces_larger_than` label a manifold3d solid's mesh instead of building every
    piece (`decompose`); against `decompose` on disjoint pieces of three sizes and genera."""
    import manifold3d

    from jaxgenus.geometry import piece_count, pieces_larger_than

    big = manifold3d.Manifold.cube((2.0, 2.0, 2.0)) - manifold3d.Manifold.cylinder(3.0, 0.4, 0.4, 32).translate((1.0, 1.0, -0.5))
    ring = manifold3d.Manifold.cylinder(0.5, 1.0, 1.0, 48) - manifold3d.Manifold.cylinder(0.5, 0.6, 0.6, 48)
    specks = [manifold3d.Manifold.cube((0.05, 0.05, 0.05)).translate((5.0 + i, 0.0, 0.0)) for i in range(5)]
    solid = big + ring.translate((4.0, 4.0, 0.0))
    for s in specks:
        solid = solid + s
    ref = solid.decompose()
    assert piece_count(solid) == len(ref) == 7 and piece_count(manifold3d.Manifold()) == 0
    kept = pieces_larger_than(solid, 0.01)
    want = sorted([p for p in ref if p.volume() > 0.01], key=lambda p: -p.volume())
    got = [(p.genus(), p.num_tri()) for p in kept]
    assert got == [(p.genus(), p.num_tri()) for p in want] and [g for g, _ in got] == [1, 1], got
    np.testing.assert_allclose([p.volume() for p in kept], [p.volume() for p in want], rtol=1e-6)
    assert len(kept) == 2 and all(p.status() == manifold3d.Error.NoError for p in kept)
    assert pieces_larger_than(manifold3d.Manifold(), 0.0) == []
