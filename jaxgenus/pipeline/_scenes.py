"""Built-in ground-truth scenes (manifold3d CSG) and crisp synthetic target images of a mesh."""

from __future__ import annotations

import numpy as np

from jaxgenus.geometry import Cameras
from jaxgenus.geometry import Mesh
from jaxgenus.rendering import render

__all__ = ["SCENES", "builtin_scene", "render_targets"]

#: name -> genus of the built-in scenes.
SCENES = {"torus": 1, "tilted_tori": 2, "three_tori": 3}


def _torus(major: float, minor: float):
    from manifold3d import CrossSection, Manifold

    return Manifold.revolve(CrossSection.circle(minor, 32).translate((major, 0.0)), 96)


def builtin_scene(name: str = "three_tori") -> Mesh:
    """A watertight ground-truth mesh, centred and scaled into the unit sphere.

    * `"torus"` (genus 1): an elliptic torus, squashed along one axis.
    * `"tilted_tori"` (genus 2): two tori of different sizes, one tilted by 25 degrees.
    * `"three_tori"` (genus 3): three tori of different sizes and tilts fused in a chain.
    """
    from manifold3d import Manifold, OpType

    if name not in SCENES:
        raise ValueError(f"name must be one of {sorted(SCENES)}, got {name!r}")
    a = _torus(0.75, 0.25)
    if name == "torus":
        shape = a.scale((1.0, 0.7, 1.3))
    else:
        parts = [a, _torus(0.6, 0.22).rotate((25.0, 0.0, 0.0)).translate((1.44, 0.3, 0.0))]
        if name == "three_tori":
            parts.append(_torus(0.55, 0.2).rotate((0.0, -30.0, 0.0)).translate((-1.36, -0.2, 0.1)))
        shape = Manifold.batch_boolean(parts, OpType.Add)
    if shape.genus() != SCENES[name] or len(shape.decompose()) != 1:
        raise RuntimeError(f"built-in scene {name!r} came out with genus {shape.genus()}")
    mesh = shape.to_mesh()
    v = np.asarray(mesh.vert_properties, np.float64)[:, :3]
    f = np.asarray(mesh.tri_verts, np.int64)
    v -= 0.5 * (v.min(0) + v.max(0))
    v /= np.linalg.norm(v, axis=1).max()
    return Mesh.from_numpy(v.astype(np.float32), f)


def render_targets(mesh: Mesh, cams: Cameras, *, supersample: int = 3, sigma: float = 0.1) -> np.ndarray:
    """Crisp synthetic RGBA targets `(N, H, W, 4)` of a ground-truth mesh.

    Renders alpha and world normals at `supersample` times the cameras'
    resolution with a near-hard silhouette (`sigma` / 100 px at the fine
    resolution), thresholds it at 0.5 (hard coverage of each fine pixel) and
    averages blocks of pixels down. A is the covered fraction; RGB is
    `(n + 1) / 2` of the mean normal over the covered part of the pixel (0 where
    nothing is covered).
    """
    if not isinstance(mesh, Mesh):
        raise ValueError(f"mesh must be a jaxgenus.Mesh, got {type(mesh).__name__}")
    if not isinstance(cams, Cameras):
        raise ValueError(f"cams must be a jaxgenus.Cameras, got {type(cams).__name__}")
    s = int(supersample)
    if s < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    h, w = cams.height, cams.width
    big = Cameras(cams.rotation, cams.translation, cams.focal * s, cams.principal_point * s, h * s, w * s)
    fine_sigma = sigma * 1e-2
    img = render(mesh, big, channels=("alpha", "normal"), sigma=fine_sigma, gamma=1e-3)
    img = np.asarray(img).reshape(len(cams), h, s, w, s, 4)
    # hard coverage of each fine pixel (the soft alpha dips to 0.75 on interior edges)
    cover = (img[..., :1] >= 0.5).astype(np.float32)
    a = cover.mean(axis=(2, 4))
    n = (img[..., 1:] * cover).mean(axis=(2, 4))
    covered = a > 0.0
    rgb = np.where(covered, (n / np.where(covered, a, 1.0) + 1.0) * 0.5, 0.0)
    return np.concatenate([np.clip(rgb, 0.0, 1.0), np.clip(a, 0.0, 1.0)], -1).astype(np.float32)
