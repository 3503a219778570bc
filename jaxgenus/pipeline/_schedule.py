"""The resolution schedule of a fit and what it costs.

`levels` gives each cycle its pyramid level (`resolution_factors`: coarse copies first, each
level twice the last, the images' own size for the final refinement) and how a step renders it
(`step_views`: whole views, fewer views or one window, within `OptimizeOptions.max_pixels`).

`CostModel` estimates the time a fit still needs, before the cycles run, from the pixels each
step renders: a step costs `a + b * pixels` seconds, with `a` (the mesh's part: solves, remesh
carry, projection) and `b` (per rendered pixel) measured on this machine from the cycles that
ran (one level measured: `a` is taken as the cost of `PIXELS_PER_FACE` pixels per face); a
cycle at a level not fitted before, and the first polish cycle, also compiles (as long as the
longest compile so far), a remeshing cycle remeshes (the mean remesh time so far), and the
verdict renders every view at full size (forward only: a third of a step's cost per pixel).
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from jaxgenus.geometry import Mesh
from jaxgenus.optim import (place, place_held, pyramid_level, resolution_factors, scaled_cameras,
                            step_views, view_neighbours, views_layout)
from jaxgenus.pipeline._cycles import Level
from jaxgenus.pipeline._history import CycleRecord, Plan
from jaxgenus.pipeline._options import ReconstructOptions
from jaxgenus.pipeline._setup import Setup, fine_texture, texture_share

__all__ = ["CostModel", "PIXELS_PER_FACE", "detail_floor", "fit_factors", "levels", "planned", "schedule_line",
           "world_lengths"]

#: The prior of a step's fixed cost in pixels rendered, per face of the mesh, used while only one
#: level has been timed (DTU scan65 on 2 CPU cores at 9k faces: 0.13 s per step at 30k pixels,
#: 0.29 s at 480k, 1.7 s at 7.7M).
PIXELS_PER_FACE = 64


def _consistency_used(setup: Setup, options: ReconstructOptions) -> bool:
    """Whether the fit uses photo-consistency: photo targets and its weight > 0 (on several devices, of
    one process or of several, each looks its views' neighbours up in a copy of every view's photo at
    the level a block fits)."""
    return setup.targets.kind == "photo" and options.consistency > 0


def _area(mesh: Mesh) -> float:
    v, f = mesh.to_numpy()
    v = np.asarray(v, np.float64)
    return float(0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum())


def detail_floor(setup: Setup, options: ReconstructOptions, surface: Mesh) -> int:
    """The finest level (downsampling factor, a power of two) worth fitting photos or silhouettes at:
    the one whose pixels are half the edge length the face budget allows on `surface` (the visual
    hull when the plan is made; its area in equilateral faces). The albedo lives on the vertices; in finer images the photos' texture, which it cannot
    hold, moves the surface instead. Silhouettes too: their outline is no finer than the mesh's
    edges, and the full-size level samples one view a step. Normal maps are fitted to the full size
    (their shading shows detail at every pixel). With photo-consistency the pixels are a quarter of
    the edge: the term compares the views' texture with each other, not with the albedo, and places
    the surface to a fraction of a pixel (measurements: docs/results.md, "Captures at full size")."""
    if setup.targets.kind == "normals":
        return 1
    edge = math.sqrt(4.0 * _area(surface) / (math.sqrt(3.0) * max(options.face_budget, 1)))
    ratio = edge / ((4.0 if _consistency_used(setup, options) else 2.0) * setup.pixel)
    return 2 ** int(math.floor(math.log2(ratio))) if ratio >= 2 else 1


def fit_factors(setup: Setup, options: ReconstructOptions, floor: int) -> list[int]:
    """Per cycle, the downsampling factor of the level it fits: the schedule (`resolution_factors`),
    no finer than `floor` after the first; `one_jit`: the last level throughout."""
    cams = setup.cams
    factors = resolution_factors(cams.height, cams.width, options.n_cycles, options.coarse_resolution,
                                 options.native_cycles)
    if factors[0] > 1:
        factors = [max(f, min(floor, factors[0])) for f in factors]
    return [factors[-1]] * options.n_cycles if options.one_jit else factors


def levels(setup: Setup, options: ReconstructOptions, start: Mesh) -> list[Level]:
    """The level each cycle fits: downsampled copies of the targets (the schedule, photos no finer
    than the plan's floor, `detail_floor`), the native level through crops when `crop` is set (only after
    downsampled cycles); one program of `one_jit` fits the last level throughout."""
    cams = setup.cams
    floor = setup.plan.floor if setup.plan is not None else detail_floor(setup, options, start)
    factors = fit_factors(setup, options, floor)
    scheduled = resolution_factors(cams.height, cams.width, options.n_cycles, options.coarse_resolution,
                                   options.native_cycles)[0] > 1
    table = None
    if _consistency_used(setup, options):  # photo-consistency pairs: views that see the same part of the start
        table = view_neighbours(cams, points=np.asarray(start.to_numpy()[0], np.float64))
    built = {f: _level(setup, options, f, scheduled, table) for f in sorted(set(factors))}
    return [built[f] for f in factors]


def _level(setup: Setup, options: ReconstructOptions, f: int, scheduled: bool, table) -> Level:
    """The pyramid level of factor `f` (`levels`): targets, cameras, how a step renders it."""
    cams, tg = setup.cams, setup.targets
    mesh, order, valid = views_layout(len(cams), options.devices)
    level = pyramid_level(tg.fit, f, normals=tg.kind == "normals")
    crop = options.crop if (f == 1 and scheduled) else 0
    lc = scaled_cameras(cams, f)
    views, window = step_views(len(lc), lc.height, lc.width, dataclasses.replace(options.optimize, crop=crop))
    near = None if table is None else jnp.asarray(table)
    stereo = None
    if table is not None and setup.stereo is not None and options.stereo > 0 and not crop:
        stereo = jnp.asarray(_resampled(setup.stereo, f, lc.height, lc.width))
    if mesh is not None:  # views split over the devices: each renders ceil(views / devices) of its own
        views = min(-(-views // mesh.size), len(order) // mesh.size) * mesh.size
        lc = place(lc[order], mesh, split=True)
        if setup.held is None:
            level = place(level[order], mesh, split=True)
        else:  # this process holds only its own views' images
            level = place_held(level, mesh, order, setup.held)
        if table is not None:  # the neighbours of each slot's view, as slots (optimize_steps)
            near = place(jnp.asarray(_slot_table(table, order, valid)), mesh, split=True)
            stereo = None if stereo is None else place(stereo[order], mesh, split=True)
    pixels = views * (min(window, lc.height) * min(window, lc.width) if window else lc.height * lc.width)
    return Level(lc, jnp.asarray(level), crop, f, views, window, pixels,
                 None if mesh is None else place(jnp.asarray(valid), mesh, split=True),
                 near if stereo is None else (near, stereo), table)


def _slot_table(table: np.ndarray, order: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """`table (N, M)` of views' neighbours in the `spread_views` layout `(order, valid)`: row `s` holds the
    neighbours of slot `s`'s view, each as the slot that holds that view (a real one, not padding)."""
    slot_of = np.zeros(len(table), np.int64)
    slot_of[order[valid]] = np.flatnonzero(valid)
    return slot_of[np.asarray(table)[order]].astype(np.int32)


