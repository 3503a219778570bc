"""`reconstruct`: multi-view images -> a watertight mesh of a given genus.

The pipeline (Gao et al. 2026, on this library's parts) reads as its stages:

1. `prepare` (`_setup`): validated targets, the canonical frame (units and placement
   never matter), the pixel size, the genus (estimated when not given), `fine()` for
   thin structures.
2. `first_start` (`_start_stage`): the visual hull with the requested genus (handles it
   lacks opened where the images show holes, else drilled), or a genus-g primitive.
3. `fit` (`_fit`): [optimizer block -> native V-cycle remesh through the XLA FFI] over
   the image pyramid, then the verdict (`_verdict`) and a typed `History`.
4. Refits (`_refits` here): further fits from the result, dropped when they fit the
   images worse.

`ReconstructOptions.nicolet()` is the Nicolet et al. 2021 baseline in the same code:
a sphere start, no remeshing, the same renderer and optimizer.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable

import jax
import numpy as np

from jaxgenus.geometry import Cameras, Mesh, fill_unseen, fit_outline, fit_photo_depth, phong_subdivision
from jaxgenus.optim import summed_over_processes
from jaxgenus.pipeline._cycles import heap_returned
from jaxgenus.pipeline._fit import FitIndex, estimate_warnings, fit, refits, start_line
from jaxgenus.pipeline._handles import HoleTests, hole_tests
from jaxgenus.pipeline._history import GenusEstimate, HandleRecord, Reconstruction
from jaxgenus.pipeline._options import ReconstructOptions
from jaxgenus.pipeline._schedule import planned
from jaxgenus.pipeline._setup import Setup, prepare
from jaxgenus.pipeline._start import Start, remeshed_start
from jaxgenus.pipeline._verdict import Evidence, judged_as_written
from jaxgenus.pipeline._start_stage import (CHECK_TRIES, estimate_line, evidence_level, evidence_pixel,
                                             first_edge_length, first_start,
                                             holes_not_had, image_handle_records, images_estimate)

#: The result is subdivided only where its median edge is longer than this many pixels at the images'
#: own size: a finer mesh holds no detail the images show (a 64-px torus stays at the faces it was fitted with).
SUBDIVIDE_EDGE_PX = 2.0

__all__ = ["genus_estimate", "reconstruct"]


def _check_arguments(genus, options):
    if genus is not None and (isinstance(genus, bool) or not isinstance(genus, (int, np.integer)) or genus < 0):
        raise ValueError(f"genus must be an int >= 0 or None (estimate it), got {genus!r}")
    if not isinstance(options, ReconstructOptions):
        raise ValueError(f"options must be a ReconstructOptions, got {type(options).__name__}")


def genus_estimate(images, cams: Cameras, *, targets: str | None = None,
                   options: ReconstructOptions = ReconstructOptions(), key=None, log=None, views=None,
                   region=None) -> GenusEstimate:
    """The genus `images` show: what `reconstruct(images, cams)` estimates when no genus is given,
    through the same code. A `GenusEstimate`: the silhouettes' visual hull's genus and, for normal
    maps, the holes no silhouette shows that the images confirm (a fit at the hull's genus and a
    cut tested at each place it disagrees with the images the way a hole does; `pipeline._start_stage`),
    with the `agreement` of the cues, the `plausible` genera and the `cue` that decided. Arguments
    as in `reconstruct`. Silhouettes and photos: host-side, no optimization; normal maps: one fit."""
    if not isinstance(options, ReconstructOptions):
        raise ValueError(f"options must be a ReconstructOptions, got {type(options).__name__}")
    say = log if log is not None else (lambda line: None)
    setup = _planned_setup(images, cams, None, targets, options, say, views, region)
    if not _reads_interior(setup, None):
        return setup.estimate
    t0 = time.perf_counter()
    key = jax.random.key(0) if key is None else key
    setup, _, rec = _first_fit(setup, key, FitIndex(0, 1), t0, None, say)
    return _with_holes(setup, rec, key, FitIndex(0, 1), t0, None, say, estimate_only=True)[0].estimate


def _planned_setup(images, cams, genus, targets, options, say, views, region) -> Setup:
    """The run's `Setup` (`prepare`) with its `Plan` (`planned`); the plan is said first, then
    what was measured for it."""
    measured = []
    setup = prepare(images, cams, genus, targets, options, measured.append, views, region)
    setup = planned(setup, genus is not None, say)
    for line in measured:
        if line not in setup.choices:  # said in the plan
            say(line)
    return setup


def _reads_interior(setup: Setup, genus) -> bool:
    """Whether a run estimates the genus from the images' interior too (normal maps, no genus given)."""
    return (genus is None and setup.targets.kind == "normals" and setup.options.hidden_handles == "images"
            and setup.options.start != "sphere")


