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

Photo targets (`appearance=(albedo, lighting)` given) are `(N, H, W, 4)` RGBA
photographs; the render is `("alpha", "color")` with the Lambertian face colours
of `jaxgenus.rendering._shading`, and the photometric term is a robust (Charbonnier) error
of the colour where the target's mask is set. A clipped target value (0 or 1:
the true value lies beyond it) only penalizes a render on its unclipped side, so
saturated pixels pull no shading past their limit. The albedo smoothness term
is the mean over the mesh's edges of `|albedo_i - albedo_j|^2`; it separates
shading (which follows the normals) from texture (which it keeps smooth).
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from jaxgenus.optim._intrinsic import RATIO_BAND, albedo_edges, shading_ratio_cost
from jaxgenus.optim._carving import carving_term
from jaxgenus.optim._consistency import photo_consistency, stereo_depth_cost
from jaxgenus.optim._containment import containment_penalty
from jaxgenus.geometry import settings_repr, bilaplacian_energy, inversion_penalty, vertex_normals
from jaxgenus.rendering import RenderSettings, irradiance, render, shading_colors

__all__ = ["CLIP_LOW", "CLIP_HIGH", "LossWeights", "albedo_smoothness", "image_loss", "image_terms", "objective",
           "render_channels"]

#: Target photo values at or beyond these are clipped (under- / over-exposed): one-sided error.
CLIP_LOW, CLIP_HIGH = 0.5 / 255.0, 254.5 / 255.0
_CHARBONNIER = 1e-3


@dataclasses.dataclass(frozen=True, repr=False)
class LossWeights:
    """Static weights of the objective's terms (0 skips a term entirely).

    Attributes:
        alpha, normal: the image terms (each a mean over the pixels, so O(1) and
            resolution-independent). `reconstruct` sets `alpha` to 4 for photos of a fine texture
            (`ReconstructOptions.fine_texture`).
        bilaplacian: `||L x||^2`, a sum over the vertices (default 0: the large-steps
            parametrization already smooths; e.g. `1e-2 / n_vertices` penalizes curvature).
        inversion: triangle inversion (zero unless a triangle flips; one face folded flat
            onto itself costs as much as the whole image term can). Larger weights also
            unfold every face, but a fold's gradient spike then inflates uniform Adam's
            second moment and shrinks later steps (docs/stability.md).
        photo: the photometric term of photo targets (docs/photometric.md for the choice).
        albedo_smoothness: the albedo's mean squared edge difference (photo targets); it
            separates shading, which follows the normals, from texture.
        containment: `containment_penalty` (pixels outside the target silhouettes beyond a
            1 px margin; `objective(..., outside=...)`). Off by default: it removes the
            slivers of thin shapes at low resolution but folded a thin shape at higher
            resolution (docs/reconstruction.md).
        carve: `carving_term` (normal maps only; value 0, a force). Off here; `reconstruct`
            sets it in refits (`ReconstructOptions.refit_carve`).
        consistency: multi-view photo-consistency of photo targets (`photo_consistency`: the
            mean robust cost of `1 - NCC` over textured windows, each view against a neighbour
            through the rendered depth); used when `objective` is given `neighbours`
            (`reconstruct` gives them to photo targets in one process). Weight 1
            (docs/results.md, "Photo-consistency").
        albedo_edges: a factor on the photometric term at the pixels next to an albedo edge
            (`albedo_edges`: a jump in colour that shading does not make), where a face's blended
            albedo cannot follow the photo. 1 (default) keeps them as they are; 0 leaves them out,
            which suits a texture finer than the mesh holds but not a real capture whose albedo the
            mesh follows (docs/results.md, "Albedo edges").
        stereo: photo targets with stereo depths (`objective(..., neighbours=(.., .., depths))`;
            `reconstruct` finds them by plane sweep, `jaxgenus.capture.stereo_depths`):
            `stereo_depth_cost`, the rendered depth against them, a basin as wide as the sweep.
        shading_ratio: photo targets: `shading_ratio_cost`, the log ratios of nearby pixels of the
            photo against those of the smoothly shaded irradiance at the mesh's normals (albedo-free;
            one more render a step), over the pairs near an albedo edge (`RATIO_BAND`). 0 here;
            `reconstruct` sets 6 for photos of a fine texture (`ReconstructOptions.fine_texture`);
            on smooth albedos it costs (docs/results.md, "Shading ratios").
        consistency_blur: not a weight of a term: how much of a binomial blur (sigma 1 px, each
            photo in its own pixels) the `consistency` term compares, 1 all, 0 none. The blur
            smooths the term on smooth shading, but it biases NCC off the true surface where a
            fine texture is foreshortened differently in two views; `reconstruct` sets 0 for
            photos of a fine texture (`ReconstructOptions.fine_texture`; docs/results.md, "No blur
            for a fine texture").
        consistency_colour: not a weight of a term: 1 compares R, G and B in the `consistency` term
            (one NCC per window from the three channels' covariances and variances), 0 (default) the
            grey level. `reconstruct`'s closing polish uses 1 (`ReconstructOptions.polish_cycles`).
    """

    def __repr__(self) -> str:
        return settings_repr(self)


    alpha: float = 1.0
    normal: float = 1.0
    bilaplacian: float = 0.0
    inversion: float = 1.0
    photo: float = 6.0
    albedo_smoothness: float = 20.0
    containment: float = 0.0
    carve: float = 0.0
    consistency: float = 1.0
    stereo: float = 1.0
    albedo_edges: float = 1.0
    shading_ratio: float = 0.0
    consistency_blur: float = 1.0
    consistency_colour: float = 0.0

    def __post_init__(self):
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, (int, float)) or not v >= 0.0 or v == float("inf"):
                raise ValueError(f"weights.{f.name} must be a finite Python float >= 0, got {v!r}")
        if self.consistency_blur > 1.0:
            raise ValueError(f"weights.consistency_blur must be in [0, 1], got {self.consistency_blur!r}")
        if self.consistency_colour not in (0, 1):
            raise ValueError(f"weights.consistency_colour must be 0 (grey) or 1 (RGB), got {self.consistency_colour!r}")


