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
from jaxgenus.pipeline._fit import FitIndex, estimate_warnings, fit
from jaxgenus.pipeline._handles import HoleTests, hole_tests
from jaxgenus.pipeline._history import GenusEstimate, HandleRecord, History, Reconstruction
from jaxgenus.pipeline._options import ReconstructOptions
from jaxgenus.pipeline._setup import Setup, prepare
from jaxgenus.pipeline._start import Start, remeshed_start
from jaxgenus.pipeline._start_stage import (CHECK_TRIES, estimate_line, evidence_level, evidence_pixel,
                                             first_edge_length, first_start,
                                             holes_not_had, image_handle_records, images_estimate, refit_start)

_DEPTH_MAX_FACES = 1 << 20
#: The result is subdivided only where its median edge is longer than this many pixels at the images'
#: own size: a finer mesh holds no detail the images show (a 64-px torus stays at the faces it was fitted with).
SUBDIVIDE_EDGE_PX = 2.0

__all__ = ["genus_estimate", "reconstruct"]

# A refit that lowers the mean normal error by less than this share of it predicts a next
# one that gains nothing (docs/results.md, "Default refits"). Default refits only.
_MIN_REFIT_GAIN = 0.03


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
    setup = prepare(images, cams, None, targets, options, say, views, region)
    if not _reads_interior(setup, None):
        return setup.estimate
    t0 = time.perf_counter()
    key = jax.random.key(0) if key is None else key
    setup, _, rec = _first_fit(images, cams, setup, key, FitIndex(0, 1), t0, None, say, views, region)
    return _with_holes(setup, rec, key, FitIndex(0, 1), t0, None, say, estimate_only=True)[0].estimate


def _reads_interior(setup: Setup, genus) -> bool:
    """Whether a run estimates the genus from the images' interior too (normal maps, no genus given)."""
    return (genus is None and setup.targets.kind == "normals" and setup.options.hidden_handles == "images"
            and setup.options.start != "sphere")


def _first_fit(images, cams, setup: Setup, key, index: FitIndex, t0: float, callback, say, views, region):
    """`(setup, start, rec)`: the first fit of a run, from its first start."""
    def fit_genus(g: int) -> Reconstruction:  # the same images at another genus (hidden handles)
        return reconstruct(images, cams, g, targets=setup.targets.kind,
                           options=dataclasses.replace(setup.options, hidden_handles="drill", refits=0, subdivide=False,
                                                       fit_outline=False, fit_photo_depth=False),
                           key=key, views=views, region=region)

    start = first_start(setup, fit_genus, say)
    say(_start_line(start, setup.genus, time.perf_counter() - t0))
    return setup, start, fit(setup, start, setup.options, key, index, t0=t0, callback=callback, say=say)


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
        tests = hole_tests(v, f, *evidence_level(setup), min_radius=evidence_pixel(setup))
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
    say(_start_line(start, setup.genus, time.perf_counter() - t0))
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
            `(n + 1) / 2` (what `render_targets` produces) or a photo.
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
    setup = prepare(images, cams, genus, targets, options, say, views, region)
    n_refits = options.refit_count(setup.cams.height, setup.cams.width, setup.targets.kind)
    index = FitIndex(0, 1 + n_refits)

    setup, start, rec = _first_fit(images, cams, setup, key, index, t0, callback, say, views, region)
    if _reads_interior(setup, genus):
        setup, rec = _with_holes(setup, rec, key, index, t0, callback, say)
    if n_refits and rec.genus_ok:
        rec = _refits(rec, setup, options, n_refits, key, callback, say)
    if setup.targets.kind == "normals" and rec.genus_ok:
        rec = _topology_checked(rec, setup, say)
    if setup.options.fill_unseen and setup.targets.kind == "photo":
        rec = _filled(rec, cams, say)
    rec = _subdivided_if_coarse(rec, cams, say) if setup.options.subdivide else rec
    rec = _at_full_size(rec, setup, say)
    return dataclasses.replace(rec, history=dataclasses.replace(
        rec.history, seconds=time.perf_counter() - t0 - waited[0], faces=int(rec.mesh.n_faces)))


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
        tests = hole_tests(v, f, *evidence_level(setup), max_tries=CHECK_TRIES, min_radius=evidence_pixel(setup))
    except ValueError:  # not a manifold solid to cut: nothing to test
        return rec
    why = holes_not_had(tests, rec.genus, lambda p: p * frame.scale + frame.centre)
    say(f"topology: {why or 'no cut at the strongest disagreements lowers the image loss'} "
        f"({len(tests.tested)} tested, {time.perf_counter() - t0:.0f}s)")
    if not why:
        return rec
    return dataclasses.replace(rec, history=dataclasses.replace(rec.history, ok=False,
                                                                warnings=rec.history.warnings + [why]))


def _filled(rec: Reconstruction, cams: Cameras, say: Callable[[str], None]) -> Reconstruction:
    """`rec` with the surface no camera sees on the membrane around it (`ReconstructOptions.fill_unseen`)."""
    v, f = rec.mesh.to_numpy()
    fill = fill_unseen((v, f), cams)
    n = int(fill.moved.sum())
    if n == 0:
        say("unseen surface: every vertex in some camera's frame is seen by one (ReconstructOptions.fill_unseen)")
        return rec
    scale = float(np.linalg.norm(np.ptp(v, axis=0)))
    say(f"unseen surface: {n} of {len(v)} vertices ({100 * n / len(v):.0f}%) no camera sees moved onto the "
        f"membrane the seen surface spans, median {np.median(fill.distance[fill.moved]) / scale:.3f} and at most "
        f"{fill.distance.max() / scale:.3f} of the mesh's diagonal (ReconstructOptions.fill_unseen=False: off)")
    return dataclasses.replace(rec, mesh=Mesh.from_numpy(fill.vertices.astype(v.dtype), f))


