"""The fitting problem the step-cost benchmarks share (public API only).

A mesh, its cameras, and normal-map targets of the same mesh stretched by
(1.2, 0.8, 0.9), with a rasterizer plan for the mesh. Imported by the scripts
beside it (`python benchmarks/NAME.py` puts this folder on the path).
"""

import jax.numpy as jnp
import numpy as np

import jaxgenus as jg


def stretched_fit(mesh, views: int, resolution: int):
    """`(cams, targets, plan)` for fitting `mesh` to its stretched copy."""
    cams = jg.sphere_cameras(views, radius=3.0, fov_deg=40.0, resolution=resolution)
    v, f = mesh.to_numpy()
    target = jg.Mesh.from_numpy(v * np.array([1.2, 0.8, 0.9]), f, capacity=(mesh.vertex_capacity, mesh.face_capacity))
    images = jg.render(target, cams, channels=("alpha", "normal"))
    targets = jnp.concatenate([(images[..., 1:] + 1.0) / 2.0, images[..., :1]], axis=-1)
    return cams, targets, jg.rendering.plan_render(mesh, cams, face_margin=1.5)
