"""jaxgenus: inverse rendering of watertight triangle meshes of any genus, in JAX.

The public API is flat: everything a user needs is re-exported here from the
private modules (one concept per module).
"""

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
from jaxgenus._energies import (
    LossWeights,
    bilaplacian_energy,
    image_loss,
    inversion_penalty,
    objective,
    render_channels,
)
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
    OptimizeOptions,
    OptimizerState,
    init_optimizer_state,
    optimize_block,
)
from jaxgenus._render import CHANNEL_SIZES, RasterPlan, RenderInfo, plan_render, render
from jaxgenus._reconstruct import ReconstructOptions, Reconstruction, reconstruct, render_targets
from jaxgenus._hull import visual_hull
from jaxgenus._scenes import SCENES, builtin_scene

__version__ = "0.1.0"
