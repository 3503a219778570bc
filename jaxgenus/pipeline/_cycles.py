"""The optimize/remesh cycles of `reconstruct`: one cycle, two drivers.

A cycle is `optimize_steps` (a `lax.scan` of large-steps uniform Adam on the
soft-raster loss), the rasterizer's overflow count at the result (with a
JAX-splat plan only: the native CPU kernel draws every face whole), and,
when the cycle's target edge length is > 0, the native V-cycle remesher through
the XLA FFI, carrying the Adam moments and, in photometric fits, the albedo
and its moments (the rest shape of the inversion penalty
becomes the new shape). Host clock readings after the optimizer and after the
remesh time the two parts in both drivers.

* `run_per_cycle`: each cycle as two compiled programs driven from Python, the optimizer
  block (`optimizer_block`) and the remesh, timed on the host between them (no host
  callback in either, so JAX's persistent compilation cache can hold them); each cycle
  fits its own pyramid level (`levels`).
* `run_one_jit`: every cycle in one compiled `lax.scan` of `cycle`, which reads the host
  clock through ordered callbacks (`ReconstructOptions.one_jit`).

`run_polish` then runs the closing polish of photo targets fitted with photo-consistency
(`ReconstructOptions.polish_cycles`): more cycles of the finest level without remeshing, on
the silhouettes and colour photo-consistency only.

On CPU the renderer's native kernel needs no plan. Elsewhere the JAX splat is
re-planned from the geometry every cycle (plans rounded to buckets so nearby
meshes share one compiled cycle), or, in one jit, planned once for the final
face count.

Both return a `CycleRun`: the final state, the per-step arrays, one `CycleRecord`
per cycle, the plans used and the compilations.
"""

from __future__ import annotations

import ctypes
import dataclasses
import math
import time
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import io_callback

from jaxgenus.geometry import Cameras, RemeshOptions, RemeshStatus, euler_characteristic, remesh_in_jit
from jaxgenus.optim import (Appearance, OptimizeOptions, OptimizerState, StepRecord, block_factor,
                            count_compilations, init_optimizer_state, optimize_steps)
from jaxgenus.pipeline._history import CycleRecord
from jaxgenus.pipeline._options import ReconstructOptions
from jaxgenus.rendering import RasterPlan, plan_render, render

__all__ = ["POLISH_AVERAGE", "POLISH_LAMBDA", "CycleOutput", "CycleRun", "Level", "cycle", "optimizer_block", "polish_count", "run_one_jit", "run_per_cycle",
           "run_polish", "heap_returned"]

_WRAP = 1 << 31  # the host clock is read in microseconds modulo 2^31 (int32): it wraps every 36 min


class Level(NamedTuple):
    """What one cycle fits: a pyramid level of the targets.

    Attributes:
        cameras: the level's cameras (scaled with the images).
        targets: `(N, h, w, C)` targets at that level.
        crop: > 0: the cycle fits random `crop x crop` windows of them.
        factor: the images were downsampled by this factor.
        views, window, pixels: what one step renders (`jaxgenus.optim.step_views`): `views`
            views, whole (`window` 0) or through `window x window` windows; `pixels` in all.
        valid: views split over devices (`jaxgenus.optim.spread_views`): which are real; else None.
        neighbours: photo targets: `(N, M)` neighbour views of each view (photo-consistency), or
            `(table, depths (N, h, w))` with the views' stereo depths at this level; else None. With
            the views split over devices, in the slots of their layout (`optimize_steps`).
        table: photo-consistency: the `(N, M)` neighbour views of each view (host, the views' own
            order: the verdict's residual); else None.
    """

    cameras: Cameras
    targets: jax.Array
    crop: int
    factor: int
    views: int = 0
    window: int = 0
    pixels: int = 0
    valid: jax.Array | None = None
    neighbours: jax.Array | tuple | None = None
    table: np.ndarray | None = None