def _resampled(stereo, factor: int, height: int, width: int) -> np.ndarray:
    """`Setup.stereo`'s depths (at 1/`s` of the fitted images) at the level of `factor`: `(N, height, width)`,
    each pixel the depth of the stereo pixel its centre falls in."""
    depth, s = stereo
    rows = np.minimum(((np.arange(height) + 0.5) * factor / s).astype(int), depth.shape[1] - 1)
    cols = np.minimum(((np.arange(width) + 0.5) * factor / s).astype(int), depth.shape[2] - 1)
    return depth[:, rows][:, :, cols].astype(np.float32)


def world_lengths(setup: Setup, options: ReconstructOptions, fitted: list[Level]) -> list[float]:
    """The remesh edge length after each cycle (canonical units; 0: none), in pixels of the level
    the next cycle fits."""
    lengths = options.edge_lengths()
    return [lengths[c] * setup.pixel * fitted[min(c + 1, len(fitted) - 1)].factor if c < len(lengths) else 0.0
            for c in range(options.n_cycles)]


def schedule_line(options: ReconstructOptions, setup: Setup, fitted: list[Level]) -> str:
    cams = setup.cams
    line = f"optimizing: {options.n_cycles} cycles x {options.steps_per_cycle} steps (the first one compiles)"
    if fitted[0].factor > 1:
        line += (f"; images {cams.width}x{cams.height} fitted at 1/{', 1/'.join(str(lv.factor) for lv in fitted)}"
                 " of their size")
    if fitted[-1].factor > 1 and setup.targets.kind != "normals":
        line += (f"; {setup.targets.kind}s no finer than 1/{fitted[-1].factor}: finer images hold detail "
                 f"{options.face_budget} faces cannot (raise max_faces to fit them finer)")
    last = fitted[-1]
    how = (f"{last.views} of {len(cams)} views" if last.views < len(cams) else "all views") + (
        f" through {min(last.window, last.cameras.width)}x{min(last.window, last.cameras.height)} windows"
        if last.window else "")
    return line + f"; the last level renders {how} per step ({last.pixels / 1e6:.2f} Mpixel)"