def _first_fit(setup: Setup, key, index: FitIndex, t0: float, callback, say, finish=None):
    """`(setup, start, rec)`: the first fit of a run, from its first start (`finish`: as `fit`'s)."""
    def fit_genus(g: int) -> Reconstruction:  # the hidden-handle stage: the same setup fitted at the hull's genus
        pre = dataclasses.replace(setup, genus=g, options=setup.options.replaced(hidden_handles="drill"))
        step = lambda line: say(f"hidden handles: fit at genus {g}: {line}")  # noqa: E731
        return fit(pre, first_start(pre, None, step), pre.options, key, FitIndex(0, 1), t0=time.perf_counter(),
                   callback=None, say=step)

    start = first_start(setup, fit_genus, say)
    say(start_line(start, setup.genus, time.perf_counter() - t0))
    return setup, start, fit(setup, start, setup.options, key, index, t0=t0, callback=callback, say=say, finish=finish)


def _with_holes(setup: Setup, rec: Reconstruction, key, index: FitIndex, t0: float, callback, say, *,
                estimate_only: bool = False) -> tuple[Setup, Reconstruction]:
    """The estimate completed from the normal images' interior (`pipeline._start_stage`) and, when they
    confirm holes the fit at the hull's genus lacks, a fit from that fit with the holes cut."""
    hull, t1, frame = setup.estimate, time.perf_counter(), setup.frame
    if not rec.genus_ok:
        say("genus: the fit at the visual hull's genus has another genus; the images' interior was not tested")
        return setup, rec
    v, f = rec.mesh.to_numpy()
    v = (np.asarray(v, np.float64) - frame.centre) / frame.scale
    try:
        # free space only where the silhouettes agree on the fit's handles: a cut there counts one more
        tests = hole_tests(v, f, *evidence_level(setup), min_radius=evidence_pixel(setup),
                           free_space=hull.agreement >= 1.0)
    except ValueError:  # not a manifold solid to cut
        tests = HoleTests(v, f, [], [])
    est = images_estimate(hull, tests, lambda p: p * frame.scale + frame.centre)
    say(estimate_line(hull, est, time.perf_counter() - t1))
    setup = dataclasses.replace(setup, genus=est.genus, estimate=est)
    if estimate_only:
        return setup, rec
    if not tests.opened:
        warnings = [w for w in rec.history.warnings if w not in estimate_warnings(hull)] + estimate_warnings(est)
        return setup, dataclasses.replace(rec, history=dataclasses.replace(rec.history, genus_estimate=est,
                                                                           warnings=warnings))
    edge = first_edge_length(setup.options) * setup.pixel
    cut = Mesh.from_numpy(np.asarray(tests.vertices, np.float32), np.asarray(tests.faces, np.int32))
    mesh = remeshed_start(cut, est.genus, edge, setup.options)
    if mesh is None:
        why = (f"the images show {len(tests.opened)} hole(s) the result does not have (genus {hull.genus}; "
               f"estimated {est.genus}), but the cut surface could not be remeshed into a start: give the genus")
        say(f"genus: {why}")
        history = dataclasses.replace(rec.history, genus_estimate=est, ok=False, warnings=rec.history.warnings + [why])
        return setup, dataclasses.replace(rec, history=history)
    handles = (HandleRecord("hull"),) * hull.genus + image_handle_records(tests.opened, frame)
    start = Start(mesh, "fit+images", rec.history.hull_grid, 0, handles)
    say(start_line(start, setup.genus, time.perf_counter() - t0))
    return setup, fit(setup, start, setup.options, key, index, t0=t0, callback=callback, say=say)