def render_channels(target: Float[Array, "N H W C"], photo: bool = False) -> tuple[str, ...]:
    """The render channels a target needs: `("alpha",)` for C = 1, `("alpha", "normal")` for C = 4,
    `("alpha", "color")` for photos."""
    c = target.shape[-1]
    if target.ndim != 4 or c not in (1, 4):
        raise ValueError(f"target must have shape (N, H, W, 1) or (N, H, W, 4), got {target.shape}")
    if photo and c != 4:
        raise ValueError(f"photo targets must have shape (N, H, W, 4), got {target.shape}")
    return ("alpha",) if c == 1 else ("alpha", "color" if photo else "normal")


def _photo_error(rendered_rgb, target_rgb):
    """Charbonnier error per channel; one-sided where the target is clipped."""
    r = rendered_rgb - target_rgb
    r = jnp.where(target_rgb >= CLIP_HIGH, jnp.minimum(r, 0.0), r)
    r = jnp.where(target_rgb <= CLIP_LOW, jnp.maximum(r, 0.0), r)
    return jnp.sqrt(r * r + _CHARBONNIER**2) - _CHARBONNIER


def albedo_smoothness(albedo: Float[Array, "V 3"], mesh) -> Float[Array, ""]:
    """Mean over the live faces' edges of `|albedo_i - albedo_j|^2`."""
    a = albedo[mesh.faces]
    d = jnp.sum((a - jnp.roll(a, 1, axis=1)) ** 2, axis=(1, 2))
    m = mesh.face_mask
    return jnp.sum(jnp.where(m, d, 0.0)) / (3.0 * jnp.maximum(jnp.sum(m), 1))