def _subdivided(rec: Reconstruction, say: Callable[[str], None],
                why: str = "the new vertices on the smooth surface through the fitted ones (Phong; "
                           "ReconstructOptions.subdivide=False: off)") -> Reconstruction:
    """`rec` with its mesh (and albedo) through one Phong subdivision (`ReconstructOptions.subdivide`)."""
    sub = phong_subdivision(rec.mesh, values=rec.albedo)
    say(f"subdivided: {int(rec.mesh.n_faces)} -> {int(sub.mesh.n_faces)} faces, {why}")
    return dataclasses.replace(rec, mesh=sub.mesh, albedo=sub.values)


def _subdivided_if_coarse(rec: Reconstruction, cams: Cameras, say: Callable[[str], None]) -> Reconstruction:
    """`rec` through one Phong subdivision when its median edge is longer than `SUBDIVIDE_EDGE_PX` at
    the images' own size (`ReconstructOptions.subdivide`), else as fitted (said)."""
    v, f = rec.mesh.to_numpy()
    px = _median_edge_px(np.asarray(v, np.float64), np.asarray(f), cams)
    if px <= SUBDIVIDE_EDGE_PX:
        say(f"not subdivided: the median edge is {px:.1f} px at {cams.width}x{cams.height}, as fine as the images "
            f"resolve ({SUBDIVIDE_EDGE_PX:g} px or less)")
        return rec
    return _subdivided(rec, say, f"the median edge {px:.1f} px at {cams.width}x{cams.height}; the new vertices on the "
                                 f"smooth surface through the fitted ones (Phong; ReconstructOptions.subdivide=False: off)")


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


def _finer_for_photos(rec: Reconstruction, cams: Cameras, edge_px: float, say: Callable[[str], None]) -> Reconstruction:
    """`rec` through Phong subdivisions while its median edge is longer than `edge_px` pixels at the
    images' own size, up to `_DEPTH_MAX_FACES` faces (`ReconstructOptions.depth_edge_px`)."""
    while True:
        v, f = rec.mesh.to_numpy()
        px = _median_edge_px(np.asarray(v, np.float64), np.asarray(f), cams)
        if px <= edge_px or 4 * len(f) > _DEPTH_MAX_FACES:
            return rec
        rec = _subdivided(rec, say, f"for the photos' detail: the median edge {px:.1f} px at {cams.width}x"
                                    f"{cams.height} (more than {edge_px:g}; ReconstructOptions.depth_edge_px=0: off)")


def _at_full_size(rec: Reconstruction, setup: Setup, say: Callable[[str], None]) -> Reconstruction:
    """`rec` with its outline on the masks at their own size (`ReconstructOptions.fit_outline`) and,
    for photos, its surface where the photos at their own size agree (`fit_photo_depth`), where the
    finest level fitted was coarser than the images."""
    opts = setup.options
    finest = min((r["factor"] for r in rec.history.resolution), default=1)
    depth = opts.fit_photo_depth and setup.targets.kind == "photo"
    if finest <= 1 or not (opts.fit_outline or depth):
        return rec
    if setup.held is not None:
        say("outline and depth: not refined at the images' own size with the views split over processes")
        return rec
    cams, fixed = setup.world_cams, None
    if depth and opts.depth_edge_px > 0:
        rec = _finer_for_photos(rec, cams, opts.depth_edge_px, say)
    v, f = rec.mesh.to_numpy()
    if opts.fit_outline:
        # the fit placed its outline to about a pixel of the size it fitted: look that far (and a bit) past the edges
        out = fit_outline((v, f), cams, setup.targets.alpha, band=max(3.0, 1.25 * finest))
        say(f"outline: {int(out.moved.sum())} vertices moved onto the masks at {cams.width}x{cams.height} (fitted "
            f"at 1/{finest}), {out.before:.2f} -> {out.after:.2f} px off their edges on average "
            "(ReconstructOptions.fit_outline=False: off)")
        v, fixed = out.vertices.astype(v.dtype), out.moved
    if depth:
        t0 = time.perf_counter()
        fitted = fit_photo_depth((v, f), cams, setup.targets.fit, fixed=fixed)
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
    return dataclasses.replace(rec, mesh=Mesh.from_numpy(v, f))


def _start_line(start: Start, genus: int, seconds: float) -> str:
    return (f"start: {start.kind} of genus {genus}, {int(start.mesh.n_faces)} faces"
            + (f", {start.tunnels} handles drilled (the silhouettes show fewer)" if start.tunnels else "")
            + f" ({seconds:.1f}s)")


def _start_of(rec: Reconstruction) -> Start:
    """The record of the start a fit made (its mesh is replaced by a refit's)."""
    h = rec.history
    return Start(rec.mesh, h.start, h.hull_grid, h.tunnels, h.handles)


def _refits(rec: Reconstruction, setup: Setup, options: ReconstructOptions, n: int, key, callback,
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
        step(_start_line(start, setup.genus, time.perf_counter() - t0 - rec.history.seconds))
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