def reconstruct(
    images,
    cams: Cameras,
    genus: int | None = None,
    *,
    targets: str | None = None,
    options: ReconstructOptions = ReconstructOptions(),
    key=None,
    callback=None,
    log=None,
    views=None,
    region=None,
) -> Reconstruction:
    """Reconstruct a watertight mesh of genus `genus` from multi-view images.

    Example:
        >>> import jaxgenus as jg
        >>> gt = jg.builtin_scene("torus")
        >>> cams = jg.sphere_cameras(16, radius=3.0, fov_deg=40.0, resolution=64)
        >>> rec = jg.reconstruct(jg.render_targets(gt, cams), cams, genus=1)
        >>> rec.genus, rec.history["ok"], jg.metrics.volume_iou(rec.mesh, gt) > 0.9
        (1, True, True)
        >>> jg.save_mesh(rec.mesh, "torus.obj")

    Args:
        images: `(N, H, W)` / `(N, H, W, 1)` silhouettes, or `(N, H, W, 4)` RGBA in
            [0, 1] whose A is the silhouette and whose RGB is either world normals
            `(n + 1) / 2` (what `render_targets` produces) or a photo; floats, or uint8 /
            uint16 pixels read as value / 255 / 65535 (8-bit photos held as read take a quarter
            of the memory: `load_images(..., dtype=np.uint8)`).
        cams: a `Cameras` with N views of the images' size, in any units and placement.
        genus: the object's genus (int >= 0), or None to estimate it from the images
            (`history["genus_estimate"]`, a `GenusEstimate`; `genus_estimate` alone gives the
            same): the silhouettes' visual hull and, for normal maps, the holes no silhouette
            shows that the images confirm after a first fit at the hull's genus. Give the
            genus when you know it.
        targets: what RGBA images hold: `"normals"`, `"photo"` (fitted through
            Lambertian shading with a per-vertex albedo and an unknown distant light,
            both estimated: `Reconstruction.albedo`, `history["lighting"]`) or
            `"silhouette"` (use A only); None infers it.
        options: `ReconstructOptions` (`ReconstructOptions.nicolet()` for the baseline).
        key: PRNG key for view sampling (default `jax.random.key(0)`); the result is
            deterministic for a given key.
        callback: optional `callback(row, mesh)` called after every cycle with that
            cycle's `CycleRecord` (reads like a dict: `row["loss"]`, `row["elapsed"]`, ...)
            and the current mesh in the user's frame (time spent in it is not counted).
        log: optional `log(line)` called with a line per stage (frame, start, cycles, verdict).
        views: with processes joined by `jax.distributed`, the increasing indices into `cams`
            of the views `images` holds: each process then passes only its own views
            (`jaxgenus.optim.held_views(len(cams), options.devices)`: those its devices render)
            and all cameras. None: `images` holds every view.
        region: `(centre (3,), radius)`: a sphere of the cameras' world that holds the object, such
            as the unit sphere of an IDR/NeuS capture (`jaxgenus.load_region`). The visual hull,
            and so the start, is cut to it: where the frame cuts the object in the views that would
            carve them, the silhouettes leave whole regions open (DTU scan24 at 1/4 size: three
            quarters of the mesh outside the sphere, seen by no view). Every silhouette's rays
            must meet the sphere (else `ValueError`). None: no bound.

    Returns:
        A `Reconstruction`, in the user's frame and units:

        * `mesh`: the watertight `Mesh` written by the CLI (`mesh.to_numpy()`: vertices, faces);
        * `genus`: its genus (-1 when not a closed manifold); `genus_ok`: it is the genus asked for;
        * `history`: the run record: `history["ok"]` is False, with reasons in
          `history["warnings"]`, when the result does not match its images;
          `history["silhouette_iou"]` per view, `history["genus_estimate"]`, per-step arrays
          (`history["loss"]`) and one `CycleRecord` per cycle (`history["cycles"]`);
        * `options`: the `ReconstructOptions` that ran;
        * `albedo` / `lighting`: photo targets: per-vertex RGB albedo and the estimated light
          (None otherwise); `render_photo(cams)` renders the result as fitted.

        Inputs are not modified.
    """
    t0, waited = time.perf_counter(), [0.0]
    say = log if log is not None else (lambda line: None)
    key = jax.random.key(0) if key is None else key
    _check_arguments(genus, options)
    if callback is not None:
        callback = _timed(callback, waited)
    setup = _planned_setup(images, cams, genus, targets, options, say, views, region)
    n_refits = options.refit_count(setup.cams.height, setup.cams.width, setup.targets.kind)
    index = FitIndex(0, 1 + n_refits)

    finish = _finishing(setup, cams, say)
    last = not (n_refits or _reads_interior(setup, genus))  # the first fit is the last: it judges the mesh written
    setup, start, rec = _first_fit(setup, key, index, t0, callback, say, finish if last else None)
    if _reads_interior(setup, genus):
        setup, rec = _with_holes(setup, rec, key, index, t0, callback, say)
    if n_refits and rec.genus_ok:
        rec = refits(rec, setup, options, n_refits, key, callback, say)
    if setup.targets.kind == "normals" and rec.genus_ok:
        rec = _topology_checked(rec, setup, say)
    if not last:
        finest = min((r["factor"] for r in rec.history.resolution), default=1)
        mesh, albedo = finish(rec.mesh, rec.albedo, finest)
        if mesh is not rec.mesh:
            rec = _as_written(dataclasses.replace(rec, mesh=mesh, albedo=albedo), setup, say)
    return dataclasses.replace(rec, history=dataclasses.replace(
        rec.history, seconds=time.perf_counter() - t0 - waited[0], faces=int(rec.mesh.n_faces)))


