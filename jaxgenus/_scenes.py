"""Built-in ground-truth scenes (manifold3d CSG), for demos, tests and benchmarks."""

from __future__ import annotations

import numpy as np

from jaxgenus._mesh import Mesh

__all__ = ["builtin_scene", "SCENES"]

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
