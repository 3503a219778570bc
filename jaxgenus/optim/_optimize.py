"""`optimize_block`: n large-steps Adam steps as one jit-compiled `lax.scan`.

The optimizer state keeps the vertices `x` (in its `mesh`), the uniform-Adam
moments (in the `u = (I + lambda L) x` space), the rest vertices of the
inversion penalty, a step counter and a PRNG key. Every per-vertex array is
`(Vcap, 3)`, so a remesher can map the state onto a new mesh. `u` itself is not
stored: a block starts from `u = (I + lambda L) x` and ends with `x` solved
back from `u`, so `mesh.vertices` is always the current shape.

One step: pick the views (all, or `views_per_step` random ones), evaluate the
objective and its gradient at `x`, pull the gradient back to `u` by a solve,
take a uniform-Adam step in `u`, and solve the new `x`. Both solves are
warm-started (the new `x` at the old one, the pulled-back gradient at the
previous step's). A step whose loss, gradient or update is not finite is skipped (state unchanged)
and flagged with status 2; a solve that hit `cg_max_iter` is flagged with
status 1. The record holds fixed-shape `(n_steps,)` arrays.

`optimize_block` compiles once per capacity bucket (array shapes), number of
steps and options; the state buffers are donated.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.sharding import NamedSharding, PartitionSpec as P
from jaxtyping import Array, Float, Int, PRNGKeyArray

from jaxgenus.optim._adam import UniformAdamState, adam as plain_adam, uniform_adam
from jaxgenus.geometry import inverted_face_count
from jaxgenus.optim._largesteps import DEFAULT_LAMBDA, largesteps_factor, largesteps_solve, to_differential
from jaxgenus.optim._loss import LossWeights, objective, render_channels
from jaxgenus.geometry import Mesh, settings_repr
from jaxgenus.geometry import uniform_laplacian
from jaxgenus.optim._devices import AXIS, views_gradient
from jaxgenus.optim._pyramid import crop_views, step_views, target_boxes
from jaxgenus.optim._record import RECORD_KEYS, StepRecord, step_record
from jaxgenus.rendering import LIGHTING_SHAPE, RenderSettings, lighting_model

__all__ = [
    "Appearance",
    "OptimizeOptions",
    "OptimizerState",
    "block_factor",
    "init_optimizer_state",
    "optimize_block",
    "optimize_steps",
]


@dataclasses.dataclass(frozen=True, repr=False)
class OptimizeOptions:
    """Static settings of `optimize_block` (hashable; changing one recompiles).

    Attributes:
        learning_rate: uniform-Adam step size (in `u` space, about the distance a
            vertex moves per step for smooth motions).
        lambda_: large-steps `lambda` (19, as in Nicolet et al.).
        b1, b2, eps: uniform-Adam parameters.
        adam_quantile: quantile of the shared second moment (1: the max, Nicolet's;
            below 1, a few vertices with outlier gradients, e.g. on a tiny handle,
            do not freeze the rest of the mesh; see `uniform_adam`).
        weights: `LossWeights` of the objective.
        views_per_step: number of cameras sampled (without replacement) per step;
            `None`, or at least the number of cameras, uses all of them every step.
        cg_rtol, cg_max_iter: stopping rule of the CG solves (where the solve is not direct: off the
            CPU, or a mesh whose factor does not fit `factor_capacity`).
        average: the block returns the exponential moving average of its iterates,
            `x_avg <- average * x_avg + (1 - average) * x` after every step (from
            the block's starting `x`), instead of the last iterate; 0 (default) is
            off. About the last `1 / (1 - average)` steps are averaged, which
            removes most of the step noise of sampled views at a fixed step size.
        albedo_learning_rate, lighting_learning_rate: plain-Adam steps of the
            per-vertex albedo and of the lighting (photo targets only).
        crop: render a random `crop x crop` window of each sampled view, centred in
            the target's silhouette box (`jaxgenus.optim.crop_views`), instead of
            the whole image; 0 (default) renders whole views. The cost of a step then
            follows the crop, not the image size.
        device_mesh: a 1-D device mesh (axis `"views"`, `jaxgenus.optim.device_mesh`) the views are
            split over, or None (one device). With a mesh, the cameras, targets and `valid` given to
            `optimize_steps` are laid out by `spread_views` and split over it; each device renders
            `ceil(views / devices)` of its own views a step (`jaxgenus.optim._devices`).
        max_pixels: the most pixels one step renders (None: no bound). When the sampled
            views hold more, a step samples fewer views (one at least), and when one view
            holds more, a random `s x s` window of it with `s^2 <= max_pixels`
            (`step_views`): the cost and memory of a step are bounded whatever the image
            size. The default, 2^18, is 4 views of 256^2, or 2 of a 1600x1200 capture fitted
            at a quarter of its size.
        renderer: `renderer(mesh, cameras, channels=..., **render.kwargs())`;
            `None` is `jaxgenus.render`.
        render: `RenderSettings` passed to the renderer (`None`: none are passed,
            the renderer's own defaults).
    """

    def __repr__(self) -> str:
        return settings_repr(self)


    learning_rate: float = 8e-2
    lambda_: float = DEFAULT_LAMBDA
    b1: float = 0.9
    b2: float = 0.999
    eps: float = 1e-8
    adam_quantile: float = 0.99
    weights: LossWeights = LossWeights()
    views_per_step: int | None = 4
    cg_rtol: float = 1e-6
    cg_max_iter: int = 2000
    average: float = 0.0
    crop: int = 0
    max_pixels: int | None = 1 << 18
    device_mesh: object = None
    albedo_learning_rate: float = 1e-2
    lighting_learning_rate: float = 5e-2
    renderer: Callable | None = None
    render: RenderSettings | None = None

    def __post_init__(self):
        if not self.learning_rate > 0:
            raise ValueError(f"learning_rate must be > 0, got {self.learning_rate}")
        for name in ("albedo_learning_rate", "lighting_learning_rate"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not self.lambda_ >= 0:
            raise ValueError(f"lambda_ must be >= 0, got {self.lambda_}")
        if self.views_per_step is not None and self.views_per_step < 1:
            raise ValueError(f"views_per_step must be None or >= 1, got {self.views_per_step}")
        if not (isinstance(self.average, (int, float)) and 0.0 <= self.average < 1.0):
            raise ValueError(f"average must be in [0, 1), got {self.average!r}")
        if not (isinstance(self.crop, int) and self.crop >= 0):
            raise ValueError(f"crop must be an int >= 0, got {self.crop!r}")
        if self.max_pixels is not None and not (isinstance(self.max_pixels, int) and self.max_pixels >= 1):
            raise ValueError(f"max_pixels must be None or an int >= 1, got {self.max_pixels!r}")
        if not isinstance(self.weights, LossWeights):
            raise ValueError(f"weights must be a LossWeights, got {type(self.weights).__name__}")
        if not (isinstance(self.adam_quantile, (int, float)) and 0.0 < self.adam_quantile <= 1.0):
            raise ValueError(f"adam_quantile must be in (0, 1], got {self.adam_quantile!r}")
        if self.render is not None and not isinstance(self.render, RenderSettings):
            raise ValueError(f"render must be a RenderSettings or None, got {type(self.render).__name__}")

    def adam(self):
        return uniform_adam(self.learning_rate, self.b1, self.b2, self.eps, self.adam_quantile)


class Appearance(eqx.Module):
    """What a photometric fit estimates besides the shape (a PyTree; see `jaxgenus.render_photo`).

    Attributes:
        albedo: `(Vcap, 3)` per-vertex RGB albedo (>= 0), row for row with the mesh's vertices.
        lighting: `(3, 24)` spherical-harmonic or `(3, 3)` directional lighting (`_shading`).
        adam: plain-Adam state of `(albedo, lighting)`.
    """

    albedo: Float[Array, "V 3"]
    lighting: Float[Array, "3 L"]
    adam: UniformAdamState


class OptimizerState(eqx.Module):
    """State carried between `optimize_block` calls (a PyTree).

    Attributes:
        mesh: the current mesh; `mesh.vertices` is `x`.
        adam: `UniformAdamState` with `(Vcap, 3)` moments of `u`.
        rest_vertices: `(Vcap, 3)` shape at the last remesh (inversion penalty reference).
        step: int32 steps taken since `init_optimizer_state`.
        key: PRNG key for view sampling.
        appearance: the albedo and lighting of a photometric fit (`Appearance`), else None.
    """

    mesh: Mesh
    adam: UniformAdamState
    rest_vertices: Float[Array, "V 3"]
    step: Int[Array, ""]
    key: PRNGKeyArray
    appearance: Appearance | None = None


def _owned_key(key):
    """A copy of `key` (typed or raw uint32), so that donating a state leaves the caller's key alive."""
    if jnp.issubdtype(jnp.asarray(key).dtype, jax.dtypes.prng_key):
        return jax.random.wrap_key_data(jnp.array(jax.random.key_data(key)), impl=jax.random.key_impl(key))
    return jnp.array(key)


def init_optimizer_state(mesh: Mesh, key: PRNGKeyArray, *, albedo=None, lighting=None) -> OptimizerState:
    """A fresh state at a copy of `mesh` (zero moments, rest shape = current shape).

    `albedo` (an RGB triple, or `(Vcap, 3)` per vertex) starts a photometric fit
    (`Appearance`), with `lighting` `(3, 24)` or `(3, 3)` (`jaxgenus.lighting_model`;
    default `(3, 24)` zeros: uniform white light).
    The state owns its buffers, so donating it to `optimize_block` leaves `mesh` and `key` intact.
    """
    if not isinstance(mesh, Mesh):
        raise ValueError(f"mesh must be a Mesh, got {type(mesh).__name__}")
    appearance = None
    if albedo is not None or lighting is not None:
        dtype = mesh.vertices.dtype
        a = jnp.asarray(0.5 if albedo is None else albedo, dtype)
        a = jnp.broadcast_to(a, (mesh.vertex_capacity, 3)) if a.ndim <= 1 else a
        if a.shape != (mesh.vertex_capacity, 3) or not bool(jnp.all(jnp.isfinite(a))) or bool(jnp.any(a < 0)):
            raise ValueError(f"albedo must be finite, >= 0, an RGB triple or ({mesh.vertex_capacity}, 3); got shape {a.shape}")
        a = jnp.where(mesh.vertex_mask[:, None], a, 0.0)
        lt = jnp.zeros(LIGHTING_SHAPE, dtype) if lighting is None else jnp.asarray(lighting, dtype)
        lighting_model(lt)
        if not bool(jnp.all(jnp.isfinite(lt))):
            raise ValueError("lighting must be finite")
        appearance = Appearance(albedo=jnp.array(a), lighting=jnp.array(lt), adam=plain_adam(1.0).init((a, lt)))
    return OptimizerState(
        mesh=jax.tree.map(jnp.array, mesh),
        adam=uniform_adam(1.0).init(mesh.vertices),
        rest_vertices=jnp.array(mesh.vertices),
        step=jnp.zeros((), jnp.int32),
        key=_owned_key(key),
        appearance=appearance,
    )


class _Carry(NamedTuple):
    """The scan carry of `optimize_steps`: `x`, `u`, the last pulled-back gradient, the Adam
    state, the PRNG key, the iterate average, and the photo fit's `(albedo, lighting)` and
    their Adam state (None when not a photo fit)."""

    x: Array
    u: Array
    gu: Array
    adam: UniformAdamState
    key: Array
    x_avg: Array
    app: tuple | None
    app_adam: UniformAdamState | None


def _views(key, idx, cameras, targets, boxes, outside, table, crop: int, stereo=None, everyone=None):
    """The step's views `idx` (None: all of them), through random crops when `crop`. With a neighbour
    `table` (`view_neighbours`), also one random neighbour of each (its whole view), looked up in
    `everyone`, the `(cameras, targets)` of every view (default: these), and the views' `stereo`
    depths when given (not with crops)."""
    if idx is None:
        idx, cams, tgt, box, out = jnp.arange(len(cameras)), cameras, targets, boxes, outside
    else:
        cams, tgt, box = cameras[idx], targets[idx], None if boxes is None else boxes[idx]
        out = None if outside is None else outside[idx]
    near = None
    if table is not None:
        pick = jax.random.randint(jax.random.fold_in(key, 2), idx.shape, 0, table.shape[1])
        nb = table[idx, pick]
        all_cams, all_targets = (cameras, targets) if everyone is None else everyone
        near = (all_cams[nb], all_targets[nb]) + (() if stereo is None or crop else (stereo[idx],))
    if crop:
        cams, tgt = crop_views(jax.random.fold_in(key, 1), cams, tgt, box, crop)
    return cams, tgt, out, near


def _gradient(loss_fn, options: OptimizeOptions, views: tuple, valid, k: int, crop: int, geometry: tuple, everyone):
    """`gradient(key, x, app) -> ((loss, terms), (gx, g_app))` of a step: on the step's views, or with
    `options.device_mesh` on every device from its own (`views_gradient`), their photo-consistency
    neighbours looked up in `everyone` (every view's cameras and targets on every device)."""
    def select(key, local, idx, everyone):
        cams, tgt, out, box, table, stereo = local
        return _views(key, idx, cams, tgt, box, None if crop else out, table, crop, stereo, everyone)

    mesh = options.device_mesh
    if mesh is not None:
        if valid is None:
            raise ValueError("valid: needed with options.device_mesh (jaxgenus.optim.spread_views)")
        devices = mesh.shape[AXIS]
        return lambda key, x, app: views_gradient(loss_fn, mesh, min(-(-k // devices), len(valid) // devices),
                                                  select)(key, x, app, views, valid, geometry, everyone)

    def gradient(key, x, app):
        n = len(views[0])
        idx = None if k is None or k >= n else jax.random.choice(key, n, (k,), replace=False)
        cams, tgt, out, near = _views(key, idx, views[0], views[1], views[3], views[2], views[4], crop, views[5])
        return jax.value_and_grad(loss_fn, argnums=(0, 1), has_aux=True)(x, app, cams, tgt, out, geometry, near)

    return gradient


def _appearance_step(app, g_app, app_state, rates, lr_scale, vmask):
    """Plain Adam on (albedo, lighting), albedo kept >= 0 and 0 on padding; also whether it is finite."""
    upd, new_state = plain_adam(1.0).update(g_app, app_state)
    upd = tuple(u * (lr * lr_scale) for u, lr in zip(upd, rates))
    albedo = jnp.where(vmask, jnp.maximum(app[0] + upd[0], 0.0), 0.0)
    new = (albedo, app[1] + upd[1])
    return new, new_state, jnp.all(jnp.isfinite(new[0])) & jnp.all(jnp.isfinite(new[1]))


def optimize_steps(state: OptimizerState, cameras, targets, n_steps: int, options: OptimizeOptions, lr_scale,
                   outside=None, valid=None, neighbours=None, factor=None) -> tuple[OptimizerState, StepRecord]:
    """The body of `optimize_block` without `jit` or argument checks (to trace inside a larger jitted program).
    `valid`: with `options.device_mesh`, which views are real (`spread_views`). `neighbours`: photo
    targets: `(N, M)` neighbour views of every view (`view_neighbours`) for the photo-consistency
    term, or `(table, depths (N, H, W))` with the views' stereo depths for the `stereo` term. With a
    device mesh the table's rows and entries are slots of the `spread_views` layout, and every device
    gets a copy of all views' cameras and targets once a block, to look its views' neighbours up in.
    `factor`: the mesh's `block_factor`, computed before and found `ok` on the host: the solves use it
    alone (no CG fallback is traced); None: the block factors the matrix itself, with CG where that fails."""
    mesh, rest = state.mesh, state.rest_vertices
    laplacian = uniform_laplacian(mesh.faces, mesh.vertex_capacity)
    vmask = mesh.vertex_mask[:, None]
    adam, avg = options.adam(), options.average
    k, crop = step_views(len(cameras), cameras.height, cameras.width, options)
    boxes = target_boxes(targets, margin=crop // 8) if crop else None
    outside = None if crop else outside  # crops move the principal points: the whole-view maps no longer line up
    photo = state.appearance is not None
    rates = (options.albedo_learning_rate, options.lighting_learning_rate)

    def loss_fn(x, app, cams, tgt, out, geometry, near=None):
        faces, n_vertices, n_faces, rest_x = geometry
        m = Mesh(vertices=x, faces=faces, n_vertices=n_vertices, n_faces=n_faces)
        return objective(m, cams, tgt, rest_x, weights=options.weights, renderer=options.renderer,
                         render_settings=options.render, appearance=app, outside=out, neighbours=near)

    fallback = factor is None
    if factor is None:  # once a block: the mesh's connectivity is fixed in it
        factor = largesteps_factor(laplacian, options.lambda_)

    def solve(b, x0):
        return largesteps_solve(laplacian, b, options.lambda_, x0, rtol=options.cg_rtol, max_iter=options.cg_max_iter,
                                factor=factor, fallback=fallback)

    geometry = (mesh.faces, mesh.n_vertices, mesh.n_faces, rest)  # passed, not closed over (device meshes)
    stereo = None
    if isinstance(neighbours, tuple):  # (table, the views' stereo depths)
        neighbours, stereo = neighbours
    used = options.weights.consistency or (options.weights.stereo and stereo is not None)
    table = neighbours if photo and used else None
    everyone = None
    if table is not None and options.device_mesh is not None:  # every view's photo where its neighbours render
        everyone = jax.lax.with_sharding_constraint((cameras, targets), NamedSharding(options.device_mesh, P()))
    gradient = _gradient(loss_fn, options, (cameras, targets, outside, boxes, table, stereo), valid, k, crop, geometry,
                         everyone)

    def step(c: _Carry, _):
        key, sub = jax.random.split(c.key)
        (loss, terms), (gx, g_app) = gradient(sub, c.x, c.app)
        gx = jnp.where(vmask, gx, 0.0)
        gu, info_b = solve(gx, c.gu)
        updates, new_adam = adam.update(gu, c.adam)
        new_u = jnp.where(vmask, c.u + jax.tree.map(lambda t: t * lr_scale, updates), 0.0)
        new_x, info_f = solve(new_u, c.x)
        ok = jnp.isfinite(loss) & jnp.all(jnp.isfinite(gx)) & jnp.all(jnp.isfinite(new_u)) & jnp.all(jnp.isfinite(new_x))
        new_app, new_app_adam = c.app, c.app_adam
        if photo:
            new_app, new_app_adam, finite = _appearance_step(c.app, g_app, c.app_adam, rates, lr_scale, vmask)
            ok = ok & finite
        keep = lambda new, old: jax.tree.map(lambda a, b: jnp.where(ok, a, b), new, old)
        x, u, gu, adam_state, app, app_adam = keep((new_x, new_u, gu, new_adam, new_app, new_app_adam),
                                                   (c.x, c.u, c.gu, c.adam, c.app, c.app_adam))
        x_avg = avg * c.x_avg + (1.0 - avg) * x if avg > 0 else x
        inverted = inverted_face_count(x, rest, mesh.faces, mesh.face_mask)
        return _Carry(x, u, gu, adam_state, key, x_avg, app, app_adam), step_record(loss, terms, gx, info_b, info_f, ok,
                                                                               inverted)

    x0, ap = mesh.vertices, state.appearance
    u0 = jnp.where(vmask, to_differential(laplacian, x0, options.lambda_), 0.0)
    carry = _Carry(x0, u0, jnp.zeros_like(x0), state.adam, state.key, x0, (ap.albedo, ap.lighting) if photo else None,
                   ap.adam if photo else None)
    end, record = jax.lax.scan(step, carry, None, length=n_steps)
    new_app = Appearance(albedo=end.app[0], lighting=end.app[1], adam=end.app_adam) if photo else None
    new_mesh = Mesh(vertices=end.x_avg, faces=mesh.faces, n_vertices=mesh.n_vertices, n_faces=mesh.n_faces)
    return OptimizerState(mesh=new_mesh, adam=end.adam, rest_vertices=rest, step=state.step + n_steps, key=end.key,
                          appearance=new_app), record


_optimize_block_jit = jax.jit(optimize_steps, static_argnames=("n_steps", "options"), donate_argnames=("state",))


@jax.jit(static_argnames=("lambda_",))
def block_factor(mesh: Mesh, lambda_: float = DEFAULT_LAMBDA):
    """The Cholesky factor of `I + lambda_ L` for `mesh`'s connectivity (`largesteps_factor`), as a block
    computes it; read its `ok` on the host and pass it to `optimize_steps(..., factor=)` when it is."""
    return largesteps_factor(uniform_laplacian(mesh.faces, mesh.vertex_capacity), lambda_)


def optimize_block(
    state: OptimizerState,
    cameras,
    targets: Float[Array, "N H W C"],
    *,
    n_steps: int,
    options: OptimizeOptions = OptimizeOptions(),
    lr_scale=1.0,
    valid=None,
    neighbours=None,
) -> tuple[OptimizerState, StepRecord]:
    """Run `n_steps` large-steps uniform-Adam steps in one jit-compiled `lax.scan`.

    Args:
        state: from `init_optimizer_state` or a previous block; its buffers are
            donated (do not reuse the argument).
        cameras: `Cameras` with N views.
        targets: `(N, H, W, 1)` silhouettes or `(N, H, W, 4)` RGBA normal images
            (see `jaxgenus.optim._loss`), one per camera; RGBA photos when `state` has an
            `appearance` (from `init_optimizer_state(..., albedo=...)`).
        n_steps: number of steps (static).
        options: `OptimizeOptions` (static).
        lr_scale: factor on `options.learning_rate` for this block; a runtime value,
            so a learning-rate schedule over blocks does not recompile.
        valid: with `options.device_mesh`: `(N,)` which views are real, the cameras and targets laid
            out by `jaxgenus.optim.spread_views` and split over the mesh (`place`).
        neighbours: photo targets: `(N, M)` int neighbour views of every view
            (`jaxgenus.optim.view_neighbours`), which turns on the photo-consistency term
            (`LossWeights.consistency`); with `options.device_mesh`, rows and entries are slots of the
            `spread_views` layout.

    Returns:
        `(new_state, record)`: a `StepRecord` whose fields (`record["loss"]`, ...,
        every name in `RECORD_KEYS`) are `(n_steps,)` arrays.
    """
    if not isinstance(n_steps, int) or n_steps < 1:
        raise ValueError(f"n_steps must be a positive int, got {n_steps!r}")
    if not isinstance(options, OptimizeOptions):
        raise ValueError(f"options must be an OptimizeOptions, got {type(options).__name__}")
    if not isinstance(state, OptimizerState):
        raise ValueError(f"state must be an OptimizerState, got {type(state).__name__}")
    render_channels(targets, state.appearance is not None)
    if targets.shape[:3] != (len(cameras), cameras.height, cameras.width):
        raise ValueError(
            f"targets must have shape ({len(cameras)}, {cameras.height}, {cameras.width}, C), got {targets.shape}"
        )
    if (options.device_mesh is None) != (valid is None):
        raise ValueError("valid: give it exactly when options.device_mesh is set (jaxgenus.optim.spread_views)")
    if neighbours is not None:
        neighbours = jnp.asarray(neighbours)
        if neighbours.ndim != 2 or neighbours.shape[0] != len(cameras) or not jnp.issubdtype(neighbours.dtype, jnp.integer):
            raise ValueError(f"neighbours must be an int array of shape ({len(cameras)}, M), got {neighbours.shape} "
                             f"{neighbours.dtype}")
        if bool(jnp.any((neighbours < 0) | (neighbours >= len(cameras)))):
            raise ValueError(f"neighbours must index the {len(cameras)} views")
    return _optimize_block_jit(state, cameras, targets, n_steps, options, jnp.asarray(lr_scale, state.mesh.vertices.dtype),
                               None, valid, neighbours)
