"""One fit of `reconstruct`: from a start, the optimize/remesh cycles over the image pyramid, the
verdict, and the `Reconstruction` it makes (mesh mapped back to the user's frame, typed `History`).

The cycles fit the levels of the resolution schedule (`ReconstructOptions.coarse_resolution`);
each remesh sizes its edges in pixels of the level the next cycle fits. The optimizer starts
fresh (photo targets: the median colour as albedo, uniform light).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from jaxgenus.geometry import Mesh, fit_photo_depth, genus as mesh_genus, is_closed_manifold
from jaxgenus.optim import init_optimizer_state, place, pyramid_level, scaled_cameras, summed_over_processes
from jaxgenus.pipeline._cycles import CycleRun, Level, polish_count, run_one_jit, run_per_cycle, run_polish
from jaxgenus.pipeline._history import GenusEstimate, HandleRecord, History, Reconstruction
from jaxgenus.pipeline._options import ReconstructOptions
from jaxgenus.pipeline._schedule import CostModel, levels as fit_levels, schedule_line, world_lengths
from jaxgenus.pipeline._setup import Setup
from jaxgenus.pipeline._start import Start
from jaxgenus.pipeline._start_stage import refit_start
from jaxgenus.pipeline._verdict import Evidence, Verdict, judge
from jaxgenus.rendering import LIGHTING_SHAPES

__all__ = ["FitIndex", "estimate_warnings", "fit", "refits", "start_line"]

#: Where the fit reaches the photos' own size, the depth sweep before the polish moves a vertex only
#: where the photos agree a plane step (1.5 px) or more away: nearer, the fit (a tenth of a pixel on
#: smooth textured surfaces) is finer than the sweep (a fifth); farther, it is a concavity the
#: silhouettes and the fit's local gradients did not reach (docs/results.md, 2026-12-08).
SWEEP_HOLD_PX = 1.5
#: The sweep's pull of each unmeasured vertex to where it is (its solve's diagonal): a move fades over
#: about three edges from the vertices measured (`fit_photo_depth`'s `anchor`).
SWEEP_ANCHOR = 0.01


@dataclasses.dataclass(frozen=True)
class FitIndex:
    """Which fit of a run this is: `fit` (0: the first; k: the k-th refit) of `fits` planned."""

    fit: int = 0
    fits: int = 1


def _initial_state(start: Start, setup: Setup, options: ReconstructOptions, key, factor: int):
    """A fresh optimizer state at the start; photo targets: the median colour of the fully covered
    pixels of the photos at the first level fitted (1/`factor`: the same whatever size the photos
    came at; of every process's views) as albedo, uniform light."""
    tg = setup.targets
    if tg.kind != "photo":
        return init_optimizer_state(start.mesh, key)
    level = setup.all_views(pyramid_level(tg.fit, factor, normals=False))
    alpha = level[..., 3]
    inside = alpha >= 0.99
    rgb = level[..., :3][inside] if inside.any() else level[..., :3][alpha >= 0.5]
    albedo = np.maximum(np.median(rgb, axis=0), 0.02).astype(np.float32)
    return init_optimizer_state(start.mesh, key, albedo=albedo,
                                lighting=np.zeros(LIGHTING_SHAPES[options.lighting], np.float32))


def _result_genus(mesh: Mesh) -> int:
    try:
        return mesh_genus(mesh) if is_closed_manifold(mesh) else -1
    except ValueError:
        return -1


def estimate_warnings(estimate: GenusEstimate | None) -> list[str]:
    if estimate is None or estimate.agreement >= 0.5:
        return []
    return [f"the genus {estimate.genus} was estimated at a low agreement ({estimate.agreement:.0%}, decided by the "
            f"{estimate.cue}; plausible: {list(estimate.plausible)}): give the genus if you know it"]


def _handle_warnings(handles: tuple[HandleRecord, ...]) -> list[str]:
    drilled = sum(h.source == "drilled" for h in handles)
    if not drilled:
        return []
    return [f"{drilled} of {len(handles)} handles were drilled as small tunnels at spread-out sites: neither the "
            "silhouettes nor the images showed where those holes are, so the genus is right but those handles "
            "are probably not the object's own (history['handles'])"]


def _history(setup: Setup, start: Start, options: ReconstructOptions, run: CycleRun, verdict: Verdict,
             levels: list[Level], seconds: float, index: FitIndex) -> History:
    app = run.state.appearance
    where = dict(n_cycles=len(run.cycles), fit=index.fit, fits=index.fits)
    return History(
        steps=run.steps, cycles=tuple(dataclasses.replace(c, **where) for c in run.cycles), seconds=seconds,
        requested_genus=setup.genus, start=start.kind, tunnels=start.tunnels, hull_grid=start.hull_grid,
        hull_thickness=setup.thickness, fine=setup.fine, render_plans=run.plans, compilations=run.compilations,
        targets=setup.targets.kind, frame={"centre": setup.frame.centre.tolist(), "scale": setup.frame.scale},
        genus_estimate=setup.estimate, silhouette_iou=verdict.silhouette_iou,
        start_silhouette_iou=verdict.start_silhouette_iou, normal_error_deg=verdict.normal_error_deg,
        photo_error=verdict.photo_error, photo_consistency=verdict.photo_consistency,
        start_photo_consistency=verdict.start_photo_consistency,
        lighting=None if app is None else np.asarray(app.lighting, np.float64).tolist(), handles=start.handles,
        resolution=[{"factor": lv.factor, "size": [lv.cameras.height, lv.cameras.width], "crop": lv.crop,
                     "views": lv.views, "window": lv.window, "pixels": lv.pixels} for lv in levels],
        devices=1 if levels[0].valid is None else int(levels[0].valid.sharding.mesh.size),
        plan=setup.plan, ok=verdict.ok, warnings=(verdict.warnings + estimate_warnings(setup.estimate) + _handle_warnings(start.handles)
                                 + list(setup.notes)),
    )


def fit(setup: Setup, start: Start, options: ReconstructOptions, key, index: FitIndex, *, t0: float,
        callback: Callable | None, say: Callable[[str], None], finish: Callable | None = None) -> Reconstruction:
    """One fit from `start` with `options` (module doc). `t0`: when this fit's clock started
    (`perf_counter`); `callback(row, mesh)` after every cycle (user frame; its time is not counted);
    `finish(mesh, albedo, finest) -> (mesh, albedo)`: the stages after the fit (user frame), run
    before the verdict, which then judges the mesh they return (the one a run writes)."""
    levels = fit_levels(setup, options, start.mesh)
    lengths = world_lengths(setup, options, levels)
    polish = polish_count(options, levels[-1])
    where = dict(n_cycles=options.n_cycles + polish, fit=index.fit, fits=index.fits)
    frame = setup.frame
    user_callback = None if callback is None else (
        lambda row, m: callback(dataclasses.replace(row, **where), frame.mesh_to_world(m)))
    say(schedule_line(options, setup, levels))
    state = _initial_state(start, setup, options, key, levels[0].factor)
    if levels[0].valid is not None:  # views split over devices: the state is replicated on them
        state = place(state, levels[0].valid.sharding.mesh, split=False)
    remaining = None if options.one_jit else CostModel.of(setup, options, levels, lengths, polish).remaining
    if options.one_jit:
        run = run_one_jit(state, levels, lengths, options, t0, user_callback)
    else:
        run = run_per_cycle(state, levels, lengths, options, t0, user_callback, remaining)
    if polish and setup.targets.kind == "photo" and options.fit_photo_depth and levels[-1].factor == 1:
        run = _swept(run, setup, levels[-1], say)
    if polish:
        say(f"polish: {polish} cycles of {options.steps_per_cycle} steps on the silhouettes and colour "
            "photo-consistency only (polish_cycles=0 given by name: none)")
        run = run_polish(run, levels[-1], options, t0, user_callback, remaining)
    mesh, app = run.state.mesh, run.state.appearance
    g = _result_genus(mesh)
    genus_ok = g == (0 if options.start == "sphere" else setup.genus)
    albedo = None if app is None else np.array(app.albedo[: int(mesh.n_vertices)], np.float32)
    fitted = written = frame.mesh_to_world(mesh)
    if finish is not None:
        written, albedo = finish(fitted, albedo, min(lv.factor for lv in levels))
    verdict = _verdict(setup, start, options, run, levels, genus_ok, mesh if written is fitted else written, albedo, say)
    seconds = time.perf_counter() - t0 - run.callback_seconds
    history = _history(setup, start, options, run, verdict, levels, seconds, index)
    return Reconstruction(mesh=written, genus=g, genus_ok=genus_ok, history=history, options=options, albedo=albedo)


def _swept(run: CycleRun, setup: Setup, level: Level, say: Callable[[str], None]) -> CycleRun:
    """`run` with its mesh moved along its normals to where the photos agree (`fit_photo_depth`: two
    sweeps of +-12 and +-6 px, two neighbouring views agreeing; `SWEEP_HOLD_PX`, `SWEEP_ANCHOR`), for a fit whose
    finest level is the photos' own size; the polish that follows fits what it moved. With the views
    split over processes each sweeps with its own views and the moves are summed (the same mesh in each)."""
    t0 = time.perf_counter()
    mesh = run.state.mesh
    v, f = mesh.to_numpy()
    split = setup.held is not None and len(setup.held) < len(setup.cams)
    out = fit_photo_depth((v, f), setup.cams, setup.images, hold_px=SWEEP_HOLD_PX, anchor=SWEEP_ANCHOR,
                          held=setup.held if split else None, total=summed_over_processes if split else None)
    moved = int((out.distance > 1e-4).sum()) if np.isfinite(out.vertices).all() else 0  # the frame: about unit size
    if moved:
        vertices = mesh.vertices.at[: len(v)].set(jnp.asarray(out.vertices, mesh.vertices.dtype))
        state = eqx.tree_at(lambda s: s.mesh.vertices, run.state, vertices)
        if level.valid is not None:  # views split over devices: the state stays replicated on them
            state = place(state, level.valid.sharding.mesh, split=False)
        run = dataclasses.replace(run, state=state)
    say(f"photo depth: before the polish, {int(out.measured.sum())} of {len(v)} vertices measured where two views "
        f"agree at {setup.cams.width}x{setup.cams.height}, {moved} moved by > 1e-4 of the object's size "
        f"({time.perf_counter() - t0:.0f}s; ReconstructOptions.fit_photo_depth=False: off)")
    return run


def _verdict(setup: Setup, start: Start, options: ReconstructOptions, run: CycleRun, levels: list[Level],
             genus_ok: bool, mesh: Mesh, albedo, say: Callable[[str], None]) -> Verdict:
    """The verdict (`judge`, said) on `mesh`: the fitted mesh (canonical frame, as the state holds it,
    appearance the state's) or the mesh the stages after the fit wrote (the user's frame; `albedo` its
    per-vertex albedo)."""
    app, frame, finest = run.state.appearance, setup.frame, levels[-1]
    written = mesh is not run.state.mesh
    appearance = None if app is None else (app.albedo, app.lighting)
    if written:
        v, f = mesh.to_numpy()
        mesh = Mesh.from_numpy(((np.asarray(v, np.float64) - frame.centre) / frame.scale).astype(np.float32), f)
        if app is not None:
            padded = np.zeros((mesh.vertex_capacity, 3), np.float32)
            padded[: len(albedo)] = albedo
            appearance = (padded, app.lighting)
    consistency = None
    if finest.table is not None:  # the residual at the finest level fitted (straight colours), views in order
        level = setup.all_views(np.asarray(pyramid_level(setup.targets.fit, finest.factor, normals=False)))
        a = level[..., 3:]
        level = np.concatenate([np.where(a > 0, level[..., :3] / np.maximum(a, 1e-6), 0.0), a], axis=-1)
        consistency = (scaled_cameras(setup.cams, finest.factor), level, finest.table)
    t0 = time.perf_counter()
    verdict = judge(Evidence(mesh, start.mesh, setup.cams, setup.targets, run.steps, run.cycles, genus_ok, appearance,
                             setup.images if setup.targets.kind == "photo" else None,
                             carved_start=start.kind.startswith("visual_hull"), consistency=consistency,
                             held=setup.held), options)
    say(f"verdict{f' on the mesh written ({int(mesh.n_faces)} faces)' if written else ''}: "
        f"{'ok' if verdict.ok else 'NOT OK'}; silhouette IoU min {min(verdict.silhouette_iou):.3f}, "
        f"mean {np.mean(verdict.silhouette_iou):.3f} over {len(verdict.silhouette_iou)} views"
        + ("" if verdict.normal_error_deg is None else f"; normal error mean {np.mean(verdict.normal_error_deg):.2f} deg")
        + ("" if verdict.photo_consistency is None or not np.isfinite(verdict.photo_consistency).any() else
           f"; photo-consistency residual median {np.nanmedian(verdict.photo_consistency):.3f} (start "
           f"{np.nanmedian(verdict.start_photo_consistency):.3f})") + f" ({time.perf_counter() - t0:.0f}s)")
    return verdict


# A refit that lowers the mean normal error by less than this share of it predicts a next
# one that gains nothing (docs/results.md, "Default refits"). Default refits only.
_MIN_REFIT_GAIN = 0.03

def start_line(start: Start, genus: int, seconds: float) -> str:
    return (f"start: {start.kind} of genus {genus}, {int(start.mesh.n_faces)} faces"
            + (f", {start.tunnels} handles drilled (the silhouettes show fewer)" if start.tunnels else "")
            + f" ({seconds:.1f}s)")


def _start_of(rec: Reconstruction) -> Start:
    """The record of the start a fit made (its mesh is replaced by a refit's)."""
    h = rec.history
    return Start(rec.mesh, h.start, h.hull_grid, h.tunnels, h.handles)


def refits(rec: Reconstruction, setup: Setup, options: ReconstructOptions, n: int, key, callback,
            say: Callable[[str], None]) -> Reconstruction:
    """Up to `n` further fits, each from the last kept result (module doc; `ReconstructOptions.refits`)."""
    carving = setup.options.for_refit(setup.targets.kind) is not setup.options
    why = "" if options.refits is not None else (f" (normal maps of {setup.cams.width}x{setup.cams.height} are "
                                                 "fitted through the resolution schedule; ReconstructOptions.refits)")
    say(f"refits: {n} more fit{'s' if n > 1 else ''} from this result{why}"
        + (", carving where the normals contradict the images (ReconstructOptions.refit_carve)" if carving else ""))
    for r in range(n):
        if not rec.genus_ok:  # nothing of the right genus to start from: keep what failed, it says why
            break
        step = (lambda line, r=r: say(f"refit {r + 1}/{n}: {line}"))
        opts = setup.options.for_refit(setup.targets.kind) if carving else setup.options
        t0 = time.perf_counter() - rec.history.seconds
        start = refit_start(rec.mesh, _start_of(rec), setup, opts)
        if start is None:
            step("refit: the previous result could not be remeshed into a start; keeping it")
            return rec
        step(start_line(start, setup.genus, time.perf_counter() - t0 - rec.history.seconds))
        new = fit(setup, start, opts, key, FitIndex(r + 1, 1 + n), t0=t0, callback=callback, say=step)
        worse = _fits_worse(new.history, rec.history)
        if worse:
            # a carving refit that fits worse is retried once without carving (the heptoroid's
            # tubes: a contour a pixel off reads as a contradiction); any other is final
            retry = carving and r + 1 < n
            step(f"fits its images worse than the fit it started from ({worse}): keeping that fit"
                 + ("; the next refit runs without carving" if retry else ""))
            history = dataclasses.replace(rec.history, seconds=new.history.seconds,
                                          warnings=rec.history.warnings + [f"refit {r + 1} was dropped: {worse}"])
            rec = dataclasses.replace(rec, history=history)
            if not retry:
                return rec
            carving = False
            continue
        gain = _normal_gain(new.history, rec.history)
        rec = new
        if options.refits is None and r + 1 < n and gain < _MIN_REFIT_GAIN:
            step(f"lowered the mean normal error by {gain:.1%} (< {_MIN_REFIT_GAIN:.0%}): no further refit")
            break
    return rec


def _normal_gain(new: History, old: History) -> float:
    """How much lower `new`'s mean normal error is than `old`'s, as a share of `old`'s
    (inf when the targets are not normal maps: nothing to judge by)."""
    a, b = new.normal_error_deg, old.normal_error_deg
    if a is None or b is None or float(np.mean(b)) <= 0:
        return float("inf")
    return 1.0 - float(np.mean(a)) / float(np.mean(b))


def _fits_worse(new: History, old: History) -> str:
    """Why the fit `new` matches its images worse than `old` ("" when it does not): its
    verdict fails where the old one passed, or its mean silhouette IoU, normal error or
    photo error over all views is worse by more than a small tolerance."""
    why = []
    if old.ok and not new.ok:
        why.append("its verdict is not ok")
    iou_new, iou_old = float(np.mean(new.silhouette_iou)), float(np.mean(old.silhouette_iou))
    if iou_new < iou_old - 0.005:
        why.append(f"mean silhouette IoU {iou_new:.3f} < {iou_old:.3f}")
    for a, b, label, tol in ((new.normal_error_deg, old.normal_error_deg, "normal error", 0.2),
                             (new.photo_error, old.photo_error, "photo error", 0.002)):
        if a is not None and b is not None and float(np.mean(a)) > float(np.mean(b)) + tol:
            why.append(f"mean {label} {float(np.mean(a)):.3g} > {float(np.mean(b)):.3g}")
    return "; ".join(why)
