"""The verdict of a run: does the result match its images?

After the last cycle the result is rendered in every view and compared with
the targets: the per-view silhouette IoU (rendered alpha >= 0.5 against target
alpha >= 0.5), and the per-view mean angle between rendered and target normals
where the targets are normal maps. The start mesh is scored the same way.

A run is **not ok** (`ok = False`) when any of these holds, each with a warning:

* the result's genus differs from the requested one;
* the loss diverged: a non-finite step, or a loss that ends a cycle above 1.5x where the
  cycle began (and, except for photos, whose finer levels show more texture, a final loss
  above 1.5x the first);
* a view's silhouette IoU is under `min_iou` (a result that does not cover its
  silhouettes, or silhouettes that disagree with each other);
* a view disagrees with the rest: its IoU is `outlier_gap` below the median of
  the views (a mislabelled or miscalibrated view);
* the result matches its silhouettes worse than the start did (mean IoU lower
  by more than 0.01; 0.03 when the start is the visual hull of the same
  silhouettes, which fits them by construction: `START_TOLERANCE`).

* photo targets fitted with photo-consistency: the photos agree less on the result than on
  the start in some views (the residual, mean `1 - NCC` against a neighbour through the
  mesh's depth, `consistency_residuals`, above the start's by more than
  `CONSISTENCY_TOLERANCE`); those views are named. The geometry is judged by this residual
  and the silhouettes, not by how well one Lambertian light explains the photos;
* other photo targets (no photo-consistency, or no view with texture and a neighbour): the
  median over the views of the photometric error (mean absolute RGB difference of the
  result's render, with its albedo and lighting, against the photo where both cover the
  pixel) is above `max_photo_error`: the shading model does not explain the photos. With
  photo-consistency measured, that is a warning (specular or unevenly lit photos).

Warnings that do not make a run fail: faces inverted at the last step, faces
the rasterizer dropped or truncated, remeshes that hit the face budget (the mesh
is coarser than asked), photo views whose error is far above the others'
(a change of exposure or light between views?), views where photo-consistency had nothing
to work with (no texture, no neighbour).

The mesh a run returns is judged: when stages after the fit change it, `judged_as_written`
scores it again and adds what it fails.

Photo targets fitted with photo-consistency also get its residual per view
(`consistency_residuals`) in `photo_consistency`, and the start's in `start_photo_consistency`.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgenus.capture import Targets, unit_float
from jaxgenus.geometry import Cameras, Mesh
from jaxgenus.optim import consistency_windows, gathered_views
from jaxgenus.pipeline._history import History
from jaxgenus.pipeline._options import ReconstructOptions
from jaxgenus.rendering import plan_render, render, shading_colors

__all__ = ["Evidence", "Verdict", "ViewScores", "consistency_residuals", "judge", "judged_as_written", "photo_errors",
           "silhouette_ious", "view_scores"]


class Verdict(NamedTuple):
    """Per-view scores and the verdict (see the module doc)."""

    silhouette_iou: list[float]
    start_silhouette_iou: list[float]
    normal_error_deg: list[float] | None
    ok: bool
    warnings: list[str]
    photo_error: list[float] | None = None
    photo_consistency: list[float] | None = None
    start_photo_consistency: list[float] | None = None


#: How far a view's photo-consistency residual (mean `1 - NCC`, in [0, 1]) may rise above the start's
#: before the verdict fails: the fit lowers it where the photos have texture; a result the photos agree
#: on less than on the visual hull it started from has moved its surface where they do not show it.
CONSISTENCY_TOLERANCE = 0.05


#: Pixels rendered at once by the verdict: views go through the renderer in chunks of at most
#: this many pixels (one view, or a band of rows of one view where a view holds more), so its memory
#: grows with neither the number of views nor their size. The renderer holds about 150 bytes a pixel
#: while it runs on the CPU (chunks of four DTU views of 1600x1200 raised a run's peak by 1.2 GB);
#: the photo-consistency residual renders two views a view and compares windows of both: chunks of
#: 2^21 pixels (17 views of 400x300) raised the peak by 0.9 GB, of 2^19 by 0.3 GB; it takes 2^17.
CHUNK_PIXELS = 1 << 19


def _chunks(cams: Cameras, pixels: int | None = None) -> list[tuple[np.ndarray, int]]:
    """`(views, n)` per chunk of at most `pixels` (`CHUNK_PIXELS`) but one view, all chunks of one size: the
    last one is padded by repeating its last view, of which only the first `n` count, so every chunk
    runs one compiled program."""
    size = min(len(cams), max(1, (pixels or CHUNK_PIXELS) // (cams.height * cams.width)))
    return [(np.minimum(np.arange(i, i + size), len(cams) - 1), min(size, len(cams) - i))
            for i in range(0, len(cams), size)]


def _band_rows(cams: Cameras, plan) -> int:
    """The rows `view_scores` renders at once: a view's, or where it holds more than `CHUNK_PIXELS`
    and the CPU's kernel renders (no `plan`: its memory goes with the pixels), fewer. The JAX splat's
    memory goes with the faces each view draws, whatever its rows: it renders whole views."""
    return cams.height if plan is not None else min(cams.height, max(1, CHUNK_PIXELS // cams.width))


def _pieces(cams: Cameras, band: int) -> list[tuple[np.ndarray, int, int, int, int]]:
    """What `view_scores` renders at once, `(views, n, top, first, rows)`: rows `top ...` of `views`
    (`top + first ...` of them count, `rows` of them, of the first `n` views). Views of at most
    `band` rows go in chunks of whole views (`_chunks`); taller ones a band of rows at a time, all
    bands as tall (the last one moved up to end at the image's last row), so one program renders all."""
    h = cams.height
    if band >= h:
        return [(idx, n, 0, 0, h) for idx, n in _chunks(cams)]
    return [(np.array([i]), 1, min(r, h - band), r - min(r, h - band), min(band, h - r))
            for i in range(len(cams)) for r in range(0, h, band)]


def _band(cams: Cameras, top: int, rows: int) -> Cameras:
    """`cams` seeing rows `top ... top + rows` of their images (all rows when `rows` is the height)."""
    if top == 0 and rows == cams.height:
        return cams
    shift = jnp.asarray([0.0, top], cams.principal_point.dtype)
    return Cameras(cams.rotation, cams.translation, cams.focal, cams.principal_point - shift, rows, cams.width)


def _plan(mesh: Mesh, cams: Cameras, sigma: float):
    """One raster plan for all of `cams` (None on the CPU: its native kernel needs none). A plan made
    per chunk differs from chunk to chunk, and each would compile a program of its own (on an H200,
    DTU scan24 at full size: 86 s of verdict, nearly all compiling)."""
    return None if jax.default_backend() == "cpu" else plan_render(mesh, cams, sigma=sigma)


class ViewScores(NamedTuple):
    """Per view: the silhouette IoU, and where asked the mean normal angle (degrees) and the photometric error."""

    silhouette_iou: list[float]
    normal_error_deg: list[float] | None
    photo_error: list[float] | None


def view_scores(mesh: Mesh, cams: Cameras, alpha: np.ndarray, *, sigma: float, normals=None, photos=None,
                appearance=None, shading: str = "flat") -> ViewScores:
    """Per view, from renders of `mesh` of at most `CHUNK_PIXELS` (`_pieces`): the IoU of the rendered silhouette with
    `alpha (N, H, W)` (both at 0.5); with `normals (N, H, W, 3)` the mean angle (degrees) between rendered
    and target normals over the pixels both cover (NaN where none); with `photos (N, H, W, 4)` (straight;
    uint8 / uint16 as `unit_float` reads them) and `appearance = (albedo, lighting)` the mean absolute RGB
    difference of `render_photo` against them over the pixels both cover at alpha 0.5 (NaN where none)."""
    photo = photos is not None and appearance is not None
    channels = ("alpha",) + (("normal",) if normals is not None else ()) + (("color",) if photo else ())
    kw = shading_colors(mesh, *appearance, shading) if photo else {}
    plan = _plan(mesh, cams, sigma)
    tall = _band_rows(cams, plan)
    sums = np.zeros((len(cams), 6))  # per view: intersection, union, angle sum, count, error sum, count
    for idx, n, top, first, rows in _pieces(cams, tall):
        img = np.asarray(render(mesh, _band(cams[idx], top, tall), channels=channels, sigma=sigma, plan=plan,
                                **kw))[:n, first:first + rows]
        at = slice(top + first, top + first + rows)
        for k, i in enumerate(idx[:n]):
            mine, theirs = img[k, ..., 0] >= 0.5, np.asarray(alpha[i, at]) >= 0.5
            sums[i, :2] += (mine & theirs).sum(), (mine | theirs).sum()
            if normals is not None:
                both = mine & theirs
                m = img[k, ..., 1:4][both].astype(np.float64)
                t = np.asarray(normals[i, at], np.float64)[both]
                m = m / np.maximum(np.linalg.norm(m, axis=-1, keepdims=True), 1e-12)
                t = t / np.maximum(np.linalg.norm(t, axis=-1, keepdims=True), 1e-12)
                sums[i, 2:4] += np.degrees(np.arccos(np.clip(np.sum(m * t, axis=-1), -1.0, 1.0))).sum(), both.sum()
            if photo:
                target = unit_float(photos[i, at])
                both = mine & (target[..., 3] >= 0.5)
                rgb = img[k, ..., -3:][both].astype(np.float64) / np.maximum(img[k, ..., 0][both][:, None], 1e-6)
                sums[i, 4:6] += np.abs(rgb - target[both][:, :3].astype(np.float64)).mean(axis=-1).sum(), both.sum()
    mean = lambda a, b: np.where(b > 0, a / np.maximum(b, 1), np.nan).tolist()  # noqa: E731
    return ViewScores(np.where(sums[:, 1] > 0, sums[:, 0] / np.maximum(sums[:, 1], 1), 1.0).tolist(),
                      mean(sums[:, 2], sums[:, 3]) if normals is not None else None,
                      mean(sums[:, 4], sums[:, 5]) if photo else None)


def silhouette_ious(mesh: Mesh, cams: Cameras, alpha: np.ndarray, *, sigma: float, normals=None):
    """`(ious, normal errors or None)` of `view_scores`."""
    return view_scores(mesh, cams, alpha, sigma=sigma, normals=normals)[:2]


def photo_errors(mesh: Mesh, cams: Cameras, photos: np.ndarray, albedo, lighting, *, sigma: float,
                 shading: str = "flat") -> list[float]:
    """The photometric error per view of `view_scores` (`photos (N, H, W, 4)` straight RGBA, alpha their mask)."""
    return view_scores(mesh, cams, np.asarray(photos)[..., 3], sigma=sigma, photos=photos, appearance=(albedo, lighting),
                       shading=shading).photo_error


def consistency_residuals(mesh: Mesh, cams: Cameras, photos: np.ndarray, table: np.ndarray, *,
                          sigma: float) -> list[float]:
    """Per view, the photo-consistency residual of `mesh` (mean `1 - NCC` over the textured windows,
    `jaxgenus.optim.consistency_windows`) against its first neighbour in `table`, photos `(N, H, W, 4)`
    straight RGBA; NaN where no window had texture or a neighbour. Views are rendered in chunks, each
    chunk one compiled program (renders and windows)."""
    out, plan = [], _plan(mesh, cams, sigma)
    windows = jax.jit(_windows, static_argnames=("sigma", "plan"))
    for idx, n in _chunks(cams, CHUNK_PIXELS // 4):  # two renders a view and the windows' sums of both
        nb = table[idx, 0]
        ref = np.asarray(photos[idx], np.float32)
        near = np.asarray(photos[nb], np.float32)
        ref[..., :3] *= ref[..., 3:]
        near[..., :3] *= near[..., 3:]
        ncc, w = windows(mesh, cams[idx], ref, cams[nb], near, sigma=sigma, plan=plan)
        ncc, w = np.asarray(ncc, np.float64), np.asarray(w, np.float64)
        for k, i in enumerate(idx[:n]):
            m = w[k].sum()
            out.append(float((w[k] * np.minimum(1.0 - ncc[k], 1.0)).sum() / m) if m > 0 and nb[k] != i else float("nan"))
    return out


def _windows(mesh, ref_cams, ref, nb_cams, near, *, sigma, plan):
    r = render(mesh, ref_cams, channels=("alpha", "depth"), sigma=sigma, plan=plan)
    d = render(mesh, nb_cams, channels=("depth", "alpha"), sigma=sigma, plan=plan)
    return consistency_windows(r[..., 1], r[..., 0], ref_cams, ref, nb_cams, near, d)


@dataclasses.dataclass(frozen=True)
class Evidence:
    """What the verdict compares (canonical frame).

    Attributes:
        result, start: the fitted mesh and the mesh the fit started from.
        cams: the cameras (canonical frame); targets: the run's `Targets`.
        steps: the per-step arrays of the fit (`loss`, `status`, `inverted_faces`, ...).
        cycles: the fit's `CycleRecord`s.
        genus_ok: the result has the requested genus.
        appearance: photo targets: `(albedo, lighting)` of the result, else None.
        photos: photo targets: the straight RGBA photos, else None.
        consistency: photo targets with photo-consistency: `(cameras, photos, neighbours)` of the
            finest level fitted (straight RGBA), for the residual per view; else None.
        carved_start: the start was carved from these very silhouettes (a visual hull), so it
            matches them by construction, sharp corners and all: a smooth result may trail it
            by a little and still fit (`START_TOLERANCE`).
        held: the views `targets` and `photos` hold when this process holds only some
            (indices into `cams`); each process scores its own and the scores are put together.
        start_iou: the start's per-view silhouette IoU when scored before (None: `start` is scored).
    """

    result: Mesh
    start: Mesh
    cams: Cameras
    targets: Targets
    steps: dict
    cycles: tuple
    genus_ok: bool
    appearance: tuple | None = None
    photos: np.ndarray | None = None
    carved_start: bool = False
    consistency: tuple | None = None
    held: np.ndarray | None = None
    start_iou: list[float] | None = None


#: How far (mean silhouette IoU) a result may trail its start before the verdict fails: a
#: start carved from the same silhouettes (a visual hull) fits them by construction, so a
#: smooth fit trails it (16 torus masks at 96²: hull 0.994, a good fit 0.984).
START_TOLERANCE = {"carved": 0.03, "other": 0.01}


def _loss_rise(loss: np.ndarray, time: np.ndarray, *, whole: bool) -> str:
    """Where the loss ended above 1.5x where it began ("" where nowhere): within a cycle (the mean of
    its last steps against its first, a fifth of them up to 10, over the views each samples), and
    with `whole` over the run (its last step against its first). Photo targets check only within
    cycles: a finer level shows texture a coarser one averaged away, so their loss grows between
    levels when all is well."""
    ends = np.flatnonzero(np.isfinite(time))
    if len(ends) == 0 or ends[-1] != len(loss) - 1:
        ends = np.append(ends, len(loss) - 1)
    start = 0
    for c, end in enumerate(ends):
        part = loss[start:end + 1]
        k = max(1, min(10, len(part) // 5))
        first, last = float(np.mean(part[:k])), float(np.mean(part[-k:]))
        if np.isfinite(first) and last > 1.5 * first:
            return f"{first:.4g} over the first steps of cycle {c}, {last:.4g} over its last"
        start = end + 1
    if whole and np.isfinite(loss[0]) and loss[-1] > 1.5 * loss[0]:
        return f"{loss[0]:.4g} at the first step, {loss[-1]:.4g} at the last"
    return ""


def judge(evidence: Evidence, options: ReconstructOptions, *, consistency_measured: bool = False) -> Verdict:
    """Score the result and the start against the targets and decide (see the module doc), with the
    thresholds of `options` (`min_view_iou`, `outlier_gap`, `max_photo_error`) and its renderer's `sigma`.
    `consistency_measured`: the fit's geometry was judged by photo-consistency (the photometric error
    only warns) although `evidence` holds none to score again (a mesh changed after the fit)."""
    e, sigma = evidence, options.render.sigma
    result, start, cams, targets, steps, cycles = e.result, e.start, e.cams, e.targets, e.steps, e.cycles
    min_iou, outlier_gap, max_photo_error = options.min_view_iou, options.outlier_gap, options.max_photo_error
    here = cams if e.held is None else cams[e.held]  # a process scores the views it holds

    def every(scores):  # a per-view list with the other processes' views
        return None if scores is None else gathered_views(np.asarray(scores, np.float64), e.held, len(cams)).tolist()

    photo = e.appearance is not None
    scores = view_scores(result, here, targets.alpha, sigma=sigma, normals=targets.normals, photos=e.photos if photo else None,
                         appearance=e.appearance, shading=options.render.shading)
    iou, nerr = every(scores.silhouette_iou), every(scores.normal_error_deg)
    start_iou = e.start_iou if e.start_iou is not None else every(silhouette_ious(start, here, targets.alpha,
                                                                                 sigma=sigma)[0])
    fail, warn = [], []
    if not e.genus_ok:
        fail.append("the result's genus is not the requested one")
    loss = np.asarray(steps["loss"])
    bad_steps = int(np.sum(np.asarray(steps["status"]) == 2))
    if bad_steps:
        fail.append(f"the loss diverged: {bad_steps} non-finite steps were skipped")
    rise = _loss_rise(loss, np.asarray(steps.get("time", np.full(len(loss), np.nan))), whole=targets.kind != "photo")
    if rise:
        fail.append(f"the loss diverged: {rise}")
    low = [i for i, x in enumerate(iou) if x < min_iou]
    if low:
        fail.append(f"silhouette IoU under {min_iou} in views {low} (min {min(iou):.3f}): the result does not "
                    "match those images, or they disagree with the others")
    med = float(np.median(iou))
    odd = [i for i, x in enumerate(iou) if x < med - outlier_gap]
    if odd:
        fail.append(f"views {odd} disagree with the rest (IoU {', '.join(f'{iou[i]:.3f}' for i in odd)} against "
                    f"a median of {med:.3f}): mislabelled or miscalibrated?")
    if np.mean(iou) < np.mean(start_iou) - START_TOLERANCE["carved" if e.carved_start else "other"]:
        fail.append(f"the result matches its silhouettes worse than the start (mean IoU {np.mean(iou):.3f} < "
                    f"{np.mean(start_iou):.3f})")
    inverted = int(np.asarray(steps["inverted_faces"])[-1])
    if inverted:
        warn.append(f"{inverted} faces inverted at the last step")
    if cycles and cycles[-1].truncated_faces:
        warn.append(f"the rasterizer drew {cycles[-1].truncated_faces} faces incompletely at the end (dropped or "
                    "truncated): raise its budget or lower max_faces")
    hits = [c.cycle for c in cycles if c.remesh_status == "CAPACITY_EXCEEDED"]
    if hits:
        warn.append(f"remeshes after cycles {hits} hit the face budget (edges longer than the images resolve; "
                    "raise max_faces for more detail)")
    pcon = start_pcon = None
    if e.consistency is not None:
        pcon = consistency_residuals(result, *e.consistency, sigma=sigma)
        start_pcon = consistency_residuals(start, *e.consistency, sigma=sigma)
        blank = [i for i, r in enumerate(pcon) if not np.isfinite(r)]
        if blank:
            warn.append(f"photo-consistency had nothing to work with in {len(blank)} of {len(pcon)} views (no texture "
                        f"or no neighbour 5-60 degrees away): views {blank[:10]}{' ...' if len(blank) > 10 else ''}; "
                        "their inside is shaped by the silhouettes and the shading alone")
        worse = [i for i, (r, r0) in enumerate(zip(pcon, start_pcon)) if r > r0 + CONSISTENCY_TOLERANCE]
        if worse:
            fail.append(f"the photos agree less on the result than on the start in views {worse[:10]}"
                        f"{' ...' if len(worse) > 10 else ''} (photo-consistency residual "
                        f"{', '.join(f'{pcon[i]:.3f} > {start_pcon[i]:.3f}' for i in worse[:5])}): the surface moved "
                        "where the photos do not show it")
        consistency_measured = consistency_measured or bool(np.isfinite(pcon).any())
    perr = None
    if e.appearance is not None:
        perr = every(scores.photo_error)
        med = float(np.nanmedian(perr))
        if not med <= max_photo_error:
            (warn if consistency_measured else fail).append(
                f"photometric error {med:.3f} (median over the views) is above {max_photo_error}: Lambertian shading "
                "under one distant light does not explain the photos" + (
                    " (specular or unevenly lit?); the geometry is judged by photo-consistency" if consistency_measured
                    else ""))
        odd = [i for i, e in enumerate(perr) if e > 2.0 * med + 0.02]
        if odd:
            warn.append(f"photo views {odd} fit far worse than the rest (error {', '.join(f'{perr[i]:.3f}' for i in odd)}"
                        f" against a median of {med:.3f}): exposure or lighting changed between views?")
    return Verdict(iou, start_iou, nerr, not fail, fail + warn, perr, pcon, start_pcon)


def judged_as_written(history: History, evidence: Evidence, options: ReconstructOptions) -> tuple[History, Verdict]:
    """`history` with the verdict on `evidence.result`, the mesh a run writes when stages after its
    fit changed the fitted one (`reconstruct`'s outline, depth, unseen surface, subdivision): its
    per-view scores replace the fitted mesh's, and what it fails or warns of that the fitted mesh did
    not is added, so `ok` holds only when both pass (the photo-consistency residual stays the fit's)."""
    measured = history.photo_consistency is not None and bool(np.isfinite(history.photo_consistency).any())
    v = judge(evidence, options, consistency_measured=measured)
    known = {w[:32] for w in history.warnings}
    new = [f"the mesh written: {w}" for w in v.warnings if w[:32] not in known]
    return dataclasses.replace(history, silhouette_iou=v.silhouette_iou, normal_error_deg=v.normal_error_deg,
                               photo_error=v.photo_error if v.photo_error is not None else history.photo_error,
                               ok=history.ok and v.ok, warnings=history.warnings + new), v