class CycleOutput(NamedTuple):
    """What one `cycle` reports (arrays; stacked over cycles by `run_one_jit`)."""

    record: StepRecord  # (n_steps,) arrays
    overflow: jax.Array  # faces drawn incompletely at the end of the optimizer block
    status: jax.Array  # RemeshStatus of the remesh, -1 when there was none
    clock: tuple  # host clock (us mod 2^31) at the start, after the optimizer and at the end
    mesh: object  # the mesh after the cycle


@dataclasses.dataclass(frozen=True)
class CycleRun:
    """What a driver returns.

    Attributes:
        state: the optimizer state after the last cycle.
        steps: per-step arrays of every cycle, concatenated (`RECORD_KEYS` and `time`).
        cycles: one `CycleRecord` per cycle.
        plans: distinct rasterizer plans used.
        compilations: new compiled executables per program (`"cycle"`: optimizer blocks, `"remesh"`,
            `"all_cycles"`).
        callback_seconds: time spent in the caller's callback (not part of the run).
    """

    state: OptimizerState
    steps: dict
    cycles: tuple[CycleRecord, ...]
    plans: int
    compilations: dict
    callback_seconds: float


def _clock_us(_after) -> np.ndarray:
    """Host clock in microseconds mod 2^31 (int32), read once `_after` is computed."""
    return np.int32(time.perf_counter_ns() // 1000 % _WRAP)


def _remesh_state(state: OptimizerState, length, options: RemeshOptions):
    """Remesh the state's mesh (FFI), carrying the Adam moments; rest shape := new shape."""
    adam, app = state.adam, state.appearance
    columns = [adam.mu, adam.nu]
    if app is not None:  # the albedo and its Adam moments ride along (the lighting is global)
        columns += [app.albedo, app.adam.mu[0], app.adam.nu[0]]
    attrs = jnp.concatenate(columns, axis=1)
    # the budget inside a run is the capacity bucket that `max_faces` chose (room for a split phase)
    options = dataclasses.replace(options, target_edge_length=length, max_faces=None)
    mesh, carried, info = remesh_in_jit(state.mesh, options, attrs)
    carried = carried.astype(adam.mu.dtype)
    new_adam = adam._replace(mu=carried[:, :3], nu=jnp.maximum(carried[:, 3:6], 0.0))
    if app is not None:
        live = mesh.vertex_mask[:, None]
        albedo = jnp.where(live, jnp.maximum(carried[:, 6:9], 0.0), 0.0)
        app_adam = app.adam._replace(mu=(carried[:, 9:12], app.adam.mu[1]),
                                     nu=(jnp.maximum(carried[:, 12:15], 0.0), app.adam.nu[1]))
        app = Appearance(albedo=albedo, lighting=app.lighting, adam=app_adam)
    new_state = OptimizerState(mesh=mesh, adam=new_adam, rest_vertices=mesh.vertices, step=state.step, key=state.key,
                               appearance=app)
    return new_state, info.status


def _overflow(state, cams, opt: OptimizeOptions):
    """Faces drawn incompletely (only a planned splat can truncate them)."""
    if opt.render is None or opt.render.plan is None:
        return jnp.zeros((), jnp.int32)
    _, info = render(state.mesh, cams, channels=("alpha",), sigma=opt.render.sigma, plan=opt.render.plan,
                     return_info=True)
    return info.n_overflow


def cycle(state, cams, targets, valid, neighbours, lr_scale, length, *, n_steps: int, opt: OptimizeOptions,
          remesh_options: RemeshOptions | None):
    """One cycle in one program (the scan of `run_one_jit`): `n_steps` optimizer steps at `lr_scale`
    then a remesh to `length` (world units) if `length > 0` and `remesh_options`; the host clock is read in the program."""
    clock = jax.ShapeDtypeStruct((), jnp.int32)
    t_start = io_callback(_clock_us, clock, state.mesh.vertices[0, 0], ordered=True)
    lr_scale = lr_scale * (1.0 + 0.0 * t_start.astype(lr_scale.dtype))  # the optimizer runs after t_start
    state, record = optimize_steps(state, cams, targets, n_steps, opt, lr_scale, None, valid, neighbours)
    overflow = _overflow(state, cams, opt)
    t_opt = io_callback(_clock_us, clock, record.loss[-1], ordered=True)
    status = jnp.int32(-1)
    length = length * (1.0 + 0.0 * t_opt.astype(length.dtype))  # the remesh runs after t_opt is read
    if remesh_options is not None:  # None: the connectivity is kept (no remesh is traced)
        state, status = jax.lax.cond(
            length > 0,
            lambda s: _remesh_state(s, length, remesh_options),
            lambda s: (s, jnp.int32(-1)),
            state,
        )
    t_end = io_callback(_clock_us, clock, state.mesh.vertices[0, 0], ordered=True)
    return state, CycleOutput(record, overflow, status, (t_start, t_opt, t_end), state.mesh)


@jax.jit(static_argnames=("n_steps", "opt"), donate_argnames=("state",))
def optimizer_block(state, cams, targets, valid, neighbours, lr_scale, factor, *, n_steps: int, opt: OptimizeOptions):
    """A cycle's `n_steps` optimizer steps and the faces drawn incompletely after them. `factor`: the
    mesh's `block_factor` when it is `ok` (the block then compiles no CG fallback), else None."""
    state, record = optimize_steps(state, cams, targets, n_steps, opt, lr_scale, None, valid, neighbours, factor)
    return state, record, _overflow(state, cams, opt)


def _known_factor(mesh, opt: OptimizeOptions):
    """The mesh's Cholesky factor when one process's CPU computes it and it fit its buffer, else None
    (the block factors the matrix itself and falls back to CG). Views split over devices: None."""
    if opt.device_mesh is not None or jax.default_backend() != "cpu":
        return None
    factor = block_factor(mesh, opt.lambda_)
    return factor if bool(factor.ok) else None


_remesh_jit = jax.jit(_remesh_state, static_argnames=("options",), donate_argnames=("state",))


def _timed_cycle(state, level: Level, lr_scale: float, length: float, *, n_steps: int, opt: OptimizeOptions,
                 remesh_options: RemeshOptions | None):
    """`(state, out, compiled)`: one cycle as two programs, the optimizer block and (when `length > 0`
    and `remesh_options`) the remesh, timed on the host between them. No host callback in either,
    so both can come from JAX's persistent compilation cache. `out` is a `CycleOutput` on the host;
    `compiled`: the new executables of each (`"cycle"`, `"remesh"`)."""
    with count_compilations() as counts:
        t_start = _clock_us(None)
        state, record, overflow = optimizer_block(state, level.cameras, level.targets, level.valid,
                                                  level.neighbours, jnp.float32(lr_scale), _known_factor(state.mesh, opt),
                                                  n_steps=n_steps, opt=opt)
        record, overflow = jax.device_get((record, overflow))
        t_opt = _clock_us(None)
        status = np.int32(-1)
        if remesh_options is not None and length > 0:
            state, status = _remesh_jit(state, jnp.float32(length), remesh_options)
            status = jax.device_get(status)
        t_end = _clock_us(None)
    out = CycleOutput(record, overflow, status, (t_start, t_opt, t_end), jax.device_get(state.mesh))
    if sum(counts.values()):
        heap_returned()
    return state, out, {"cycle": counts["optimizer_block"], "remesh": counts["_remesh_state"]}


def heap_returned() -> None:
    """Give the heap freed since back to the system (glibc's `malloc_trim`; elsewhere nothing). XLA's
    compiler frees what it allocated, but glibc's arenas keep it: 0.3-0.5 GiB after each new program
    of a DTU fit at full size, and 0.8 GiB before its full-size stages (results log, 2026-12-07)."""
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


_STATIC = ("n_steps", "opt", "remesh_options")


@jax.jit(static_argnames=_STATIC, donate_argnames=("state",))
def _all_cycles(state, cams, targets, valid, neighbours, lr_scales, lengths, *, n_steps, opt, remesh_options):
    def body(s, xs):
        return cycle(s, cams, targets, valid, neighbours, *xs, n_steps=n_steps, opt=opt, remesh_options=remesh_options)

    return jax.lax.scan(body, state, (lr_scales, lengths))


def _plan_bucket(plan: RasterPlan) -> RasterPlan:
    """Round the plan's face budgets up to powers of 1.25 so nearby meshes share one compiled plan."""

    def up(n):
        return 0 if n == 0 else int(math.ceil(1.25 ** math.ceil(math.log(max(n, 1), 1.25))))

    return RasterPlan(window=plan.window, max_faces=up(plan.max_faces), big_window=plan.big_window, max_big_faces=up(plan.max_big_faces))


def _cycle_plan(mesh, cams, options) -> RasterPlan | None:
    """None on CPU (the renderer's native kernel needs no plan); elsewhere a plan of
    the JAX splat from the geometry, rounded to a bucket. A plan for whole views
    also serves their crops (the same face sizes, fewer faces)."""
    if jax.default_backend() == "cpu":
        return None
    return _plan_bucket(plan_render(mesh, cams, sigma=options.render.sigma, face_margin=1.3))


def _optimize_options(options: ReconstructOptions, plan: RasterPlan | None, level: Level) -> OptimizeOptions:
    """The optimizer's settings of a cycle: the run's, with the cycle's plan, crop and devices."""
    mesh = None if level.valid is None else level.valid.sharding.mesh
    return dataclasses.replace(options.optimize, crop=level.crop, render=dataclasses.replace(options.render, plan=plan),
                               device_mesh=mesh)


def _us_between(a, b) -> float:
    """Seconds from clock reading `a` to `b` (modulo the wrap)."""
    return float((int(b) - int(a)) % _WRAP) * 1e-6


def _row(c: int, out, *, remeshed: bool, loss, compilations: int, seconds: float, elapsed: float) -> CycleRecord:
    m = out.mesh
    status = RemeshStatus(int(out.status)).name if remeshed else None
    return CycleRecord(
        cycle=c, faces=int(m.n_faces), vertices=int(m.n_vertices), chi=euler_characteristic(m), loss=float(loss),
        truncated_faces=int(out.overflow), compilations=compilations, seconds=seconds, elapsed=elapsed,
        remesh_status=status, remesh_seconds=_us_between(*out.clock[1:]) if remeshed else None,
        optimizer_seconds=_us_between(*out.clock[:2]),
    )


def _host_steps(record, n_steps: int, elapsed: float) -> dict:
    """One cycle's step record as numpy arrays, with `time` (seconds since the start) at its last step."""
    steps = {k: np.asarray(record[k]) for k in record.keys()}
    steps["time"] = np.full(n_steps, np.nan)
    steps["time"][-1] = elapsed
    return steps


def _joined(steps: list[dict]) -> dict:
    return {k: np.concatenate([s[k] for s in steps]) for k in steps[0]}


def _reported(row: CycleRecord, mesh, cycles: list, estimate: Callable | None, callback: Callable | None) -> float:
    """Append `row` to `cycles` (with its `eta` from `estimate(rows)` when given) and pass it to
    `callback(row, mesh)`; the seconds spent in the callback."""
    if estimate is not None:
        row = dataclasses.replace(row, eta=float(estimate(cycles + [row])))
    cycles.append(row)
    if callback is None:
        return 0.0
    tb = time.perf_counter()
    callback(row, jax.tree.map(jnp.asarray, mesh))
    return time.perf_counter() - tb


def run_per_cycle(state, levels: list[Level], world_lengths, options: ReconstructOptions, t0: float,
                  callback: Callable | None, estimate: Callable | None = None) -> CycleRun:
    """One compiled cycle per cycle: cycle c fits `levels[c]` and remeshes to `world_lengths[c]`
    after (0: none). `t0` is the run's start (`perf_counter`); `callback(row, mesh)` is called
    after every cycle, and the time spent in it is reported, not counted; `estimate(rows)`: the
    seconds the fit still needs after the cycles `rows` (the rows' `eta`)."""
    steps, cycles, plans, compiled, waited = [], [], set(), {"cycle": 0, "remesh": 0}, 0.0
    n = options.steps_per_cycle
    for c, level in enumerate(levels):
        tc = time.perf_counter()
        plan = _cycle_plan(state.mesh, level.cameras, options)
        plans.add(plan)
        state, out, counts = _timed_cycle(state, level, options.lr_decay**c, float(world_lengths[c]), n_steps=n,
                                          opt=_optimize_options(options, plan, level), remesh_options=options.remesh_options)
        now = time.perf_counter()
        steps.append(_host_steps(out.record, n, now - t0 - waited))
        row = _row(c, out, remeshed=world_lengths[c] > 0, loss=steps[-1]["loss"][-1],
                   compilations=sum(counts.values()), seconds=now - tc, elapsed=now - t0 - waited)
        compiled = {k: compiled.get(k, 0) + v for k, v in counts.items()}
        waited += _reported(row, out.mesh, cycles, estimate, callback)
    return CycleRun(state, _joined(steps), tuple(cycles), len(plans), {**compiled, "all_cycles": 0}, waited)


def _growing_plan(mesh, cams, world_lengths, options) -> RasterPlan:
    """A JAX-splat plan sized for the final face count, for the whole run."""
    faces0 = int(mesh.n_faces)
    lengths = [w for w in world_lengths if w > 0]
    growth = 1.0 if not lengths else min(options.face_budget / faces0, (lengths[0] / lengths[-1]) ** 2)
    plan = plan_render(mesh, cams, sigma=options.render.sigma, face_margin=1.3 * max(growth, 1.0))
    # the shape changes under this plan: keep a big tier (faces up to twice the window
    # or the largest now, for an eighth of the budget) for faces that grow or stretch
    return _plan_bucket(RasterPlan(
        window=plan.window, max_faces=plan.max_faces, big_window=max(plan.big_window, 2 * plan.window),
        max_big_faces=max(plan.max_big_faces, plan.max_faces // 8),
    ))


def run_one_jit(state, levels: list[Level], world_lengths, options: ReconstructOptions, t0: float,
                callback: Callable | None) -> CycleRun:
    """Every cycle in one compiled scan, with one plan sized for the final face count (same
    arguments and returns as `run_per_cycle`).

    One program has one image size: every cycle fits the last level (`levels[-1]`,
    the images' own resolution, through crops when they are large)."""
    n, level = options.n_cycles, levels[-1]
    plan = None if jax.default_backend() == "cpu" else _growing_plan(state.mesh, level.cameras, world_lengths, options)
    lr_scales = jnp.asarray([options.lr_decay**c for c in range(n)], jnp.float32)
    with count_compilations() as counts:
        state, out = _all_cycles(
            state, level.cameras, level.targets, level.valid, level.neighbours, lr_scales,
            jnp.asarray(world_lengths, jnp.float32),
            n_steps=options.steps_per_cycle, opt=_optimize_options(options, plan, level),
            remesh_options=options.remesh_options,
        )
        out = jax.device_get(out)
    wall = time.perf_counter() - t0
    t_end = np.asarray(out.clock[2], np.int64)
    elapsed = [wall - _us_between(t_end[c], t_end[-1]) for c in range(n)]
    steps, cycles = [], []
    for c in range(n):
        one = jax.tree.map(lambda a: a[c], out)
        steps.append(_host_steps(one.record, options.steps_per_cycle, elapsed[c]))
        cycles.append(_row(
            c, one, remeshed=world_lengths[c] > 0, loss=steps[-1]["loss"][-1],
            compilations=counts["_all_cycles"] if c == 0 else 0,
            seconds=elapsed[c] - (elapsed[c - 1] if c else 0.0), elapsed=elapsed[c],
        ))
    waited = 0.0
    if callback is not None:
        tb = time.perf_counter()
        for c in range(n):
            callback(cycles[c], jax.tree.map(lambda a: jnp.asarray(a[c]), out.mesh))
        waited = time.perf_counter() - tb
    return CycleRun(state, _joined(steps), tuple(cycles), 1, {"cycle": 0, "all_cycles": counts["_all_cycles"]}, waited)


def polish_count(options: ReconstructOptions, level: Level) -> int:
    """The polish cycles a fit whose finest level is `level` runs: `options.polish_cycles` when it
    fits photos with photo-consistency (a neighbour table), else 0."""
    return options.polish_cycles if level.table is not None and options.consistency > 0 else 0


#: The polish's large-steps `lambda_`: less smoothing than the cycles' (19), so photo-consistency can
#: sharpen creases (docs/results.md, "The closing polish").
POLISH_LAMBDA = 5.0
#: The polish's iterate averaging (`OptimizeOptions.average`: about the last 100 steps of each cycle).
POLISH_AVERAGE = 0.99


def _polish_options(options: ReconstructOptions, level: Level, plan) -> OptimizeOptions:
    """The polish's optimizer settings: the silhouettes (at the cycles' weight) and colour
    photo-consistency, unblurred, only (no shading, albedo, stereo or ratio terms), iterates
    averaged (`POLISH_AVERAGE`), smoothing `POLISH_LAMBDA`."""
    weights = dataclasses.replace(options.optimize.weights, photo=0.0, albedo_smoothness=0.0, stereo=0.0,
                                  shading_ratio=0.0, carve=0.0, containment=0.0, consistency_blur=0.0,
                                  consistency_colour=1.0)
    return dataclasses.replace(_optimize_options(options, plan, level), weights=weights,
                               average=POLISH_AVERAGE, lambda_=POLISH_LAMBDA)


def run_polish(run: CycleRun, level: Level, options: ReconstructOptions, t0: float,
               callback: Callable | None, estimate: Callable | None = None) -> CycleRun:
    """`run` followed by `polish_count` polish cycles of `level` (module doc; the step size of the last
    cycle, fresh Adam moments, the connectivity kept), their rows
    (`polish` True) and steps appended to `run`'s. The other arguments as in `run_per_cycle`."""
    n = polish_count(options, level)
    if n == 0:
        return run
    app = run.state.appearance
    state = init_optimizer_state(run.state.mesh, run.state.key, albedo=app.albedo, lighting=app.lighting)
    plan = _cycle_plan(state.mesh, level.cameras, options)  # the connectivity stays: one plan
    opt, steps = _polish_options(options, level, plan), options.steps_per_cycle
    lr = options.lr_decay ** (options.n_cycles - 1)
    cycles, compiled, waited = list(run.cycles), dict(run.compilations), run.callback_seconds
    all_steps = [run.steps]
    for k in range(n):
        tc = time.perf_counter()
        state, out, counts = _timed_cycle(state, level, lr, 0.0, n_steps=steps, opt=opt, remesh_options=None)
        now = time.perf_counter()
        all_steps.append(_host_steps(out.record, steps, now - t0 - waited))
        row = dataclasses.replace(_row(options.n_cycles + k, out, remeshed=False, loss=all_steps[-1]["loss"][-1],
                                       compilations=counts["cycle"], seconds=now - tc, elapsed=now - t0 - waited),
                                  polish=True)
        compiled["cycle"] = compiled.get("cycle", 0) + counts["cycle"]
        waited += _reported(row, out.mesh, cycles, estimate, callback)
    return CycleRun(state, _joined(all_steps), tuple(cycles), run.plans + 1, compiled, waited)
