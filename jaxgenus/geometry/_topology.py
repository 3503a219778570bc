"""Topology of capacity meshes: Euler characteristic, genus, manifoldness, components.

`mesh_report` runs the native checker through the XLA FFI, so it works inside
`jit` and `lax.scan`; the other functions are host-side conveniences built on the
same kernel that return Python values and raise on meshes where the answer
would be wrong (open or non-manifold surfaces have no genus here).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Int

from jaxgenus._ffi import host_ffi_call, native
from jaxgenus.geometry._mesh import Mesh

__all__ = [
    "MeshReport",
    "mesh_report",
    "euler_characteristic",
    "genus",
    "component_genera",
    "is_closed_manifold",
    "connected_components",
    "piece_count",
    "pieces_larger_than",
]

# The report's entry names in buffer order, from the one native definition
# (JAXGENUS_REPORT_FIELDS in native/kernels/mesh_check.h).
_FIELDS = tuple(native.REPORT_FIELDS)


class MeshReport(eqx.Module):
    """What the native checker found (int32 scalars; a PyTree usable under `jit`).

    `status` is 0 for a readable mesh and 1 for invalid input (counts beyond
    capacity, indices out of range); the other fields are then zero.
    `face_component` labels live faces `0..n_components-1` and padding `-1`.
    """

    status: Int[Array, ""]
    n_vertices: Int[Array, ""]
    n_edges: Int[Array, ""]
    n_faces: Int[Array, ""]
    euler_characteristic: Int[Array, ""]
    boundary_edges: Int[Array, ""]
    nonmanifold_edges: Int[Array, ""]
    flipped_edges: Int[Array, ""]
    nonmanifold_vertices: Int[Array, ""]
    degenerate_faces: Int[Array, ""]
    n_components: Int[Array, ""]
    isolated_vertices: Int[Array, ""]
    face_component: Int[Array, "F"]

    @property
    def is_closed_manifold(self) -> Array:
        """True when the mesh is closed, edge- and vertex-manifold and consistently oriented."""
        bad = (
            self.boundary_edges
            + self.nonmanifold_edges
            + self.flipped_edges
            + self.nonmanifold_vertices
            + self.degenerate_faces
            + self.isolated_vertices
        )
        return (self.status == 0) & (bad == 0) & (self.n_faces > 0)


def _check_mesh(mesh) -> Mesh:
    if not isinstance(mesh, Mesh):
        raise ValueError(f"mesh must be a jaxgenus.Mesh, got {type(mesh).__name__}")
    if mesh.faces.ndim != 2 or mesh.faces.shape[1] != 3:
        raise ValueError(f"mesh.faces must have shape (F, 3), got {mesh.faces.shape}")
    return mesh


def mesh_report(mesh: Mesh) -> MeshReport:
    """Topology report of a (padded) mesh; runs in the native kernel via the XLA FFI.

    Works inside `jit`, `lax.scan` and `vmap` (sequentially). Not differentiable
    (it has nothing to differentiate).
    """
    mesh = _check_mesh(mesh)
    faces = jax.lax.stop_gradient(jnp.asarray(mesh.faces, jnp.int32))
    counts = jnp.stack([mesh.n_vertices, mesh.n_faces]).astype(jnp.int32)
    fcap = faces.shape[0]
    report, comp = host_ffi_call(
        "jaxgenus_mesh_check",
        (
            jax.ShapeDtypeStruct((native.REPORT_SIZE,), jnp.int32),
            jax.ShapeDtypeStruct((fcap,), jnp.int32),
        ),
        faces, jax.lax.stop_gradient(counts), vertex_capacity=np.int64(mesh.vertex_capacity))
    fields = {name: report[i] for i, name in enumerate(_FIELDS)}
    return MeshReport(**fields, face_component=comp)


def _host_report(mesh: Mesh) -> dict:
    """The same report computed through the numpy entry point (outside jit)."""
    mesh = _check_mesh(mesh)
    faces = np.ascontiguousarray(np.asarray(mesh.faces), dtype=np.int32)
    report, comp = native.mesh_check(faces, int(mesh.n_vertices), int(mesh.n_faces), mesh.vertex_capacity)
    out = {name: int(report[i]) for i, name in enumerate(_FIELDS)}
    out["face_component"] = comp
    if out["status"] != 0:
        raise ValueError("mesh: invalid mesh (live counts exceed capacity or face indices out of range)")
    return out


def _problems(r: dict) -> list[str]:
    names = {
        "boundary_edges": "boundary edges (the mesh is open)",
        "nonmanifold_edges": "non-manifold edges (more than two faces on an edge)",
        "flipped_edges": "edges with inconsistently oriented faces",
        "nonmanifold_vertices": "non-manifold vertices",
        "degenerate_faces": "faces with a repeated vertex",
        "isolated_vertices": "vertices used by no face",
    }
    out = [f"{r[k]} {text}" for k, text in names.items() if r[k]]
    if r["n_faces"] == 0:
        out.append("no faces")
    return out


def euler_characteristic(mesh: Mesh) -> int:
    """chi = V - E + F of the live part (any mesh; padding ignored)."""
    return _host_report(mesh)["euler_characteristic"]


def is_closed_manifold(mesh: Mesh) -> bool:
    """True when the mesh is closed, edge- and vertex-manifold and consistently oriented."""
    return not _problems(_host_report(mesh))


def connected_components(mesh: Mesh) -> tuple[int, np.ndarray]:
    """`(n_components, labels)`: edge-connected face components; labels has one entry per live face."""
    r = _host_report(mesh)
    nf = r["n_faces"]
    return r["n_components"], np.asarray(r["face_component"][:nf])


def component_genera(mesh: Mesh) -> list[int]:
    """Genus of each connected component of a closed orientable manifold mesh.

    Raises `ValueError` for open, non-manifold or inconsistently oriented meshes.
    """
    r = _host_report(mesh)
    problems = _problems(r)
    if problems:
        raise ValueError("mesh: genus is defined here only for closed orientable manifolds; found " + ", ".join(problems))
    nf = r["n_faces"]
    faces = np.asarray(mesh.faces[:nf])
    labels = np.asarray(r["face_component"][:nf])
    # closed and edge-manifold: every edge has two faces, so a component of F faces has 3F/2 edges
    # and chi = V - 3F/2 + F
    n_f = np.bincount(labels, minlength=r["n_components"])
    vertex_label = np.full(int(faces.max()) + 1, -1)
    vertex_label[faces.ravel()] = np.repeat(labels, 3)
    n_v = np.bincount(vertex_label[vertex_label >= 0], minlength=r["n_components"])
    return [int((2 - (int(v) - int(f) // 2)) // 2) for v, f in zip(n_v, n_f)]


def genus(mesh: Mesh) -> int:
    """Total genus (sum over components) of a closed orientable manifold mesh.

    For a single component this is `(2 - chi) / 2`. Raises `ValueError` for open,
    non-manifold or inconsistently oriented meshes rather than return a wrong number.
    """
    return int(sum(component_genera(mesh)))


# --- pieces of a manifold3d solid (the hole tests' cuts): labelled on its mesh, not built by decompose()

def _solid_pieces(solid):
    """`(vertices (V, 3), faces (F, 3), the piece of each face, how many pieces)` of `solid`'s mesh."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components as graph_components

    mesh = solid.to_mesh()
    v = np.asarray(mesh.vert_properties, np.float64)[:, :3]
    f = np.asarray(mesh.tri_verts, np.int64).reshape(-1, 3)
    same = np.arange(len(v))  # vertices a property seam split: one vertex for the labelling
    same[np.asarray(mesh.merge_from_vert, np.int64)] = np.asarray(mesh.merge_to_vert, np.int64)
    g = same[f]
    edges = coo_matrix((np.ones(2 * len(g)), (g[:, [0, 1]].ravel(), g[:, [1, 2]].ravel())), shape=(len(v), len(v)))
    _, label = graph_components(edges, directed=False)
    used = np.unique(g)
    return v, f, label[g[:, 0]], len(np.unique(label[used])) if len(used) else 0


def piece_count(solid) -> int:
    """How many connected pieces `solid` has (`len(solid.decompose())`, without building them)."""
    return _solid_pieces(solid)[3]


def pieces_larger_than(solid, volume: float) -> list:
    """The pieces of `solid` whose volume exceeds `volume`, as Manifolds, largest first (those of
    `solid.decompose()`; the smaller ones are never built)."""
    import manifold3d

    v, f, piece, _ = _solid_pieces(solid)
    if not len(f):
        return []
    p = v[f]
    signed = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])) / 6.0
    volumes = np.bincount(piece, signed)
    kept = []
    for k in np.flatnonzero(volumes > volume):
        used, local = np.unique(f[piece == k], return_inverse=True)
        kept.append(manifold3d.Manifold(manifold3d.Mesh(vert_properties=v[used].astype(np.float32),
                                                        tri_verts=local.reshape(-1, 3).astype(np.uint32))))
    return sorted(kept, key=lambda m: -m.volume())
