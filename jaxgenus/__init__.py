"""jaxgenus: inverse rendering of watertight triangle meshes of any genus, in JAX.

    >>> import jaxgenus as jg
    >>> gt = jg.builtin_scene("torus")
    >>> cams = jg.sphere_cameras(16, radius=3.0, fov_deg=40.0, resolution=64)
    >>> rec = jg.reconstruct(jg.render_targets(gt, cams), cams, genus=1)  # doctest: +SKIP
    >>> rec.genus, rec.history["ok"]  # doctest: +SKIP
    (1, True)

The names here are the ones a user calls. The package is built in layers, one subpackage
each, imports pointing down the list; each keeps its advanced names public in its own
`__all__` (kernels, optimizer state, plans, run records):

* `jaxgenus.geometry`: meshes, cameras, topology, operators, energies, primitives, remeshing;
* `jaxgenus.rendering`: the soft rasterizer and photo shading;
* `jaxgenus.capture`: images, masks, camera files, pairing, targets, visual hull, frame;
* `jaxgenus.optim`: the objective and the large-steps optimizer;
* `jaxgenus.pipeline`: `reconstruct` and its stages;
* `jaxgenus.metrics`: chamfer distance, volume IoU, Hausdorff, ICP, handle placement.
"""

from importlib.metadata import PackageNotFoundError as _PackageNotFoundError, version as _version

from jaxgenus import capture, geometry, metrics, optim, pipeline, rendering

from jaxgenus.geometry import (
    Cameras,
    cameras_from_blender,
    cameras_from_opencv,
    cameras_from_opengl,
    cameras_to_opencv,
    component_genera,
    euler_characteristic,
    genus,
    genus_primitive,
    is_closed_manifold,
    load_mesh,
    look_at,
    Mesh,
    mesh_report,
    phong_subdivision,
    project,
    remesh,
    RemeshOptions,
    save_mesh,
    sphere_cameras,
)
from jaxgenus.rendering import (
    render,
    render_photo,
    RenderSettings,
)
from jaxgenus.capture import (
    load_cameras,
    load_images,
    load_region,
    pair_images,
    visual_hull,
)
from jaxgenus.optim import (
    LossWeights,
    OptimizeOptions,
)
from jaxgenus.pipeline import (
    builtin_scene,
    genus_estimate,
    GenusEstimate,
    History,
    reconstruct,
    Reconstruction,
    ReconstructOptions,
    render_targets,
    SCENES,
)

try:
    __version__ = _version("jaxgenus")
except _PackageNotFoundError:  # imported from a source tree that was never installed
    __version__ = "0+unknown"

__all__ = [
    "builtin_scene",
    "Cameras",
    "cameras_from_blender",
    "cameras_from_opencv",
    "cameras_from_opengl",
    "cameras_to_opencv",
    "component_genera",
    "euler_characteristic",
    "genus",
    "genus_estimate",
    "genus_primitive",
    "GenusEstimate",
    "History",
    "is_closed_manifold",
    "load_cameras",
    "load_images",
    "load_mesh",
    "load_region",
    "look_at",
    "LossWeights",
    "Mesh",
    "mesh_report",
    "metrics",
    "OptimizeOptions",
    "pair_images",
    "phong_subdivision",
    "project",
    "reconstruct",
    "Reconstruction",
    "ReconstructOptions",
    "remesh",
    "RemeshOptions",
    "render",
    "render_photo",
    "render_targets",
    "RenderSettings",
    "save_mesh",
    "SCENES",
    "sphere_cameras",
    "visual_hull",
]