def _as_written(rec: Reconstruction, setup: Setup, say: Callable[[str], None]) -> Reconstruction:
    """`rec` judged again on its mesh as written, changed after the fit's verdict (`judged_as_written`)."""
    t0, frame, h = time.perf_counter(), setup.frame, rec.history
    v, f = rec.mesh.to_numpy()
    mesh = Mesh.from_numpy(((np.asarray(v, np.float64) - frame.centre) / frame.scale).astype(np.float32), f)
    appearance = photos = None
    if rec.albedo is not None:
        albedo = np.zeros((mesh.vertex_capacity, 3), np.float32)
        albedo[: len(rec.albedo)] = rec.albedo
        appearance, photos = (albedo, rec.lighting), setup.images
    evidence = Evidence(mesh, mesh, setup.cams, setup.targets, h.steps, h.cycles, rec.genus_ok, appearance, photos,
                        carved_start=h.start.startswith("visual_hull"), held=setup.held,
                        start_iou=list(h.start_silhouette_iou))
    history, verdict = judged_as_written(h, evidence, rec.options)
    say(f"verdict on the mesh written ({int(mesh.n_faces)} faces): {'ok' if history.ok else 'NOT OK'}; silhouette IoU "
        f"min {min(verdict.silhouette_iou):.3f}, mean {np.mean(verdict.silhouette_iou):.3f} "
        f"({time.perf_counter() - t0:.0f}s)")
    return dataclasses.replace(rec, history=history)


def _timed(callback: Callable, waited: list[float]) -> Callable:
    """`callback` adding the seconds it takes to `waited[0]` (the run's time leaves them out)."""
    def timed(*args):
        t = time.perf_counter()
        try:
            return callback(*args)
        finally:
            waited[0] += time.perf_counter() - t
    return timed


