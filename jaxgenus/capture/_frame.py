"""The scene's frame: where the object is, how large, and the world size of a pixel.

`reconstruct` works in a canonical frame of its own choosing, so that the units
and the placement of the user's scene never matter: the object's visual hull is
centred at the origin and scaled so that it fits in the unit ball (about; its
carved grid points lie within radius 1). Cameras are mapped into that frame
exactly (`x_cam = R x + t` with `x = scale * x' + centre` gives
`R x' + (R centre + t) / scale` up to the factor `scale` on camera depths, which
a pinhole projection ignores) and the result is mapped back. Every length option
of `reconstruct` is in pixels or in this frame.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxgenus.geometry import Cameras
from jaxgenus.capture._hull import carved_points
from jaxgenus.geometry import Mesh

__all__ = ["SceneFrame", "pixel_footprint", "scene_frame"]


class SceneFrame(NamedTuple):
    """`x_world = scale * x_canonical + centre` (float64 host values)."""

    centre: np.ndarray
    scale: float

    def cameras_to_canonical(self, cams: Cameras) -> Cameras:
        """The same cameras looking at the canonical frame (same pixels for every point)."""
        rot = np.asarray(cams.rotation, np.float64)
        trans = np.asarray(cams.translation, np.float64)
        t = (np.einsum("nij,j->ni", rot, self.centre) + trans) / self.scale
        dtype = cams.translation.dtype
        return Cameras(cams.rotation, jnp.asarray(t, dtype), cams.focal, cams.principal_point, cams.height, cams.width)

    def region_to_canonical(self, region):
        """A sphere `(centre, radius)` of the world (or None) in the canonical frame."""
        return None if region is None else ((np.asarray(region[0], np.float64) - self.centre) / self.scale,
                                            float(region[1]) / self.scale)

    def mesh_to_world(self, mesh: Mesh) -> Mesh:
        """A copy of a canonical-frame `mesh` in world units (padding stays zero)."""
        v = np.asarray(mesh.vertices, np.float64) * self.scale + self.centre
        v = np.where(np.asarray(mesh.vertex_mask)[:, None], v, 0.0)
        return Mesh(vertices=jnp.asarray(v, mesh.vertices.dtype), faces=mesh.faces, n_vertices=mesh.n_vertices, n_faces=mesh.n_faces)


def scene_frame(alpha, cams: Cameras, *, resolution: int = 48, region=None) -> SceneFrame:
    """The canonical frame of silhouettes `alpha (N, H, W)`: the centre of the visual hull's
    bounding box and the largest distance from it to a carved grid point (plus one cell); the
    hull within the sphere `region` when one is given (`carved_points`)."""
    pts, cell = carved_points(alpha, cams, resolution=resolution, region=region)
    centre = 0.5 * (pts.min(0) + pts.max(0))
    radius = float(np.linalg.norm(pts - centre, axis=1).max()) + cell
    return SceneFrame(centre=centre, scale=radius)


def pixel_footprint(cams: Cameras, point) -> float:
    """Median over the cameras of the world size of one pixel at `point (3,)`."""
    depth = np.linalg.norm(np.asarray(cams.centers) - np.asarray(point), axis=1)
    return float(np.median(depth / np.asarray(cams.focal)[:, 0]))
