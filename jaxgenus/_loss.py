"""The inverse-rendering objective: image loss of the soft render plus the geometric energies.

`objective` is `Phi(R(x)) + w_bilaplacian * bilaplacian_energy(x)
+ w_inversion * inversion_penalty(x, x_rest)`, where `Phi` is the l1
`image_loss` between the soft render `R(x)` and the target images. A term whose
weight is 0 is not computed at all (weights are static Python floats). This
module sits above the renderer and the energies and combines them.

Target images are `(N, H, W, 1)` silhouettes (alpha) or `(N, H, W, 4)` RGBA
images whose RGB is the world normal mapped to `(n + 1) / 2` and whose A is the
silhouette. The render is asked for exactly the channels the target has
(`render_channels`): `("alpha",)` gives `(N, H, W, 1)` and `("alpha", "normal")`
gives `(N, H, W, 4)` = alpha followed by the world normal in `[-1, 1]`.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import jax.numpy as jnp
from jaxtyping import Array, Float

from jaxgenus._energies import bilaplacian_energy, inversion_penalty
from jaxgenus._render import render

__all__ = ["LossWeights", "image_loss", "image_terms", "objective", "render_channels"]


@dataclasses.dataclass(frozen=True)
class LossWeights:
    """Static weights of the objective's terms (0 skips a term entirely).

    Defaults: `alpha = 1`, `normal = 1` (each image term is a mean over the
    pixels, so they are O(1) and resolution-independent), `bilaplacian = 0`
    (the large-steps parametrization already smooths; raise it, e.g. to
    `1e-2 / n_vertices`, to penalize curvature explicitly -- `||L x||^2` is a sum over
    vertices), and `inversion = 1` (zero unless a triangle flips; one face
    folded flat onto itself, `det J = -1`, costs as much as the whole image term
    can). Larger inversion weights also unfold every face, but the gradient
    spike of a fold inflates uniform Adam's second moment, which then shrinks
    all later steps (docs/stability.md: at lambda = 1, learning rate 0.5, the
    image loss after 100 steps is 0.034 with weight 1 and 0.117 with weight 1e3).
    """

    alpha: float = 1.0
    normal: float = 1.0
    bilaplacian: float = 0.0
    inversion: float = 1.0

    def __post_init__(self):
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, (int, float)) or not v >= 0.0 or v == float("inf"):
                raise ValueError(f"weights.{f.name} must be a finite Python float >= 0, got {v!r}")


def render_channels(target: Float[Array, "N H W C"]) -> tuple[str, ...]:
    """The render channels a target needs: `("alpha",)` for C = 1, `("alpha", "normal")` for C = 4."""
    c = target.shape[-1]
    if target.ndim != 4 or c not in (1, 4):
        raise ValueError(f"target must have shape (N, H, W, 1) or (N, H, W, 4), got {target.shape}")
    return ("alpha",) if c == 1 else ("alpha", "normal")


def image_terms(rendered, target, weights: LossWeights) -> dict[str, Array]:
    """The weighted image terms `{"alpha": ..., "normal": ...}` (a term with weight 0 is absent)."""
    render_channels(target)
    if rendered.shape != target.shape:
        raise ValueError(f"rendered must have the target's shape {target.shape}, got {rendered.shape}")
    terms = {}
    if target.shape[-1] == 4:
        t_alpha = target[..., 3]
        if weights.normal:
            err = jnp.abs(0.5 * (rendered[..., 1:4] + 1.0) - target[..., :3])
            terms["normal"] = weights.normal * jnp.mean(t_alpha[..., None] * err)
    else:
        t_alpha = target[..., 0]
    if weights.alpha:
        terms["alpha"] = weights.alpha * jnp.mean(jnp.abs(rendered[..., 0] - t_alpha))
    return terms


def image_loss(
    rendered: Float[Array, "N H W C"], target: Float[Array, "N H W C"], *, weights: LossWeights = LossWeights()
) -> Float[Array, ""]:
    """l1 image loss over the channels the target has.

    `alpha`: mean over pixels of `|alpha - alpha_target|`. `normal` (RGBA targets
    only): mean over pixels and the 3 channels of `A_target * |(n + 1) / 2 - RGB_target|`,
    i.e. normals count only where the target alpha is set. Each is multiplied by
    its weight in `weights`.
    """
    terms = image_terms(rendered, target, weights)
    return sum(terms.values(), jnp.zeros((), rendered.dtype))


def objective(
    mesh,
    cameras,
    target: Float[Array, "N H W C"],
    rest_vertices: Float[Array, "V 3"],
    *,
    weights: LossWeights = LossWeights(),
    renderer: Callable | None = None,
    render_kwargs: dict | None = None,
) -> tuple[Float[Array, ""], dict[str, Array]]:
    """The total objective at `mesh.vertices` and its weighted terms.

    Renders `mesh` with `renderer(mesh, cameras, channels=..., **render_kwargs)`
    (default `jaxgenus.render`) for the channels `target` has, and returns
    `(total, terms)` where `terms` holds the weighted `alpha`, `normal`,
    `bilaplacian` and `inversion` values that were computed (weight 0: absent).
    """
    renderer = render if renderer is None else renderer
    terms = {}
    if weights.alpha or (weights.normal and target.shape[-1] == 4):
        rendered = renderer(mesh, cameras, channels=render_channels(target), **(render_kwargs or {}))
        terms.update(image_terms(rendered, target, weights))
    if weights.bilaplacian:
        terms["bilaplacian"] = weights.bilaplacian * bilaplacian_energy(mesh.vertices, mesh.faces)
    if weights.inversion:
        terms["inversion"] = weights.inversion * inversion_penalty(mesh.vertices, rest_vertices, mesh.faces)
    return sum(terms.values(), jnp.zeros((), mesh.vertices.dtype)), terms
