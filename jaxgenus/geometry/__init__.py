"""Meshes and what is computed on them alone: the `Mesh` type, cameras and projection, mesh files,
topology, differential operators, energies, genus-g primitives, Betti numbers, distances, and the
native remesher. Depends on nothing else in jaxgenus.
"""

from jaxgenus.geometry._betti import Betti, HandlePlacement, betti_numbers, handle_placement, voxelize
from jaxgenus.geometry._cameras import (
    Cameras,
    cameras_from_blender,
    cameras_from_opencv,
    cameras_from_opengl,
    cameras_to_opencv,
    cameras_to_opengl,
    look_at,
    project,
    sphere_cameras,
)
from jaxgenus.geometry._energies import bilaplacian_energy, inversion_penalty, inverted_face_count
from jaxgenus.geometry._mesh import Mesh, capacity_bucket, load_mesh, save_mesh
from jaxgenus.geometry._metrics import (
    ChamferResult,
    ICPResult,
    Normalization,
    chamfer_distance,
    hausdorff_distance,
    icp_align,
    normalize_to_unit_sphere,
    volume_iou,
)
from jaxgenus.geometry._operators import UniformLaplacian, face_normals, uniform_laplacian, vertex_normals
from jaxgenus.geometry._primitives import genus_primitive
from jaxgenus.geometry._photo_depth import PhotoDepthFit, fit_photo_depth
from jaxgenus.geometry._reprojection import (OutlineFit, Reprojection, UnseenFill, fill_unseen, fit_outline,
                                             reprojection_psnr, seen_counts)
from jaxgenus.geometry._subdivision import Subdivision, phong_subdivision
from jaxgenus.geometry._remesh import RemeshInfo, RemeshOptions, RemeshStatus, remesh, remesh_in_jit, settings_repr
from jaxgenus.geometry._topology import (
    MeshReport,
    component_genera,
    connected_components,
    euler_characteristic,
    genus,
    is_closed_manifold,
    mesh_report,
    piece_count,
    pieces_larger_than,
)

__all__ = [
    "Betti",
    "Cameras",
    "ChamferResult",
    "HandlePlacement",
    "ICPResult",
    "Mesh",
    "MeshReport",
    "Normalization",
    "RemeshInfo",
    "RemeshOptions",
    "RemeshStatus",
    "Subdivision",
    "UniformLaplacian",
    "betti_numbers",
    "bilaplacian_energy",
    "cameras_from_blender",
    "cameras_from_opencv",
    "cameras_from_opengl",
    "cameras_to_opencv",
    "cameras_to_opengl",
    "capacity_bucket",
    "chamfer_distance",
    "Reprojection",
    "reprojection_psnr",
    "UnseenFill",
    "fill_unseen",
    "OutlineFit",
    "fit_outline",
    "PhotoDepthFit",
    "fit_photo_depth",
    "seen_counts",
    "component_genera",
    "connected_components",
    "euler_characteristic",
    "face_normals",
    "genus",
    "genus_primitive",
    "handle_placement",
    "hausdorff_distance",
    "icp_align",
    "inversion_penalty",
    "inverted_face_count",
    "is_closed_manifold",
    "load_mesh",
    "look_at",
    "mesh_report",
    "phong_subdivision",
    "piece_count",
    "pieces_larger_than",
    "normalize_to_unit_sphere",
    "project",
    "remesh",
    "remesh_in_jit",
    "settings_repr",
    "save_mesh",
    "sphere_cameras",
    "uniform_laplacian",
    "vertex_normals",
    "volume_iou",
    "voxelize",
]