@dataclasses.dataclass(frozen=True)
class CostModel:
    """The seconds a fit still needs after some of its cycles (module doc).

    Attributes:
        pixels: per cycle, the pixels one step renders.
        remeshes: per cycle, whether it remeshes.
        steps: optimizer steps per cycle.
        verdict_pixels: pixels the verdict renders (every view at full size, once per render).
        polish: how many of the cycles, the last ones, are polish cycles (a program of their own).
    """

    pixels: tuple[int, ...]
    remeshes: tuple[bool, ...]
    steps: int
    verdict_pixels: int
    polish: int = 0

    @staticmethod
    def of(setup: Setup, options: ReconstructOptions, fitted: list[Level], lengths: list[float],
           polish: int = 0) -> CostModel:
        """The model of a fit of the levels `fitted`, remeshing to `lengths`, then `polish` polish cycles
        of the last level (`run_polish`)."""
        renders = 2 + (setup.targets.kind == "photo")  # the result's and the start's silhouettes, its colours
        n, h, w = len(setup.held_cams()), setup.cams.height, setup.cams.width
        remeshes = tuple(bool(x > 0 and options.remesh) for x in lengths)
        return CostModel(tuple(lv.pixels for lv in fitted) + (fitted[-1].pixels,) * polish,
                         remeshes + (False,) * polish, options.steps_per_cycle, renders * n * h * w, polish)

    def step_costs(self, done: list[CycleRecord]) -> tuple[float, float]:
        """`(a, b)`: seconds per step and per rendered pixel per step, fitted to the cycles done (a
        step time that does not grow with the pixels: `b` = 0); one level timed: `b` as `prior`."""
        p = np.array([float(self.pixels[r.cycle]) for r in done])
        t = np.array([(r.optimizer_seconds or r.seconds) / self.steps for r in done])
        if len(set(p.tolist())) >= 2:
            b, a = np.polyfit(p, t, 1)
            return (float(a), float(b)) if a >= 0 and b > 0 else (float(np.mean(t)), 0.0)
        b = self.prior(done)
        return max(float(np.mean(t)) - b * p[0], 0.0), b

    def prior(self, done: list[CycleRecord]) -> float:
        """The per-pixel cost of a step if the first cycle's step cost `PIXELS_PER_FACE` pixels per
        face on top of the pixels it rendered."""
        r = done[0]
        return (r.optimizer_seconds or r.seconds) / self.steps / (PIXELS_PER_FACE * max(r.faces, 1) + self.pixels[0])

    def remaining(self, done: list[CycleRecord]) -> float:
        """Seconds after the last of `done` (the cycles so far, in order) to the end of the fit."""
        if not done:
            return float("nan")
        a, b = self.step_costs(done)
        overhead = [max(r.seconds - (r.optimizer_seconds or r.seconds) - (r.remesh_seconds or 0.0), 0.0)
                    for r in done]
        program = lambda c: (self.pixels[c], c >= len(self.pixels) - self.polish)  # noqa: E731
        fitted = {program(r.cycle) for r in done}
        compile_s = max(overhead)  # a new level or the polish compiles a new program: as long as the longest so far
        remesh = [r.remesh_seconds for r in done if r.remesh_seconds is not None]
        remesh_s = float(np.mean(remesh)) if remesh else 0.0
        total = 0.0
        for c in range(done[-1].cycle + 1, len(self.pixels)):
            p = self.pixels[c]
            total += self.steps * (a + b * p) + (compile_s if program(c) not in fitted else 0.0)
            total += remesh_s if self.remeshes[c] else 0.0
            fitted.add(program(c))
        verdict = (b if b > 0 else self.prior(done)) * self.verdict_pixels / 3.0  # forward only: a third of a step's
        return total + verdict


#: The loss weights that do not act on targets of a kind (left out of the plan), and those of photo-consistency.
_PHOTO = {"photo", "albedo_smoothness", "albedo_edges", "shading_ratio", "consistency", "stereo", "consistency_blur",
          "consistency_colour"}
_UNUSED = {"normals": _PHOTO, "silhouette": _PHOTO | {"normal", "carve"}, "photo": {"normal", "carve"}}
_COLOUR = {"consistency", "stereo", "consistency_blur", "consistency_colour"}


