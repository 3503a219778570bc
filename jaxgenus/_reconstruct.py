"""`reconstruct`: multi-view images -> a watertight mesh of a given genus.

Pipeline (Gao et al. 2026, on this library's parts):

1. Validate the targets and carve their visual hull to get the object's bounds.
2. Start from the silhouettes' visual hull when its largest component has the
   requested genus (a few grids and closings are tried) or fewer handles (the
   missing ones are drilled as small tunnels just under its surface), else from
   `genus_primitive(genus)` fitted into the hull's bounds (its longest axis along
   the hull's longest axis, its thinnest along the thinnest).
3. Cycles of [`optimize_block` (a jit-compiled `lax.scan` of large-steps uniform
   Adam on the soft-raster l1 loss) -> the native V-cycle remesher through the
   XLA FFI], with target edge lengths going from coarse to fine. The mesh lives
   in one capacity bucket sized for the final face budget, and the remesher
   carries the Adam moments along splits and collapses, so every cycle reuses one
   compiled block (a new rasterizer plan bucket is the only other reason to
   recompile; both are counted in the history).
4. The final mesh's genus is checked against the requested one.

`ReconstructOptions.nicolet()` is the Nicolet et al. 2021 baseline in the same
code: a sphere start, no remeshing, the same renderer and optimizer.
"""

from __future__ import annotations

import dataclasses
import math
import time

import equinox as eqx
import jax
from jax.experimental import io_callback
import jax.numpy as jnp
import numpy as np

from jaxgenus._cameras import Cameras
from jaxgenus._energies import LossWeights
from jaxgenus._hull import split_targets, visual_hull, visual_hull_bounds
from jaxgenus._mesh import Mesh, capacity_bucket
from jaxgenus._optimize import (
    OptimizeOptions,
    OptimizerState,
    _optimize_block,
    _optimize_block_jit,
    init_optimizer_state,
    optimize_block,
)
from jaxgenus._primitives import genus_primitive
from jaxgenus._remesh import RemeshOptions, RemeshStatus, remesh, remesh_in_jit
from jaxgenus._render import RasterPlan, _render_jit, plan_render, render
from jaxgenus._topology import connected_components, euler_characteristic, genus as mesh_genus, is_closed_manifold

__all__ = ["ReconstructOptions", "Reconstruction", "reconstruct", "render_targets"]