def _topology_checked(rec: Reconstruction, setup: Setup, say: Callable[[str], None]) -> Reconstruction:
    """`rec`, not ok when its normal images show holes it does not have (`pipeline._start_stage.holes_not_had`)."""
    t0, frame = time.perf_counter(), setup.frame
    v, f = rec.mesh.to_numpy()
    v = (np.asarray(v, np.float64) - frame.centre) / frame.scale
    try:
        tests = hole_tests(v, f, *evidence_level(setup), max_tries=CHECK_TRIES, min_radius=evidence_pixel(setup),
                           free_space=False)
    except ValueError:  # not a manifold solid to cut: nothing to test
        return rec
    why = holes_not_had(tests, rec.genus, lambda p: p * frame.scale + frame.centre)
    say(f"topology: {why or 'no cut at the strongest disagreements lowers the image loss'} "
        f"({len(tests.tested)} tested, {time.perf_counter() - t0:.0f}s)")
    if not why:
        return rec
    return dataclasses.replace(rec, history=dataclasses.replace(rec.history, ok=False,
                                                                warnings=rec.history.warnings + [why]))


def _finishing(setup: Setup, cams: Cameras, say: Callable[[str], None]) -> Callable:
    """The stages after the fit as `finish(mesh, albedo, finest) -> (mesh, albedo)` (the user's frame;
    `finest`: the finest level fitted, 1/`finest` of the images' size): photos' unseen surface
    (`fill_unseen`), a subdivision where the mesh is coarser than the images (`subdivide`), the
    outline and, for photos, the depth at the images' own size (`_at_full_size`). The mesh
    returned is the one the run writes; it is the input itself when no stage changed it."""
    def finish(mesh: Mesh, albedo, finest: int):
        heap_returned()
        if setup.options.fill_unseen and setup.targets.kind == "photo":
            mesh = _filled(mesh, cams, say)
        if setup.options.subdivide:
            mesh, albedo = _subdivided_if_coarse(mesh, albedo, cams, say)
        return _at_full_size(mesh, albedo, finest, setup, say)
    return finish


def _filled(mesh: Mesh, cams: Cameras, say: Callable[[str], None]) -> Mesh:
    """`mesh` with the surface no camera sees on the membrane around it (`ReconstructOptions.fill_unseen`)."""
    v, f = mesh.to_numpy()
    fill = fill_unseen((v, f), cams)
    n = int(fill.moved.sum())
    if n == 0:
        say("unseen surface: every vertex in some camera's frame is seen by one (ReconstructOptions.fill_unseen)")
        return mesh
    scale = float(np.linalg.norm(np.ptp(v, axis=0)))
    say(f"unseen surface: {n} of {len(v)} vertices ({100 * n / len(v):.0f}%) no camera sees moved onto the "
        f"membrane the seen surface spans, median {np.median(fill.distance[fill.moved]) / scale:.3f} and at most "
        f"{fill.distance.max() / scale:.3f} of the mesh's diagonal (ReconstructOptions.fill_unseen=False: off)")
    return Mesh.from_numpy(fill.vertices.astype(v.dtype), f)


def _subdivided(mesh: Mesh, albedo, say: Callable[[str], None], why: str):
    """`(mesh, albedo)` through one Phong subdivision (`ReconstructOptions.subdivide`)."""
    sub = phong_subdivision(mesh, values=albedo)
    say(f"subdivided: {int(mesh.n_faces)} -> {int(sub.mesh.n_faces)} faces, {why}")
    return sub.mesh, sub.values