def planned(setup: Setup, genus_given: bool, say) -> Setup:
    """`setup` with its `Plan` (`pipeline._history.Plan`), made once before any fit: the finest level
    from the face budget on the visual hull (`detail_floor`), the settings of a fine texture measured
    on that level's photos (`fine_texture`), the levels, stages and what a step renders; `say(line)`
    for each line of it. The fits, refits and the hidden-handle stage all run `setup.options` and
    `setup.plan` as made here."""
    options, tg, cams = setup.options, setup.targets, setup.cams
    hull = None if tg.kind == "normals" else setup.hulls.get(options.hull_resolutions[0], 0)[0]
    floor = detail_floor(setup, options, hull) if hull is not None else 1
    chose, share = list(setup.choices), None
    if tg.kind == "photo":
        # every view's, also where this process holds only some: every process makes the same plan
        photos = setup.all_views(np.asarray(pyramid_level(tg.fit, fit_factors(setup, options, floor)[-1], normals=False)))
        share = texture_share(photos)

        options = fine_texture(options, tg.kind, photos, chose.append, setup.resolved, share=share)
        floor = detail_floor(setup, options, hull) if hull is not None else 1
    factors = fit_factors(setup, options, floor)
    last = factors[-1]
    lc = scaled_cameras(cams, last)
    crop = options.crop if last == 1 and factors[0] > 1 else 0
    views, window = step_views(len(lc), lc.height, lc.width, dataclasses.replace(options.optimize, crop=crop))
    pixels = views * (min(window, lc.height) * min(window, lc.width) if window else lc.height * lc.width)
    size = int(np.prod(np.shape(tg.fit))) * 4
    weights = {f.name: getattr(options.optimize.weights, f.name) for f in dataclasses.fields(options.optimize.weights)
               if f.name not in _UNUSED[tg.kind]}
    if not _consistency_used(setup, options):
        weights = {k: v for k, v in weights.items() if k not in _COLOUR}
    if setup.stereo is None:
        weights.pop("stereo", None)
    settings = {"n_cycles": options.n_cycles, "steps_per_cycle": options.steps_per_cycle,
                "max_faces": options.face_budget, **{k: v for k, v in weights.items() if v}}
    polish = options.polish_cycles if _consistency_used(setup, options) else 0
    if polish:
        settings["polish_cycles"] = polish
    mesh = views_layout(len(cams), options.devices)[0]
    if mesh is not None and _consistency_used(setup, options):
        finest = int(np.prod(np.shape(tg.fit))) * 4 // last**2
        chose.append(f"photo-consistency on {mesh.size} devices: each holds its views and a copy of every view's "
                     f"photo to look their neighbours up in ({finest / 2**20:.0f} MiB at the finest level)")
    scene = {"views": len(cams), "size": [cams.width, cams.height], "targets": tg.kind, "genus": setup.genus,
             "genus_from": "given" if genus_given else "estimated", "devices": 1 if mesh is None else int(mesh.size),
             "hull_thickness_px": setup.thickness, "texture_share": share, "resolved_faces": setup.resolved}
    plan = Plan(scene=scene, stages=_stages(setup, options, genus_given, polish, last), factors=tuple(factors),
                floor=floor, settings=settings, choices=tuple(chose), views_per_step=views, pixels_per_step=pixels,
                image_bytes=int(size * (1 + sum(1.0 / f**2 for f in set(factors) if f > 1))))
    for line in plan.lines():
        say(line)
    return dataclasses.replace(setup, options=options, plan=plan)


def _stages(setup: Setup, options: ReconstructOptions, genus_given: bool, polish: int, last: int) -> tuple[str, ...]:
    """The stages a run of `options` on `setup` runs, in order (`Plan.stages`)."""
    kind, normals = setup.targets.kind, setup.targets.kind == "normals"
    start = {"auto": "visual-hull start", "sphere": "sphere start", "primitive": "genus-g primitive start"}
    stages = [start[options.start]]
    if options.start == "auto":
        stages.append("handles the hull lacks: " + ("a fit at its genus, cut where the normal images show holes"
                                                    if normals and options.hidden_handles == "images" else "drilled"))
    swept = polish and last == 1 and options.fit_photo_depth and kind == "photo"  # the sweep before the polish
    stages.append(f"fit {options.n_cycles} cycles x {options.steps_per_cycle} steps"
                  + (" + depth sweep" if swept else "") + (f" + {polish} polish cycles" if polish else ""))
    if not genus_given and normals and options.hidden_handles == "images" and options.start != "sphere":
        stages.append("genus: holes the normal images confirm counted and cut, then a fit")
    refits = options.refit_count(setup.cams.height, setup.cams.width, kind)
    if refits:
        stages.append(f"up to {refits} refits")
    if normals:
        stages.append("topology check")
    if options.fill_unseen and kind == "photo":
        stages.append("unseen surface")
    if options.subdivide:
        stages.append("subdivision where coarse")
    if last > 1 and options.fit_outline:
        stages.append("outline at full size")
    if last > 1 and options.fit_photo_depth and kind == "photo":
        stages.append("depth at full size")
    return tuple(stages + ["verdict on the mesh written"])