def image_terms(rendered, target, weights: LossWeights, photo: bool = False) -> dict[str, Array]:
    """The weighted image terms `{"alpha": ..., "normal" or "photo": ...}` (a term with weight 0 is absent)."""
    render_channels(target, photo)
    if rendered.shape != target.shape:
        raise ValueError(f"rendered must have the target's shape {target.shape}, got {rendered.shape}")
    terms = {}
    if target.shape[-1] == 4:
        t_alpha = target[..., 3]
        if photo:
            if weights.photo:
                err = _photo_error(rendered[..., 1:4], target[..., :3])
                if weights.albedo_edges != 1.0:  # the default skips the edge map
                    err = jnp.where(albedo_edges(target)[..., None], weights.albedo_edges * err, err)
                terms["photo"] = weights.photo * jnp.mean(t_alpha[..., None] * err)
        elif weights.normal:
            err = jnp.abs(0.5 * (rendered[..., 1:4] + 1.0) - target[..., :3])
            terms["normal"] = weights.normal * jnp.mean(t_alpha[..., None] * err)
    else:
        t_alpha = target[..., 0]
    if weights.alpha:
        terms["alpha"] = weights.alpha * jnp.mean(jnp.abs(rendered[..., 0] - t_alpha))
    return terms


def image_loss(
    rendered: Float[Array, "N H W C"], target: Float[Array, "N H W C"], *, weights: LossWeights = LossWeights(),
    photo: bool = False,
) -> Float[Array, ""]:
    """l1 image loss over the channels the target has.

    `alpha`: mean over pixels of `|alpha - alpha_target|`. `normal` (RGBA targets
    only): mean over pixels and the 3 channels of `A_target * |(n + 1) / 2 - RGB_target|`,
    i.e. normals count only where the target alpha is set. Each is multiplied by
    its weight in `weights`. `photo`: the target is an RGBA photo and `rendered`
    holds alpha and colour; the colour term is the robust photometric error
    (see the module doc) where the target alpha is set.
    """
    terms = image_terms(rendered, target, weights, photo)
    return sum(terms.values(), jnp.zeros((), rendered.dtype))


def _shading_ratio(alpha, shading, target):
    """`shading_ratio_cost` of the rendered irradiance at the vertex normals (interpolated; the main
    render's `"values"`), over the pairs near an albedo edge (`RATIO_BAND`)."""
    near = albedo_edges(target, band=RATIO_BAND)  # where the albedo cannot follow the photo
    return shading_ratio_cost(alpha, shading, target, where=near)[0]


def _consistency(mesh, renderer, kw, alpha, depth, cameras, target, neighbours, blur, colour):
    """The photo-consistency loss of the views against their neighbours (the neighbours' depth constant)."""
    nb_cams, nb_photos = neighbours[:2]
    fixed = jax.tree.map(jax.lax.stop_gradient, mesh)
    kw = {k: v for k, v in kw.items() if k not in ("face_colors", "vertex_colors", "vertex_values")}
    nb_depth = jax.lax.stop_gradient(renderer(fixed, nb_cams, channels=("depth", "alpha"), **kw))
    loss, _ = photo_consistency(depth, alpha, cameras, target, nb_cams, nb_photos, nb_depth, blur=blur,
                                colour=bool(colour))
    return loss