@dataclasses.dataclass(frozen=True)
class ReconstructOptions:
    """Settings of `reconstruct` (immutable). Edge lengths are in pixels (see below).

    Attributes:
        n_cycles: optimize/remesh cycles; the last one is not followed by a remesh.
        steps_per_cycle: optimizer steps per cycle (the paper remeshes every 130-200).
        views_per_step: cameras sampled per step (`None`: all of them).
        learning_rate, lambda_: large-steps uniform Adam step and smoothing.
        adam_quantile: quantile of uniform Adam's shared second moment (1: the max,
            Nicolet's; the default 0.99 keeps a few vertices with outlier gradients,
            e.g. on a tiny handle, from freezing the rest of the mesh).
        average: each block returns the exponential moving average of its iterates
            with this decay (0: the last iterate; see `OptimizeOptions.average`).
        lr_decay: the step is `learning_rate * lr_decay ** cycle` (coarse to fine; no recompile).
        weights: `LossWeights` of the objective.
        sigma, gamma: soft rasterizer edge blur (px) and depth temperature.
        initial_faces: face count of the starting primitive.
        max_faces: face budget (sets the capacity bucket; the remesher coarsens to fit).
        initial_edge_length, final_edge_length: remesh targets of the first and the last
            remesh (geometric in between: coarse to fine), in pixels: one pixel is the
            median over the cameras of the world-space footprint of a pixel at the
            visual hull's centre, so the mesh is as fine as the images resolve.
        adaptive: curvature-adaptive remeshing (`False`: uniform).
        remesh: remesh between cycles (`False` keeps the connectivity: Nicolet's baseline).
        start: `"auto"` (the silhouettes' visual hull when its largest component has the
            requested genus at one of `hull_resolutions`, possibly after closing
            thin spurious tunnels; when it has fewer handles, the missing ones are
            added as small tunnels under its surface; else the genus-g primitive),
            `"primitive"` (always the genus-g primitive) or `"sphere"` (genus 0).
        hull_resolutions: grid sizes tried, in order, for the visual-hull start.
        fine_below: thin-structure switch: when the silhouettes' visual hull (grid
            `hull_resolutions[0]`, largest piece) is thinner than this many pixels,
            as `2 * volume / area` (a slab's thickness, a tube's radius),
            `reconstruct` runs with `self.fine()` instead (`history["fine"]`,
            `Reconstruction.options`). At 24 views of 128², the heptoroid's hull is
            2.6 px thick (its sheets 1.8 px), the 21 other benchmark shapes' 5.9 px
            and more; the demo's three_tori at 64² is 3.2 px. 0 turns it off.
        one_jit: run all cycles (optimizer blocks and FFI remeshes) as one
            jit-compiled `lax.scan` with one rasterizer plan sized for the final
            face count, instead of one compiled block per cycle driven from Python
            (which re-plans the rasterizer from the geometry every cycle). One
            compilation per run; `callback` is then called after the run, once per
            cycle, with that cycle's row and mesh.
    """

    n_cycles: int = 4
    steps_per_cycle: int = 150
    views_per_step: int | None = 4
    learning_rate: float = 8e-2
    lr_decay: float = 0.5
    adam_quantile: float = 0.99
    average: float = 0.0
    lambda_: float = 19.0
    weights: LossWeights = LossWeights()
    sigma: float = 0.1
    gamma: float = 0.01
    initial_faces: int = 2000
    max_faces: int = 12000
    initial_edge_length: float = 2.0
    final_edge_length: float = 1.4
    adaptive: bool = False
    remesh: bool = True
    start: str = "auto"
    hull_resolutions: tuple[int, ...] = (64, 48, 80)
    fine_below: float = 3.0
    one_jit: bool = False

    def __post_init__(self):
        for name in ("n_cycles", "steps_per_cycle", "initial_faces", "max_faces"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 1:
                raise ValueError(f"options.{name} must be a positive int, got {v!r}")
        if not 0.0 < self.lr_decay <= 1.0:
            raise ValueError(f"options.lr_decay must be in (0, 1], got {self.lr_decay!r}")
        for name in ("learning_rate", "sigma", "gamma", "initial_edge_length", "final_edge_length"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"options.{name} must be a positive number, got {v!r}")
        if not (isinstance(self.average, (int, float)) and 0.0 <= self.average < 1.0):
            raise ValueError(f"options.average must be in [0, 1), got {self.average!r}")
        if not (isinstance(self.adam_quantile, (int, float)) and 0.0 < self.adam_quantile <= 1.0):
            raise ValueError(f"options.adam_quantile must be in (0, 1], got {self.adam_quantile!r}")
        if self.start not in ("auto", "primitive", "sphere"):
            raise ValueError(f"options.start must be 'auto', 'primitive' or 'sphere', got {self.start!r}")
        if not all(isinstance(r, int) and r >= 8 for r in self.hull_resolutions):
            raise ValueError(f"options.hull_resolutions must be ints >= 8, got {self.hull_resolutions!r}")
        if not (isinstance(self.fine_below, (int, float)) and math.isfinite(self.fine_below) and self.fine_below >= 0):
            raise ValueError(f"options.fine_below must be a number >= 0, got {self.fine_below!r}")
        if self.max_faces < self.initial_faces:
            raise ValueError("options.max_faces must be >= options.initial_faces")

    @classmethod
    def nicolet(cls, **overrides) -> "ReconstructOptions":
        """Nicolet et al. 2021: sphere start, no remeshing, same renderer, their uniform Adam (the max)."""
        base = dict(start="sphere", remesh=False, adam_quantile=1.0)
        base.update(overrides)
        return cls(**base)

    def fine(self) -> "ReconstructOptions":
        """A copy set up for thin structures a few pixels wide (e.g. sheets 2 px thick).

        `reconstruct` switches to it by itself when the visual hull is thinner than
        `fine_below` pixels.

        Sharper edges (`sigma` 0.03 px: at the default 0.1 the outward tails of
        the contour faces bias silhouettes out, and the fit thins such tubes by
        ~9 % in volume), a finer mesh (1.4 -> 1.0 px edges, up to 20k faces),
        5 cycles with a slow step decay (0.9) and iterate averaging (`average`
        0.95: the step noise of the sampled views, not the step size, limits
        sheets under 2 px thick). About twice the time of the defaults.
        `ReconstructOptions.nicolet().fine()` is the baseline at the same renderer,
        schedule and averaging. On thick shapes it costs twice the time for the
        same result (pretzel: CD 0.0015 / IoU 0.985 against 0.0015 / 0.984).
        """
        return dataclasses.replace(
            self, sigma=0.03, lr_decay=0.9, average=0.95, n_cycles=5, max_faces=max(self.max_faces, 20000),
            initial_edge_length=1.4, final_edge_length=1.0,
        )

    def edge_lengths(self) -> list[float]:
        """Target edge length of each remesh in pixels (coarse to fine)."""
        n = self.n_cycles - 1
        if n <= 0:
            return []
        if n == 1:
            return [self.final_edge_length]
        r = (self.final_edge_length / self.initial_edge_length) ** (1.0 / (n - 1))
        return [self.initial_edge_length * r**i for i in range(n)]


@dataclasses.dataclass(frozen=True)
class Reconstruction:
    """Result of `reconstruct`.

    Attributes:
        mesh: the final `Mesh` (`.to_numpy()` for arrays).
        genus: genus of `mesh` (-1 when it is not a closed manifold).
        genus_ok: `genus` equals the requested genus.
        history: per-step arrays (`loss`, `alpha`, `normal`, ..., from `optimize_block`,
            concatenated over cycles, plus `time` in seconds since the start) and
            per-cycle lists under `cycles` (wall time, faces, chi, remesh status,
            truncated faces, new compilations), `render_plans` (distinct rasterizer
            plans) and `compilations` (new compiled executables per jitted piece:
            `optimize_block` once per plan bucket, `remesh` once per capacity bucket).
        options: the `ReconstructOptions` used.
    """

    mesh: Mesh
    genus: int
    genus_ok: bool
    history: dict
    options: ReconstructOptions


def _axis_fit(v: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Map vertices into the box [lo, hi], matching axes by extent (longest to longest).

    The axis permutation is completed by a mirror when it is odd, so the map is
    orientation-preserving (outward normals stay outward).
    """
    vlo, vhi = v.min(0), v.max(0)
    src = np.argsort(vhi - vlo)
    dst = np.argsort(hi - lo)
    perm = np.empty(3, int)
    perm[dst] = src  # output axis d takes input axis perm[d]
    odd = np.linalg.det(np.eye(3)[perm]) < 0
    out = np.empty_like(v)
    for d in range(3):
        s = perm[d]
        t = (v[:, s] - vlo[s]) / max(vhi[s] - vlo[s], 1e-12)
        if odd and d == dst[0]:
            t = 1.0 - t  # mirror the thinnest axis
        out[:, d] = lo[d] + t * (hi[d] - lo[d])
    return out


def _hull_thickness(alpha, cams: Cameras, resolution: int, pixel: float) -> float:
    """`2 * volume / area` of the largest piece of the visual hull, in pixels (inf if none)."""
    try:
        v, f = _largest_component(visual_hull(alpha, cams, resolution=resolution)).to_numpy()
    except ValueError:
        return math.inf
    v = v.astype(np.float64)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()
    volume = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    return float(2.0 * abs(volume) / area / pixel) if area > 0 else math.inf


def _largest_component(mesh: Mesh) -> Mesh:
    n, labels = connected_components(mesh)
    if n == 1:
        return mesh
    v, f = mesh.to_numpy()
    f = f[labels == np.bincount(labels).argmax()]
    used, f = np.unique(f, return_inverse=True)
    return Mesh.from_numpy(v[used], f.reshape(-1, 3))


def _tunnels(hull: Mesh, count: int, size: float) -> Mesh | None:
    """`hull` with `count` small handles: U-shaped tunnels just under its surface.

    The silhouettes cannot show handles whose holes no view sees through (eyelets,
    hooks, holes in a concave region), so the visual hull can have a lower genus
    than the object. Each missing handle is added where it changes the shape the
    least: a thin half-ring tunnel (ring radius `size`, tube radius `0.3 size`)
    that dives under the surface and comes back up `2 size` further on, cut by
    subtracting a torus centred on the surface, with manifold3d's exact booleans.
    The sites are spread over the surface by farthest-point sampling of surface
    samples; a cut is kept only when it raises the genus by exactly one and
    leaves one piece. Returns
    `None` when fewer than `count` fit. Host-side, deterministic.
    """
    import manifold3d
    import trimesh

    v, f = hull.to_numpy()
    tm = trimesh.Trimesh(v.astype(np.float64), f, process=False)
    pts, fid = trimesh.sample.sample_surface_even(tm, 2000, seed=0)
    normals = tm.face_normals[fid]
    solid = manifold3d.Manifold(manifold3d.Mesh(vert_properties=v.astype(np.float32), tri_verts=f.astype(np.uint32)))
    ring = manifold3d.Manifold.revolve(manifold3d.CrossSection.circle(0.3 * size, 12).translate([size, 0.0]), 16)
    dist = np.linalg.norm(pts - pts.mean(0), axis=1)  # farthest-point order, from the extreme sample
    added = 0
    for _ in range(min(len(pts), 8 * count)):
        if added == count:
            break
        i = int(np.argmax(dist))
        dist = np.minimum(dist, np.linalg.norm(pts - pts[i], axis=1))
        n = normals[i]
        t = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        t /= np.linalg.norm(t)
        # ring plane spanned by the tangent t (local x) and the normal n (local y)
        cut = solid - ring.transform(np.column_stack([t, n, np.cross(t, n), pts[i]]))
        if cut.genus() == solid.genus() + 1 and len(cut.decompose()) == 1:
            solid = cut
            added += 1
    if added < count:
        return None
    out = solid.to_mesh()
    return Mesh.from_numpy(np.asarray(out.vert_properties, np.float32)[:, :3], np.asarray(out.tri_verts, np.int32))


def _hull_start(alpha, cams: Cameras, genus: int, target: float, options: ReconstructOptions):
    """The visual hull as a start mesh, with the requested genus.

    Tries the grid sizes `options.hull_resolutions` with a grey-level closing of
    0, 1, 2 cells (closing fills the spurious thin tunnels carving leaves; it stops
    once no grid reaches the genus: closing only removes handles). When no hull
    has the genus but one has fewer handles, the missing ones are drilled as thin
    small tunnels (`_tunnels`, size `target`) into the one with the most.
    Returns `(mesh, (resolution, closing), tunnels)` or `(None, None, 0)`. The
    start is remeshed to edge length `target` (world units) within the face budget.
    """

    def remeshed(hull):
        m, _ = remesh(hull, RemeshOptions(target_edge_length=target, iterations=5, max_faces=options.max_faces))
        v, f = m.to_numpy()
        if len(f) > options.max_faces or euler_characteristic(m) != 2 - 2 * genus or connected_components(m)[0] != 1:
            return None
        return Mesh.from_numpy(v.astype(np.float32), f, capacity=capacity_bucket(options.max_faces))

    below = []  # (genus, order, hull, grid) of hulls with fewer handles than requested
    for closing in (0, 1, 2):
        highest = -1
        for res in options.hull_resolutions:
            try:
                hull = _largest_component(visual_hull(alpha, cams, resolution=res, closing=closing))
                g = mesh_genus(hull)
            except ValueError:
                continue
            highest = max(highest, g)
            if g < genus:
                below.append((-g, len(below), hull, (res, closing)))
            if g != genus:
                continue
            m = remeshed(hull)
            if m is not None:
                return m, (res, closing), 0
        if highest < genus:
            break
    for neg_g, _, hull, grid in sorted(below, key=lambda b: b[:2]):
        drilled = _tunnels(hull, genus + neg_g, target)
        m = None if drilled is None else remeshed(drilled)
        if m is not None:
            return m, grid, genus + neg_g
    return None, None, 0


def _initial_mesh(genus: int, lo, hi, options: ReconstructOptions) -> Mesh:
    g = 0 if options.start == "sphere" else genus
    prim = genus_primitive(g, n_faces=options.initial_faces)
    v, f = prim.to_numpy()
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    # shrink slightly inside the hull: the silhouettes then pull the surface outwards
    v = _axis_fit(v, centre - 0.9 * half, centre + 0.9 * half)
    return Mesh.from_numpy(v.astype(np.float32), f, capacity=capacity_bucket(options.max_faces))


def _pixel_footprint(cams: Cameras, point: np.ndarray) -> float:
    """Median over cameras of the world size of one pixel at `point`."""
    depth = np.linalg.norm(np.asarray(cams.centers) - point, axis=1)
    return float(np.median(depth / np.asarray(cams.focal)[:, 0]))


def _plan_bucket(plan: RasterPlan) -> RasterPlan:
    """Round the plan's face budgets up to powers of 1.25 so nearby meshes share one compiled plan."""

    def up(n):
        return 0 if n == 0 else int(math.ceil(1.25 ** math.ceil(math.log(max(n, 1), 1.25))))

    return RasterPlan(
        window=plan.window, max_faces=up(plan.max_faces), big_window=plan.big_window, max_big_faces=up(plan.max_big_faces)
    )


def _remesh_state_impl(state: OptimizerState, target, options: RemeshOptions):
    """Remesh the state's mesh (FFI), carrying the Adam moments; rest shape := new shape."""
    adam = state.adam
    attrs = jnp.concatenate([adam.mu, adam.nu], axis=1)
    mesh, carried, info = remesh_in_jit(state.mesh, dataclasses.replace(options, target_edge_length=target), attrs)
    carried = carried.astype(adam.mu.dtype)
    new_adam = adam._replace(mu=carried[:, :3], nu=jnp.maximum(carried[:, 3:], 0.0))
    new_state = OptimizerState(
        mesh=mesh, adam=new_adam, rest_vertices=mesh.vertices, step=state.step, key=state.key
    )
    return new_state, info


_remesh_state = jax.jit(_remesh_state_impl, static_argnames=("options",))


def _clock_us(_after) -> np.ndarray:
    """Host clock in microseconds mod 2^31 (int32), read once `_after` is computed."""
    return np.int32(time.perf_counter_ns() // 1000 % (1 << 31))


@jax.jit(static_argnames=("n_steps", "opt", "remesh_options"), donate_argnames=("state",))
def _all_cycles(state, cams, targets, lr_scales, lengths, *, n_steps, opt, remesh_options):
    """Every cycle in one `lax.scan`: optimizer block, overflow count, remesh when `length > 0`."""
    kw = dict(opt.render_kwargs)
    clock = jax.ShapeDtypeStruct((), jnp.int32)

    def cycle(state, xs):
        lr_scale, length = xs
        state, record = _optimize_block(state, cams, targets, n_steps, opt, lr_scale)
        _, info = render(state.mesh, cams, channels=("alpha",), sigma=kw["sigma"], plan=kw["plan"], return_info=True)
        t_opt = io_callback(_clock_us, clock, record["loss"][-1], ordered=True)
        state, status = jax.lax.cond(
            length > 0,
            lambda s: (lambda out: (out[0], out[1].status))(_remesh_state_impl(s, length, remesh_options)),
            lambda s: (s, jnp.int32(-1)),
            state,
        )
        t_end = io_callback(_clock_us, clock, state.mesh.vertices[0, 0], ordered=True)
        out = dict(record=record, overflow=info.n_overflow, status=status, mesh=state.mesh, clock=(t_opt, t_end))
        return state, out

    return jax.lax.scan(cycle, state, (lr_scales, lengths))


def _compiled() -> dict:
    """Compiled-executable counts of the jitted pieces of the loop (for the history)."""
    fns = {"optimize_block": _optimize_block_jit, "remesh": _remesh_state, "render": _render_jit, "all_cycles": _all_cycles}
    return {k: (f._cache_size() if hasattr(f, "_cache_size") else 0) for k, f in fns.items()}


def _optimize_options(options: ReconstructOptions, plan: RasterPlan) -> OptimizeOptions:
    return OptimizeOptions(
        learning_rate=options.learning_rate,
        lambda_=options.lambda_,
        adam_quantile=options.adam_quantile,
        weights=options.weights,
        views_per_step=options.views_per_step,
        average=options.average,
        render_kwargs=(("sigma", options.sigma), ("gamma", options.gamma), ("plan", plan)),
    )


def _run_one_jit(state, cams, targets, lengths, pixel, options, remesh_options, t0, callback):
    """All cycles in one compiled scan (`options.one_jit`); returns what the Python loop builds."""
    n = options.n_cycles
    # one plan for the whole run, sized for the face count the last remesh asks for
    faces0 = int(state.mesh.n_faces)
    growth = 1.0 if not lengths else min(options.max_faces / faces0, (lengths[0] / lengths[-1]) ** 2)
    plan = plan_render(state.mesh, cams, sigma=options.sigma, face_margin=1.3 * max(growth, 1.0))
    # the shape changes under this plan: keep a big tier (faces up to twice the window
    # or the largest now, for an eighth of the budget) for faces that grow or stretch
    plan = _plan_bucket(RasterPlan(
        window=plan.window, max_faces=plan.max_faces, big_window=max(plan.big_window, 2 * plan.window),
        max_big_faces=max(plan.max_big_faces, plan.max_faces // 8),
    ))
    world = [lengths[c] * pixel if c < len(lengths) else 0.0 for c in range(n)]
    lr_scales = jnp.asarray([options.lr_decay**c for c in range(n)], jnp.float32)
    state, out = _all_cycles(
        state, cams, targets, lr_scales, jnp.asarray(world, jnp.float32),
        n_steps=options.steps_per_cycle, opt=_optimize_options(options, plan), remesh_options=remesh_options,
    )
    out = jax.device_get(out)
    steps, cycles = [], []
    t_opt, t_end = (np.asarray(t, np.int64) for t in out["clock"])
    wall = time.perf_counter() - t0
    # the clock wraps at 2^31 us (36 min): differences modulo 2^31
    elapsed_end = (t_end - t_end[-1]) % (1 << 31)
    elapsed_end = np.where(elapsed_end > (1 << 30), elapsed_end - (1 << 31), elapsed_end) * 1e-6 + wall
    elapsed_opt = elapsed_end - ((t_end - t_opt) % (1 << 31)) * 1e-6
    for c in range(n):
        record = {k: np.asarray(v[c]) for k, v in out["record"].items()}
        record["time"] = np.full(options.steps_per_cycle, np.nan)
        record["time"][-1] = elapsed_end[c]
        steps.append(record)
        m = jax.tree.map(lambda a: a[c], out["mesh"])
        row = {"cycle": c}
        if world[c] > 0:
            row["remesh_status"] = RemeshStatus(int(out["status"][c])).name
            row["remesh_seconds"] = float(elapsed_end[c] - elapsed_opt[c])
        row.update(
            faces=int(m.n_faces),
            vertices=int(m.n_vertices),
            chi=euler_characteristic(m),
            loss=float(record["loss"][-1]),
            truncated_faces=int(out["overflow"][c]),
            compilations=0,
            seconds=float(elapsed_end[c] - (elapsed_end[c - 1] if c else 0.0)),
            elapsed=float(elapsed_end[c]),
        )
        cycles.append(row)
    if callback is not None:
        tb = time.perf_counter()
        for c in range(n):
            callback(cycles[c], jax.tree.map(lambda a: jnp.asarray(a[c]), out["mesh"]))
        t0 += time.perf_counter() - tb
    return state, steps, cycles, {plan}, t0


def reconstruct(images, cams: Cameras, genus: int, *, options: ReconstructOptions = ReconstructOptions(), key=None, callback=None) -> Reconstruction:
    """Reconstruct a watertight mesh of genus `genus` from multi-view images.

    Args:
        images: `(N, H, W, 4)` RGBA in [0, 1] with RGB = (n + 1) / 2 world normals and
            A = silhouette (what `render_targets` produces), or `(N, H, W)` /
            `(N, H, W, 1)` silhouettes only (then only alpha is rendered and fitted).
        cams: a `Cameras` with N views of the images' size.
        genus: the object's genus (int >= 0).
        options: `ReconstructOptions` (`ReconstructOptions.nicolet()` for the baseline).
        key: PRNG key for view sampling (default `jax.random.key(0)`); the result is
            deterministic for a given key.
        callback: optional `callback(row, mesh)` called after every cycle with that
            cycle's history row (a dict: cycle, loss, faces, chi, seconds, elapsed,
            ...) and the current mesh (time spent in the callback is not counted).

    Returns:
        A `Reconstruction`. Inputs are not modified.
    """
    if isinstance(genus, bool) or not isinstance(genus, (int, np.integer)) or genus < 0:
        raise ValueError(f"genus must be an int >= 0, got {genus!r}")
    if not isinstance(options, ReconstructOptions):
        raise ValueError(f"options must be a ReconstructOptions, got {type(options).__name__}")
    genus = int(genus)
    alpha, normals = split_targets(images, cams)
    if options.views_per_step is not None and options.views_per_step > len(cams):
        raise ValueError(f"options.views_per_step ({options.views_per_step}) exceeds the {len(cams)} views")
    targets = jnp.asarray(alpha[..., None] if normals is None else np.asarray(images, np.float32))
    key = jax.random.key(0) if key is None else key

    t0 = time.perf_counter()
    lo, hi = visual_hull_bounds(alpha, cams)
    pixel = _pixel_footprint(cams, 0.5 * (lo + hi))
    thickness, fine = None, False
    if options.fine_below > 0:
        thickness = _hull_thickness(alpha, cams, options.hull_resolutions[0], pixel)
        if thickness < options.fine_below:
            options, fine = options.fine(), True
    lengths = options.edge_lengths() if options.remesh else []
    start, hull_resolution, mesh0, tunnels = options.start, None, None, 0
    if start == "auto":
        first = lengths[0] if lengths else options.final_edge_length
        mesh0, hull_resolution, tunnels = _hull_start(alpha, cams, genus, first * pixel, options)
        start = "primitive" if mesh0 is None else "visual_hull+tunnels" if tunnels else "visual_hull"
    if mesh0 is None:
        mesh0 = _initial_mesh(genus, lo, hi, options)
    state = init_optimizer_state(mesh0, key)
    remesh_options = RemeshOptions(adaptive=options.adaptive, iterations=3)

    steps, cycles, plans = [], [], set()
    sigma = options.sigma
    compiled0 = compiled = _compiled()
    if options.one_jit:
        state, steps, cycles, plans, t0 = _run_one_jit(state, cams, targets, lengths, pixel, options, remesh_options, t0, callback)
        compiled = _compiled()
        cycles[0]["compilations"] = sum(compiled.values()) - sum(compiled0.values())
    for c in range(options.n_cycles if not options.one_jit else 0):
        tc = time.perf_counter()
        plan = _plan_bucket(plan_render(state.mesh, cams, sigma=sigma, face_margin=1.3))
        plans.add(plan)
        opt = _optimize_options(options, plan)
        lr_scale = options.lr_decay**c
        state, record = optimize_block(state, cams, targets, n_steps=options.steps_per_cycle, options=opt, lr_scale=lr_scale)
        record = jax.device_get(record)
        _, info = render(state.mesh, cams, channels=("alpha",), sigma=sigma, plan=plan, return_info=True)
        truncated = int(info.n_overflow)
        row = {"cycle": c, "optimize_seconds": time.perf_counter() - tc}
        if c < len(lengths):
            tr = time.perf_counter()
            state, rinfo = _remesh_state(state, jnp.float32(lengths[c] * pixel), remesh_options)
            row["remesh_status"] = RemeshStatus(int(rinfo.status)).name
            row["remesh_seconds"] = time.perf_counter() - tr
        record["time"] = np.full(options.steps_per_cycle, np.nan)
        record["time"][-1] = time.perf_counter() - t0
        steps.append(record)
        row.update(
            faces=int(state.mesh.n_faces),
            vertices=int(state.mesh.n_vertices),
            chi=euler_characteristic(state.mesh),
            loss=float(record["loss"][-1]),
            truncated_faces=truncated,
            compilations=sum(_compiled().values()) - sum(compiled.values()),
            seconds=time.perf_counter() - tc,
            elapsed=time.perf_counter() - t0,
        )
        compiled = _compiled()
        cycles.append(row)
        if callback is not None:
            tb = time.perf_counter()
            callback(row, jax.tree.map(jnp.array, state.mesh))  # a copy: the state is donated next
            t0 += time.perf_counter() - tb

    history = {k: np.concatenate([s[k] for s in steps]) for k in steps[0]}
    history["cycles"] = cycles
    history["render_plans"] = len(plans)
    history["compilations"] = {k: compiled[k] - compiled0[k] for k in compiled}
    history["seconds"] = time.perf_counter() - t0
    history["requested_genus"] = genus
    history["start"] = start  # "visual_hull", "visual_hull+tunnels", "primitive" or "sphere"
    history["tunnels"] = tunnels  # handles drilled into a visual hull of too low a genus
    history["hull_grid"] = hull_resolution  # (resolution, closing) of the visual-hull start
    history["hull_thickness"] = thickness  # px, 2 * volume / area (None: fine_below is 0)
    history["fine"] = fine  # switched to options.fine() (thin structures)
    mesh = state.mesh
    try:
        g = mesh_genus(mesh) if is_closed_manifold(mesh) else -1
    except ValueError:
        g = -1
    expected = 0 if options.start == "sphere" else genus
    return Reconstruction(mesh=mesh, genus=g, genus_ok=(g == expected), history=history, options=options)


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
    plan = plan_render(mesh, big, sigma=fine_sigma)
    img = render(mesh, big, channels=("alpha", "normal"), sigma=fine_sigma, gamma=1e-3, plan=plan)
    img = np.asarray(img).reshape(len(cams), h, s, w, s, 4)
    # hard coverage of each fine pixel (the soft alpha dips to 0.75 on interior edges)
    cover = (img[..., :1] >= 0.5).astype(np.float32)
    a = cover.mean(axis=(2, 4))
    n = (img[..., 1:] * cover).mean(axis=(2, 4))
    covered = a > 0.0
    rgb = np.where(covered, (n / np.where(covered, a, 1.0) + 1.0) * 0.5, 0.0)
    return np.concatenate([np.clip(rgb, 0.0, 1.0), np.clip(a, 0.0, 1.0)], -1).astype(np.float32)