def _subdivided_if_coarse(mesh: Mesh, albedo, cams: Cameras, say: Callable[[str], None]):
    """`(mesh, albedo)` through one Phong subdivision when the median edge is longer than
    `SUBDIVIDE_EDGE_PX` at the images' own size (`ReconstructOptions.subdivide`), else as fitted (said)."""
    v, f = mesh.to_numpy()
    px = _median_edge_px(np.asarray(v, np.float64), np.asarray(f), cams)
    if px <= SUBDIVIDE_EDGE_PX:
        say(f"not subdivided: the median edge is {px:.1f} px at {cams.width}x{cams.height}, as fine as the images "
            f"resolve ({SUBDIVIDE_EDGE_PX:g} px or less)")
        return mesh, albedo
    return _subdivided(mesh, albedo, say, f"the median edge {px:.1f} px at {cams.width}x{cams.height}; the new vertices "
                                          "on the smooth surface through the fitted ones (Phong; "
                                          "ReconstructOptions.subdivide=False: off)")


def _median_edge_px(v: np.ndarray, f: np.ndarray, cams: Cameras) -> float:
    """The median edge length of mesh `(v, f)` in pixels of the images' own size, each edge seen from
    the nearest camera centre (the mean focal length)."""
    e = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    mid = 0.5 * (v[e[:, 0]] + v[e[:, 1]])
    near = np.full(len(e), np.inf)
    for c in np.asarray(cams.centers, np.float64):
        near = np.minimum(near, np.linalg.norm(mid - c, axis=1))
    length = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
    return float(np.median(length / np.maximum(near, 1e-12)) * np.mean(np.asarray(cams.focal)))


def _at_full_size(mesh: Mesh, albedo, finest: int, setup: Setup, say: Callable[[str], None]):
    """`(mesh, albedo)` with the outline on the masks at their own size (`ReconstructOptions.fit_outline`) and,
    for photos, its surface where the photos at their own size agree (`fit_photo_depth`), where the
    finest level fitted was coarser than the images. With the views split over processes each
    process works with its own views and the moves are summed over them (the same mesh in each)."""
    opts = setup.options
    depth = opts.fit_photo_depth and setup.targets.kind == "photo"
    split = setup.held is not None and len(setup.held) < len(setup.cams)  # this process holds only some views
    if finest <= 1 or not (opts.fit_outline or depth):
        return mesh, albedo
    cams, fixed = setup.world_cams, None
    v, f = mesh.to_numpy()
    if opts.fit_outline:
        # the fit placed its outline to about a pixel of the size it fitted: look that far (and a bit) past the edges
        here = cams if setup.held is None else cams[setup.held]  # split: each process its views, the moves summed
        out = fit_outline((v, f), here, setup.targets.alpha, band=max(3.0, 1.25 * finest),
                          total=summed_over_processes if split else None)
        say(f"outline: {int(out.moved.sum())} vertices moved onto the masks at {cams.width}x{cams.height} (fitted "
            f"at 1/{finest}), {out.before:.2f} -> {out.after:.2f} px off their edges on average "
            "(ReconstructOptions.fit_outline=False: off)")
        v, fixed = out.vertices.astype(v.dtype), out.moved
    if depth:
        t0 = time.perf_counter()
        fitted = fit_photo_depth((v, f), cams, setup.images, fixed=fixed, held=setup.held if split else None,
                                 total=summed_over_processes if split else None)
        n = int(fitted.measured.sum())
        if n == 0:
            say("photo depth: WARNING no vertex had texture and neighbouring views to measure its depth at "
                f"{cams.width}x{cams.height} (ReconstructOptions.fit_photo_depth)")
        else:
            say(f"photo depth: the surface moved along its normals to where the photos agree at {cams.width}x"
                f"{cams.height}: {n} of {len(v)} vertices measured, best offset {fitted.offset_px[0]:.2f} -> "
                f"{fitted.offset_px[-1]:.2f} px over {len(fitted.offset_px)} sweeps, patch NCC "
                f"{fitted.ncc_before[0]:.3f} as fitted, {fitted.ncc_after[-1]:.3f} at the last sweep's best offsets "
                f"({time.perf_counter() - t0:.0f}s; ReconstructOptions.fit_photo_depth=False: off)")
        v = fitted.vertices.astype(v.dtype)
    return Mesh.from_numpy(v, f), albedo