def objective(
    mesh,
    cameras,
    target: Float[Array, "N H W C"],
    rest_vertices: Float[Array, "V 3"],
    *,
    weights: LossWeights = LossWeights(),
    renderer: Callable | None = None,
    render_settings: RenderSettings | None = None,
    appearance: tuple | None = None,
    outside: Float[Array, "N H W"] | None = None,
    neighbours: tuple | None = None,
) -> tuple[Float[Array, ""], dict[str, Array]]:
    """The total objective at `mesh.vertices` and its weighted terms.

    Renders `mesh` with `renderer(mesh, cameras, channels=..., **render_settings.kwargs())`
    (default `jaxgenus.render`; `render_settings` None passes none) for the channels
    `target` has, and returns
    `(total, terms)` where `terms` holds the weighted `alpha`, `normal`,
    `bilaplacian` and `inversion` values that were computed (weight 0: absent).
    `appearance=(albedo (Vcap, 3), lighting (3, 24) or (3, 3))`: `target` is a photo, fitted
    through Lambertian colours, flat or smooth as `render_settings.shading` says (`photo` and
    `albedo_smoothness` terms); with `weights.shading_ratio` the same render also asks for the
    `"values"` channel, the irradiance at the vertex normals (`vertex_values`), so a custom
    `renderer` for photos takes that keyword as `jaxgenus.render` does.
    `outside`: the targets' `outside_distance` maps (`(N, H, W)`, pixels), for the
    `containment` term (`jaxgenus.optim._containment`); None skips it.
    `neighbours=(cameras, photos)`: photo targets: one neighbour view per view of `cameras` and
    its premultiplied RGBA photo, for the `consistency` term (`jaxgenus.optim._consistency`);
    the neighbours' depth is rendered for the visibility test and held constant. A third entry,
    `(N, H, W)` depths of the views of `cameras` found by stereo (NaN: none), adds the `stereo`
    term (`stereo_depth_cost`).
    """
    renderer = render if renderer is None else renderer
    photo = appearance is not None
    kw = {} if render_settings is None else render_settings.kwargs()
    terms = {}
    if photo:
        albedo, lighting = appearance
        shading = "flat" if render_settings is None else render_settings.shading
        kw.update(shading_colors(mesh, albedo, lighting, shading))
        if weights.albedo_smoothness:
            terms["albedo_smoothness"] = weights.albedo_smoothness * albedo_smoothness(albedo, mesh)
    ratio = photo and bool(weights.shading_ratio)
    colour = weights.photo if photo else weights.normal
    carve = bool(weights.carve) and not photo and target.shape[-1] == 4
    consistent = bool(weights.consistency) and photo and neighbours is not None
    stereo = bool(weights.stereo) and photo and neighbours is not None and len(neighbours) > 2
    deep = carve or consistent or stereo
    if weights.alpha or (colour and target.shape[-1] == 4) or deep or ratio:
        channels = render_channels(target, photo) + (("depth",) if deep else ()) + (("values",) if ratio else ())
        if ratio:  # the irradiance at the vertex normals, interpolated, rasterized in the same pass
            kw["vertex_values"] = jnp.maximum(irradiance(vertex_normals(mesh), appearance[1]), 0.0)
        rendered = renderer(mesh, cameras, channels=channels, **kw)
        if ratio:
            rendered, shading = rendered[..., :-3], rendered[..., -3:]
            terms["shading_ratio"] = weights.shading_ratio * _shading_ratio(rendered[..., 0], shading, target)
        if deep:
            rendered, depth = rendered[..., :4], rendered[..., 4]
        if carve:
            terms["carve"] = weights.carve * carving_term(rendered, depth, target)
        if consistent:
            terms["consistency"] = weights.consistency * _consistency(mesh, renderer, kw, rendered[..., 0], depth,
                                                                      cameras, target, neighbours,
                                                                      weights.consistency_blur,
                                                                      weights.consistency_colour)
        if stereo:
            terms["stereo"] = weights.stereo * stereo_depth_cost(depth, rendered[..., 0], neighbours[2])
        terms.update(image_terms(rendered, target, weights, photo))
    if weights.bilaplacian:
        terms["bilaplacian"] = weights.bilaplacian * bilaplacian_energy(mesh.vertices, mesh.faces)
    if weights.containment and outside is not None:
        terms["containment"] = weights.containment * containment_penalty(mesh.vertices, mesh.vertex_mask, cameras,
                                                                         outside)
    if weights.inversion:
        terms["inversion"] = weights.inversion * inversion_penalty(mesh.vertices, rest_vertices, mesh.faces)
    return sum(terms.values(), jnp.zeros((), mesh.vertices.dtype)), terms
