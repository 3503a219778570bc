"""The optimize/remesh cycles of `reconstruct`: one cycle body, two drivers.

`cycle` is one cycle: `optimize_steps` (a `lax.scan` of large-steps uniform Adam
on the soft-raster loss), the rasterizer's overflow count at the result, and,
when the cycle's target edge length is > 0, the native V-cycle remesher through
the XLA FFI, carrying the Adam moments and, in photometric fits, the albedo
and its moments (the rest shape of the inversion penalty
becomes the new shape). Host clock readings after the optimizer and after the
remesh time the two parts in both drivers.

* `run_per_cycle`: one jit-compiled `cycle` per cycle, driven from Python; each
  cycle fits its own pyramid level (`levels`).
* `run_one_jit`: every cycle in one compiled `lax.scan` of the same `cycle`
  (`ReconstructOptions.one_jit`).

On CPU the renderer's native kernel needs no plan. Elsewhere the JAX splat is
re-planned from the geometry every cycle (plans rounded to buckets so nearby
meshes share one compiled cycle), or, in one jit, planned once for the final
face count.

Both return the final state, one step record and one `CycleRecord` per cycle,
and the set of plans used.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import io_callback

from jaxgenus.pipeline._history import CycleRecord
from jaxgenus.optim import Appearance, OptimizeOptions, OptimizerState, optimize_steps
from jaxgenus.pipeline._options import ReconstructOptions
from jaxgenus.geometry import RemeshOptions, RemeshStatus, remesh_in_jit
from jaxgenus.rendering import RasterPlan, plan_render
from jaxgenus.rendering import render
from jaxgenus.geometry import euler_characteristic

__all__ = ["CycleOutput", "cycle", "cycle_compilations", "run_one_jit", "run_per_cycle"]

_WRAP = 1 << 31  # the host clock is read in microseconds modulo 2^31 (int32): it wraps every 36 min


class CycleOutput(NamedTuple):
    """What one `cycle` reports (arrays; stacked over cycles by `run_one_jit`)."""

    record: dict  # (n_steps,) arrays, the keys of RECORD_KEYS
    overflow: jax.Array  # faces drawn incompletely at the end of the optimizer block
    status: jax.Array  # RemeshStatus of the remesh, -1 when there was none
    clock: tuple  # host clock (us mod 2^31) after the optimizer and at the end
    mesh: object  # the mesh after the cycle


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
    mesh, carried, info = remesh_in_jit(state.mesh, dataclasses.replace(options, target_edge_length=length), attrs)
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


def cycle(state, cams, targets, outside, lr_scale, length, *, n_steps: int, opt: OptimizeOptions,
          remesh_options: RemeshOptions):
    """One cycle: `n_steps` optimizer steps at `lr_scale` (`outside`: the targets' outside-distance
    maps, or None), then a remesh to `length` (world units) if `length > 0`."""
    kw = dict(opt.render_kwargs)
    clock = jax.ShapeDtypeStruct((), jnp.int32)
    state, record = optimize_steps(state, cams, targets, n_steps, opt, lr_scale, outside)
    _, info = render(state.mesh, cams, channels=("alpha",), sigma=kw["sigma"], plan=kw["plan"], return_info=True)
    t_opt = io_callback(_clock_us, clock, record["loss"][-1], ordered=True)
    state, status = jax.lax.cond(
        length > 0,
        lambda s: _remesh_state(s, length, remesh_options),
        lambda s: (s, jnp.int32(-1)),
        state,
    )
    t_end = io_callback(_clock_us, clock, state.mesh.vertices[0, 0], ordered=True)
    return state, CycleOutput(record, info.n_overflow, status, (t_opt, t_end), state.mesh)


_STATIC = ("n_steps", "opt", "remesh_options")
_cycle_jit = jax.jit(cycle, static_argnames=_STATIC, donate_argnames=("state",))


@jax.jit(static_argnames=_STATIC, donate_argnames=("state",))
def _all_cycles(state, cams, targets, outside, lr_scales, lengths, *, n_steps, opt, remesh_options):
    def body(s, xs):
        return cycle(s, cams, targets, outside, *xs, n_steps=n_steps, opt=opt, remesh_options=remesh_options)

    return jax.lax.scan(body, state, (lr_scales, lengths))


def cycle_compilations() -> dict[str, int]:
    """Compiled executables so far of the per-cycle (`cycle`) and one-jit (`all_cycles`) programs."""
    return {k: (f._cache_size() if hasattr(f, "_cache_size") else 0) for k, f in (("cycle", _cycle_jit), ("all_cycles", _all_cycles))}


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
    return _plan_bucket(plan_render(mesh, cams, sigma=options.sigma, face_margin=1.3))


def _optimize_options(options: ReconstructOptions, plan: RasterPlan | None, crop: int = 0) -> OptimizeOptions:
    return OptimizeOptions(
        crop=crop,
        learning_rate=options.learning_rate,
        lambda_=options.lambda_,
        adam_quantile=options.adam_quantile,
        weights=options.weights,
        views_per_step=options.views_per_step,
        average=options.average,
        albedo_learning_rate=options.albedo_learning_rate,
        lighting_learning_rate=options.lighting_learning_rate,
        render_kwargs=(("sigma", options.sigma), ("gamma", options.gamma), ("plan", plan)),
    )


def _us_between(a, b) -> float:
    """Seconds from clock reading `a` to `b` (modulo the wrap)."""
    return float((int(b) - int(a)) % _WRAP) * 1e-6


def _row(c: int, out, *, remeshed: bool, loss, compilations: int, seconds: float, elapsed: float) -> CycleRecord:
    m = out.mesh
    status = RemeshStatus(int(out.status)).name if remeshed else None
    return CycleRecord(
        cycle=c, faces=int(m.n_faces), vertices=int(m.n_vertices), chi=euler_characteristic(m), loss=float(loss),
        truncated_faces=int(out.overflow), compilations=compilations, seconds=seconds, elapsed=elapsed,
        remesh_status=status, remesh_seconds=_us_between(*out.clock) if remeshed else None,
    )


def run_per_cycle(state, levels, world_lengths, options, remesh_options, t0, callback):
    """One compiled cycle per cycle; `levels[c] = (cameras, targets, crop, outside)` is what cycle c
    fits (a pyramid level; `crop` > 0: random crops of that size; `outside`: the targets'
    outside-distance maps, or None) and `world_lengths[c]`
    the remesh length after cycle c (0: none).

    Returns `(state, steps, cycles, plans, t0)`; `t0` is moved forward by the time
    spent in `callback(row, mesh)` so that it is not counted.
    """
    steps, cycles, plans = [], [], set()
    for c in range(options.n_cycles):
        tc = time.perf_counter()
        before = sum(cycle_compilations().values())
        cams, targets, crop, outside = levels[c]
        plan = _cycle_plan(state.mesh, cams, options)
        plans.add(plan)
        state, out = _cycle_jit(
            state, cams, targets, outside, jnp.float32(options.lr_decay**c), jnp.float32(world_lengths[c]),
            n_steps=options.steps_per_cycle, opt=_optimize_options(options, plan, crop), remesh_options=remesh_options,
        )
        out = jax.device_get(out)
        record = {k: np.asarray(v) for k, v in out.record.items()}
        record["time"] = np.full(options.steps_per_cycle, np.nan)
        record["time"][-1] = time.perf_counter() - t0
        steps.append(record)
        row = _row(
            c, out, remeshed=world_lengths[c] > 0, loss=record["loss"][-1],
            compilations=sum(cycle_compilations().values()) - before,
            seconds=time.perf_counter() - tc, elapsed=time.perf_counter() - t0,
        )
        cycles.append(row)
        if callback is not None:
            tb = time.perf_counter()
            callback(row, jax.tree.map(jnp.asarray, out.mesh))
            t0 += time.perf_counter() - tb
    return state, steps, cycles, plans, t0


def _growing_plan(mesh, cams, world_lengths, options) -> RasterPlan:
    """A JAX-splat plan sized for the final face count, for the whole run."""
    faces0 = int(mesh.n_faces)
    lengths = [w for w in world_lengths if w > 0]
    growth = 1.0 if not lengths else min(options.max_faces / faces0, (lengths[0] / lengths[-1]) ** 2)
    plan = plan_render(mesh, cams, sigma=options.sigma, face_margin=1.3 * max(growth, 1.0))
    # the shape changes under this plan: keep a big tier (faces up to twice the window
    # or the largest now, for an eighth of the budget) for faces that grow or stretch
    return _plan_bucket(RasterPlan(
        window=plan.window, max_faces=plan.max_faces, big_window=max(plan.big_window, 2 * plan.window),
        max_big_faces=max(plan.max_big_faces, plan.max_faces // 8),
    ))


def run_one_jit(state, levels, world_lengths, options, remesh_options, t0, callback):
    """Every cycle in one compiled scan, with one plan sized for the final face count (same returns).

    One program has one image size: every cycle fits the last level (`levels[-1]`,
    the images' own resolution, through crops when they are large)."""
    n = options.n_cycles
    cams, targets, crop, outside = levels[-1]
    before = sum(cycle_compilations().values())
    plan = None if jax.default_backend() == "cpu" else _growing_plan(state.mesh, cams, world_lengths, options)
    lr_scales = jnp.asarray([options.lr_decay**c for c in range(n)], jnp.float32)
    state, out = _all_cycles(
        state, cams, targets, outside, lr_scales, jnp.asarray(world_lengths, jnp.float32),
        n_steps=options.steps_per_cycle, opt=_optimize_options(options, plan, crop), remesh_options=remesh_options,
    )
    out = jax.device_get(out)
    wall = time.perf_counter() - t0
    t_end = np.asarray(out.clock[1], np.int64)
    elapsed = [wall - _us_between(t_end[c], t_end[-1]) for c in range(n)]
    steps, cycles = [], []
    for c in range(n):
        one = jax.tree.map(lambda a: a[c], out)
        record = {k: np.asarray(v) for k, v in one.record.items()}
        record["time"] = np.full(options.steps_per_cycle, np.nan)
        record["time"][-1] = elapsed[c]
        steps.append(record)
        cycles.append(_row(
            c, one, remeshed=world_lengths[c] > 0, loss=record["loss"][-1],
            compilations=(sum(cycle_compilations().values()) - before) if c == 0 else 0,
            seconds=elapsed[c] - (elapsed[c - 1] if c else 0.0), elapsed=elapsed[c],
        ))
    if callback is not None:
        tb = time.perf_counter()
        for c in range(n):
            callback(cycles[c], jax.tree.map(lambda a: jnp.asarray(a[c]), out.mesh))
        t0 += time.perf_counter() - tb
    return state, steps, cycles, {plan}, t0
