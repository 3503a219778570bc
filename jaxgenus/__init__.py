"""jaxgenus: inverse rendering of watertight triangle meshes of any genus, in JAX.

The public API is flat: everything a user needs is re-exported here from the
private modules (one concept per module), and `__all__` lists it.
"""

from importlib.metadata import PackageNotFoundError as _PackageNotFoundError, version as _version

from jaxgenus._mesh import Mesh, capacity_bucket
from jaxgenus._cameras import (
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
from jaxgenus._io import load_mesh, save_mesh
from jaxgenus._images import LoadedImages, load_images
from jaxgenus._camera_files import load_cameras
from jaxgenus._pairing import pair_images
from jaxgenus._topology import (
    MeshReport,
    component_genera,
    connected_components,
    euler_characteristic,
    genus,
    is_closed_manifold,
    mesh_report,
)
from jaxgenus._remesh import RemeshInfo, RemeshOptions, RemeshStatus, remesh, remesh_in_jit
from jaxgenus._primitives import genus_primitive
from jaxgenus import metrics
from jaxgenus._operators import UniformLaplacian, face_normals, uniform_laplacian, vertex_normals
from jaxgenus._plan import RasterPlan, plan_render, static_plan
from jaxgenus._render import CHANNEL_SIZES, RenderInfo, render
from jaxgenus._handles import HandleCandidate, handle_candidates, normal_image_loss, open_handles
from jaxgenus._shading import (LIGHTING_SHAPE, LIGHTING_SHAPES, directional_lighting, face_colors, irradiance,
                               lighting_model, render_photo)
from jaxgenus._carving import carving_term
from jaxgenus._containment import containment_penalty, outside_distance
from jaxgenus._energies import bilaplacian_energy, inversion_penalty
from jaxgenus._loss import LossWeights, image_loss, objective, render_channels
from jaxgenus._largesteps import (
    SolveInfo,
    from_differential,
    lambda_from_alpha,
    largesteps_solve,
    to_differential,
)
from jaxgenus._adam import GradientTransformation, UniformAdamState, uniform_adam
from jaxgenus._optimize import (
    RECORD_KEYS,
    Appearance,
    OptimizeOptions,
    OptimizerState,
    init_optimizer_state,
    optimize_block,
)
from jaxgenus._options import ReconstructOptions
from jaxgenus._history import CycleRecord, History
from jaxgenus._reconstruct import Reconstruction, reconstruct
from jaxgenus._hull import visual_hull
from jaxgenus._scenes import SCENES, builtin_scene, render_targets

try:
    __version__ = _version("jaxgenus")
except _PackageNotFoundError:  # imported from a source tree that was never installed
    __version__ = "0+unknown"

__all__ = [
    "Appearance",
    "CHANNEL_SIZES",
    "Cameras",
    "CycleRecord",
    "GradientTransformation",
    "HandleCandidate",
    "History",
    "LIGHTING_SHAPE",
    "LIGHTING_SHAPES",
    "LoadedImages",
    "LossWeights",
    "Mesh",
    "MeshReport",
    "OptimizeOptions",
    "OptimizerState",
    "RECORD_KEYS",
    "RasterPlan",
    "ReconstructOptions",
    "Reconstruction",
    "RemeshInfo",
    "RemeshOptions",
    "RemeshStatus",
    "RenderInfo",
    "SCENES",
    "SolveInfo",
    "UniformAdamState",
    "UniformLaplacian",
    "bilaplacian_energy",
    "builtin_scene",
    "cameras_from_blender",
    "cameras_from_opencv",
    "cameras_from_opengl",
    "cameras_to_opencv",
    "cameras_to_opengl",
    "directional_lighting",
    "capacity_bucket",
    "carving_term",
    "component_genera",
    "connected_components",
    "containment_penalty",
    "euler_characteristic",
    "face_colors",
    "face_normals",
    "from_differential",
    "genus",
    "handle_candidates",
    "genus_primitive",
    "image_loss",
    "irradiance",
    "init_optimizer_state",
    "inversion_penalty",
    "is_closed_manifold",
    "lambda_from_alpha",
    "largesteps_solve",
    "lighting_model",
    "load_cameras",
    "load_images",
    "load_mesh",
    "look_at",
    "mesh_report",
    "metrics",
    "normal_image_loss",
    "objective",
    "open_handles",
    "outside_distance",
    "optimize_block",
    "pair_images",
    "plan_render",
    "static_plan",
    "project",
    "reconstruct",
    "remesh",
    "remesh_in_jit",
    "render",
    "render_channels",
    "render_photo",
    "render_targets",
    "save_mesh",
    "sphere_cameras",
    "to_differential",
    "uniform_adam",
    "uniform_laplacian",
    "vertex_normals",
    "visual_hull",
]
