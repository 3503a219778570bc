"""The first stage of `reconstruct`: checked targets, the canonical frame, the genus, the settings.

`prepare` validates the images once (`capture.check_targets`), maps the cameras to the
canonical frame (the visual hull centred, about unit size: units and placement never
matter), measures the world size of a pixel there (options are in pixels), estimates
the genus when none is given, switches to `options.fine()` when the visual hull is
thinner than `fine_below` pixels of the level the first cycles fit, and raises the face budget of
photos that resolve more detail than `max_faces` holds (`detail_budget`). Its `Setup` is all
that later stages read of the inputs; refits reuse it.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxgenus.capture import (TARGET_KINDS, SceneFrame, Targets, carved_occupancy, check_region, check_targets, consistent_depths,
                              cut_views, hull_occupancy, hull_thickness, pixel_footprint, region_misses, scene_frame,
                              stereo_depths, visual_hull_bounds)
from jaxgenus.geometry import Cameras
from jaxgenus.optim import (albedo_edges, gathered_views, pyramid_level, resolution_factors, scaled_cameras,
                            view_neighbours)
from jaxgenus.pipeline._history import GenusEstimate, Plan
from jaxgenus.pipeline._options import ReconstructOptions
from jaxgenus.pipeline._start import CLOSINGS, HullTable, estimate_genus

__all__ = ["DETAIL_EDGE", "FINE_TEXTURE", "STEREO_SIZE", "TEXTURE_FACES", "TEXTURE_SETTINGS", "Setup", "detail_budget", "downsampled", "fine_texture",
           "hull_factor", "prepare", "texture_share"]

#: Photo-consistency places the surface to a fraction of a pixel where the photos carry texture: the
#: edge length, in pixels of the fitted images, that `detail_budget` sizes the face budget for (the
#: finest level `detail_floor` fits photos at with photo-consistency is a quarter of the edge).
DETAIL_EDGE = 4.0
#: Plane-sweep stereo for the start runs on the fitted photos downsampled until their longer side is
#: at most this many pixels (DTU scan24, 41 views: 200x150, about 40 s on 2 CPU cores).
STEREO_SIZE = 256
#: `reconstruct(..., region=)`: the share of a view's silhouette whose rays may miss the sphere (mask
#: edges, a pixel of blur).
_REGION_SLACK = 0.01


@dataclasses.dataclass(frozen=True)
class Setup:
    """What `prepare` found: the stages after it read the inputs only through this.

    Attributes:
        images: the images fitted: the caller's (read, never modified), or their copies
            downsampled by `options.downsample`.
        targets: the validated `Targets`.
        world_cams: the cameras of `images` (the caller's, scaled with a downsample); cams: the
            same in the canonical frame.
        frame: the canonical frame (`x_world = scale * x + centre`).
        bounds: `(lo, hi)` of the visual hull in the canonical frame.
        pixel: world size (canonical units) of one pixel at the hull's centre.
        hulls: the visual hulls of the run (built on first use, shared by the genus
            estimate and the start).
        genus: the requested or estimated genus.
        estimate: the `GenusEstimate` when the genus was estimated, else None.
        thickness: the visual hull's thickness in pixels of the images (None when
            `fine_below` is 0).
        fine: the run switched to `options.fine()`.
        options: the settings that run (the caller's, or their `fine()`; the face budget of
            `detail_budget`).
        notes: what the run should warn of, found here (views cut by the frame).
        held: the views (indices into `cams`) `images` and `targets` hold when this process
            holds only some (`reconstruct(..., views=)`); None: all of them.
        stereo: photo targets: `(depths (N, h, w), factor)`, the plane-sweep depths (of every view)
            (canonical frame; NaN: none) of `targets.fit` downsampled by `factor`; else None.
        resolved: the faces the photos resolve (`detail_budget`); 0 where not counted.
        choices: the lines of the choices made here (the thin-structure switch, the face budget).
        plan: the run's `Plan` (`pipeline._schedule.planned`), None until it is made.
    """

    images: object
    targets: Targets
    world_cams: Cameras
    cams: Cameras
    frame: SceneFrame
    bounds: tuple[np.ndarray, np.ndarray]
    pixel: float
    hulls: HullTable
    genus: int
    estimate: GenusEstimate | None
    thickness: float | None
    fine: bool
    options: ReconstructOptions
    notes: tuple[str, ...] = ()
    held: np.ndarray | None = None
    stereo: tuple[np.ndarray, int] | None = None
    resolved: int = 0
    choices: tuple[str, ...] = ()
    plan: Plan | None = None

    def held_cams(self) -> Cameras:
        """The cameras (canonical frame) of the views this process holds."""
        return self.cams if self.held is None else self.cams[self.held]

    def all_views(self, local) -> np.ndarray:
        """A per-view array of the views held here completed with every other process's views."""
        return gathered_views(local, self.held, len(self.cams))


def _cut_note(alpha, say: Callable[[str], None]) -> tuple[str, ...]:
    """A note when silhouettes touch their image's border: the object runs out of the frame there."""
    cut = cut_views(alpha)
    if not cut.any():
        return ()
    line = (f"{int(cut.sum())} of {len(cut)} masks touch the image border: the object runs out of the frame there, so "
            "the visual hull keeps what those views do not show")
    say(line)
    many = cut.sum() > 0.25 * len(cut)
    return (line + "; the genus estimate and the start are weaker",) if many else ()


def _estimated(hulls: HullTable, options: ReconstructOptions, say: Callable[[str], None]) -> GenusEstimate:
    estimate = estimate_genus(hulls, options.hull_resolutions)
    grids = "; ".join(f"{r}: {', '.join(str(e.genus) for e in estimate.evidence if e.resolution == r)}"
                      for r in options.hull_resolutions)
    say(f"genus: estimated {estimate.genus} from the visual hull, {estimate.agreement:.0%} of the grids agree "
        f"(genus per closing of 0-{CLOSINGS[-1]} cells on grid {grids})"
        + (f"; low agreement, plausible: {list(estimate.plausible)}: give the genus if you know it"
           if estimate.agreement < 0.5 else ""))
    return estimate


def _thin(cams: Cameras, hulls: HullTable, pixel: float, options: ReconstructOptions, say) -> tuple[float | None, bool]:
    """The hull's thickness in image pixels, and whether it is under `fine_below` pixels of
    the level the first cycles fit (a structure thin there needs fine() even when the
    images themselves resolve it)."""
    if options.fine_below <= 0:
        return None, False
    hull = hulls.get(options.hull_resolutions[0], 0)[0]
    thickness = math.inf if hull is None else hull_thickness(None, cams, options.hull_resolutions[0], pixel, hull=hull)
    coarse = resolution_factors(cams.height, cams.width, 1, options.coarse_resolution, 0)[0]
    if thickness / coarse >= options.fine_below:
        return thickness, False
    level = f" ({thickness:.2f} px of the images)" if coarse > 1 else ""
    say(f"thin structure: the visual hull is {thickness / coarse:.2f} px thick at the fitted level{level} "
        f"(< {options.fine_below}): fine() settings")
    return thickness, True


def detail_budget(options: ReconstructOptions, kind: str, hull, pixel: float) -> tuple[int, int]:
    """`(budget, resolved)`: the face budget of a run and the faces its images resolve. Photos fitted
    with photo-consistency (`consistency > 0`) resolve about
    `area / (sqrt(3) / 4 * (DETAIL_EDGE * pixel)^2)` faces on the visual hull `hull` (its area in
    faces of `DETAIL_EDGE`-pixel edges). When that is 4 x `max_faces` or more (at the budget, edges
    of 8 px or longer: the photos' finest levels are left out, `detail_floor`), the budget rises
    towards it, to at most `options.detail_faces` (a multiple of 1000). Otherwise, and when `hull`
    is None or `detail_faces` is not above `max_faces`: `max_faces` (docs/results.md, "Photo-consistency": "The face
    budget follows the images")."""
    budget = options.face_budget
    if (kind != "photo" or not options.remesh or options.detail_faces <= budget or hull is None
            or "max_faces" in options.held
            or options.consistency <= 0):
        return budget, 0
    v, f = hull.to_numpy()
    v = np.asarray(v, np.float64)
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum()
    resolved = int(area / (math.sqrt(3.0) / 4.0 * (DETAIL_EDGE * pixel) ** 2))
    if resolved < 4 * budget:
        return budget, resolved
    return max(budget, min(options.detail_faces, resolved // 1000 * 1000)), resolved


def _detailed(options: ReconstructOptions, tg: Targets, n_views: int, hulls: HullTable, pixel: float,
              say, held: np.ndarray | None = None) -> tuple[ReconstructOptions, int]:
    """`(options, resolved)`: `options` with the face budget of `detail_budget` (said when raised), or,
    for photos of a fine texture (`FINE_TEXTURE` at full size) that resolve fewer faces than
    `max_faces`, lowered towards that count, to no less than `TEXTURE_FACES` of it (said)."""
    budget, resolved = detail_budget(options, tg.kind, hulls.get(options.hull_resolutions[0], 0)[0], pixel)
    if (0 < resolved < budget and options.fine_texture and "max_faces" not in options.held
            and texture_share(tg.fit, held, n_views) >= FINE_TEXTURE):
        lower = max(options.initial_faces, int(round(TEXTURE_FACES * budget)) // 1000 * 1000, resolved // 1000 * 1000)
        if lower < budget:
            say(f"face budget: {lower} faces (photos of a fine texture that resolve about {resolved} at "
                f"{DETAIL_EDGE:g} px edges; max_faces {budget}, held when given by name)")
            return options.replaced(max_faces=lower), resolved
    if budget <= options.face_budget:
        return options, resolved
    say(f"face budget: {budget} faces (the photos resolve about {resolved} at {DETAIL_EDGE:g} px edges; "
        f"max_faces {options.face_budget}, at most detail_faces {options.detail_faces}; max_faces given by name "
        "holds)")
    return options.replaced(max_faces=budget), resolved


#: Photos whose albedo edges cover this share of their masks or more are of a fine texture: finer than
#: the per-vertex albedo holds (`ReconstructOptions.fine_texture`).
FINE_TEXTURE = 0.3
#: The settings photos of a fine texture fit with (`fine_texture`), measured on DTU scan24 and the
#: synthetic photo pair (docs/results.md, "Shading ratios", "The closing polish", "Five cycles for a
#: fine texture", ...): the albedo-free shading ratios on; the
#: silhouettes weighed more (the outline the masks give is what shading cannot confuse); the
#: photometric term less (a per-vertex albedo cannot hold the texture, photo-consistency does better
#: with less shading); photo-consistency compared unblurred (a blur in each photo's own pixels biases
#: NCC where two views foreshorten the texture differently); the stereo depths pulling harder (the
#: only term whose basin reaches a concavity pixels deep, and a fine texture is where they are right;
#: "A heavier stereo term"); two closing polish cycles; one more cycle; curvature-adaptive remeshing.
TEXTURE_SETTINGS = {"shading_ratio": 6.0, "alpha": 4.0, "photo": 1.0, "consistency_blur": 0.0, "stereo": 16.0,
                    "polish_cycles": 2, "n_cycles": 5, "adaptive": True}
#: Photos of a fine texture that resolve fewer faces than `max_faces` (not held) get a budget lowered
#: to that count, to no less than this share of `max_faces`.
TEXTURE_FACES = 2.0 / 3.0


def texture_share(photos, held: np.ndarray | None = None, n_views: int = 0) -> float:
    """The share of the pixels inside the masks of `photos (N, H, W, 4)` (premultiplied RGBA) that sit
    on an albedo edge (`albedo_edges(..., band=0)`), over every view (views taken a few at a time).
    `held`: the views `photos` holds when this process holds only some of `n_views`: the counts of
    every process's views are put together (`gathered_views`)."""
    counts = np.zeros((len(photos), 2), np.int64)  # per view: pixels on an edge, pixels inside
    for i in range(0, len(photos), 4):
        chunk = np.asarray(photos[i:i + 4], np.float32)
        mask = chunk[..., 3] >= 0.5
        counts[i:i + 4, 0] = np.sum(np.asarray(albedo_edges(jnp.asarray(chunk), band=0)) & mask, axis=(1, 2))
        counts[i:i + 4, 1] = np.sum(mask, axis=(1, 2))
    marked, inside = gathered_views(counts, held, n_views).sum(axis=0)
    return int(marked) / max(int(inside), 1)


def fine_texture(options: ReconstructOptions, kind: str, photos, say: Callable[[str], None],
                 resolved: int = 0, share: float | None = None) -> ReconstructOptions:
    """`options` for a fit whose finest level is `photos (N, H, W, 4)` (premultiplied), when their albedo
    edges cover `FINE_TEXTURE` of the masks or more (said when changed; photo targets and
    `options.fine_texture`; `photos` of every view, also where a process holds only some): each setting of
    `TEXTURE_SETTINGS` not in `options.held` at that value, but the colour terms (`consistency_blur`,
    `polish_cycles`) only with photo-consistency on, `stereo` only when on, and `n_cycles` only where
    the photos resolve fewer than 4 x the faces of the budget (`resolved`, `detail_budget`'s count; 0: not counted) and
    it is not more already. The share is measured on the images the fit sees: a texture the finest
    level blurs away is no fine texture. `share`: `texture_share(photos)` when measured already."""
    if kind != "photo" or not options.fine_texture:
        return options
    now = {k: getattr(options, k) for k in TEXTURE_SETTINGS}
    colour = options.consistency > 0
    skip = {"consistency_blur": not colour, "polish_cycles": not colour, "adaptive": not options.remesh,
            "stereo": options.stereo <= 0,
            "n_cycles": resolved >= 4 * options.face_budget or now["n_cycles"] >= TEXTURE_SETTINGS["n_cycles"]}
    change = {k: v for k, v in TEXTURE_SETTINGS.items()
              if k not in options.held and not skip.get(k, False) and now[k] != v}
    if not change:
        return options
    share = texture_share(photos) if share is None else share
    if share < FINE_TEXTURE:
        return options
    say(f"fine texture: albedo edges cover {share:.0%} of the masks of the finest images fitted "
        f"(>= {FINE_TEXTURE:.0%}): " + ", ".join(f"{k}={v!r}" for k, v in change.items())
        + " (each held when given by name; fine_texture=False: none)")
    return options.replaced(**change)


def _stereo_carve(tg: Targets, cams: Cameras, bounds, alpha, hull_cams: Cameras, options: ReconstructOptions, say,
                  region=None, held=None):
    """`(carve, stereo)`: the carving of the visual hull by plane-sweep stereo of the photos
    (`ReconstructOptions.stereo_carve`) as a map of occupancy grids, and `Setup.stereo`; `(None, None)`
    for other targets, or with `stereo_carve` and the `stereo` weight 0. `held`: the views `tg` holds when
    this process holds only some (every process then sweeps every view's photos at the stereo's size).
    The carving needs photos of a fine texture at the stereo size (`FINE_TEXTURE`): on smooth shading
    two views agree on wrong depths too, and a wrong carve takes true volume from the start."""
    if tg.kind != "photo" or (options.stereo_carve <= 0 and options.stereo <= 0):
        return None, None
    factor = 1
    while max(cams.height, cams.width) / factor > STEREO_SIZE:
        factor *= 2
    # averaged as normal maps are (premultiplied colour plus mid-grey for a block's uncovered share): the
    # stereo's measured input, kept to the bit (docs/results.md, "The stereo's input")
    photos = gathered_views(np.asarray(pyramid_level(tg.fit, factor, normals=True)), held, len(cams))  # every view's
    scaled = scaled_cameras(cams, factor)
    share, why = texture_share(photos) if options.stereo_carve > 0 else 1.0, ""
    if share < FINE_TEXTURE:
        why = (f"; no carving: albedo edges cover {share:.0%} of the masks, under {FINE_TEXTURE:.0%} (two views "
               "can agree on wrong depths of smooth shading)")
        options = options.replaced(stereo_carve=0.0)
        if options.stereo <= 0:
            say("stereo: off" + why)
            return None, None
    coarse = hull_occupancy(alpha, hull_cams, resolution=32, bounds=bounds, region=region)
    table = view_neighbours(scaled, points=coarse.lo + coarse.cell * np.argwhere(coarse.values >= 0.5))
    depths = consistent_depths(stereo_depths(photos, scaled, table, bounds), scaled, table)
    kept = float(np.mean(np.isfinite(depths.depth[photos[..., 3] >= 0.5])))
    said = []

    if options.stereo_carve <= 0:
        say(f"stereo: depths of {kept:.0%} of the masks' pixels at {scaled.width}x{scaled.height}, two views agreeing"
            + why)

    def carve(grid):
        carved, share = carved_occupancy(grid, depths, scaled, margin=options.stereo_carve * grid.cell)
        if not said:
            said.append(share)
            say(f"stereo: depths of {kept:.0%} of the masks' pixels at {scaled.width}x{scaled.height}, two views "
                f"agreeing; they empty {share:.1%} of the visual hull (stereo_carve=0: off)")
        return carved

    return (carve if options.stereo_carve > 0 else None), (depths.depth, factor)


def hull_factor(alpha, resolutions: tuple[int, ...]) -> int:
    """The pyramid factor the silhouettes are read at for the frame, the bounds and the visual hulls:
    the largest power of two that leaves the silhouettes' median extent (the longer side of their
    bounding boxes) at least 2 pixels per cell of the finest hull grid. Finer pixels than that add
    nothing a grid point can sample, and the same capture given at its own size or downsampled then
    reads the same silhouettes (same frame, same start). 1 for small images."""
    return _factor(_extents(alpha), resolutions)


def _extents(alpha) -> np.ndarray:
    """Per view, the longer side of the silhouette's bounding box in pixels (0: an empty one)."""
    a = np.asarray(alpha) >= 0.5
    rows, cols = a.any(axis=2), a.any(axis=1)
    return np.array([max(np.ptp(np.flatnonzero(r)), np.ptp(np.flatnonzero(c))) + 1 if r.any() else 0
                     for r, c in zip(rows, cols)], np.int64)


def _factor(extents: np.ndarray, resolutions: tuple[int, ...]) -> int:
    extent = extents[extents > 0]
    if not len(extent):
        return 1
    ratio = float(np.median(extent)) / (2.0 * max(resolutions))
    return 2 ** int(math.floor(math.log2(ratio))) if ratio >= 2 else 1


def _straight(tg: Targets, fit: np.ndarray) -> np.ndarray:
    """Images as `reconstruct` takes them from a `fit` array of `tg`'s kind (photos: straight colours)."""
    if tg.kind != "photo":
        return np.ascontiguousarray(fit, np.float32)
    a = fit[..., 3:]
    return np.concatenate([np.where(a > 0, fit[..., :3] / np.maximum(a, 1e-6), 0.0), a], axis=-1).astype(np.float32)


def _downsampled_targets(tg: Targets, factor: int) -> tuple[np.ndarray, Targets]:
    """The images and `Targets` of `tg` area-averaged over `factor x factor` blocks. The targets are
    the pyramid level itself (not re-read from the straight images), so the levels a run fits below
    them are those of the full-size run to the bit."""
    fit = pyramid_level(tg.fit, factor, normals=tg.kind == "normals")
    normals = None if tg.normals is None else fit[..., :3] * 2.0 - 1.0
    return _straight(tg, fit), Targets(tg.kind, fit[..., -1], normals, fit, tg.inferred)


def downsampled(images, cams: Cameras, factor: int, targets: str | None = None) -> tuple[np.ndarray, Cameras]:
    """`images` area-averaged over `factor x factor` blocks (as `reconstruct` takes them: silhouettes,
    RGBA normal maps or straight RGBA photos) and the cameras of those copies."""
    small, _ = _downsampled_targets(check_targets(images, cams, targets), factor)
    return small, scaled_cameras(cams, factor)


def _held(views, images, cams: Cameras) -> np.ndarray | None:
    """`views` checked: None, or the increasing indices into `cams` of the views `images` holds."""
    if views is None:  # across processes each holds all views: the steps that gather still meet
        return None if jax.process_count() == 1 else np.arange(len(cams))
    held, n_images = np.asarray(views), len(np.shape(images)) and np.shape(images)[0]
    if len(held) == 0:
        raise ValueError("views: empty; a process must hold at least one view")
    if held.ndim != 1 or not np.issubdtype(held.dtype, np.integer) or len(held) != n_images:
        raise ValueError(f"views: expected {n_images} view indices (one per image), got an array of shape "
                         f"{held.shape} and dtype {held.dtype}")
    if len(held) and (held.min() < 0 or held.max() >= len(cams) or np.any(np.diff(held) <= 0)):
        raise ValueError(f"views: expected increasing indices into the {len(cams)} cameras, got {held.tolist()[:10]}")
    return held.astype(np.int64)


def _region_checked(region, alpha, cams: Cameras, say):
    """`region` checked (`check_region`) against the silhouettes `alpha` of `cams`: every view's must
    lie inside the sphere (its rays must meet it); else a `ValueError` naming the worst view."""
    region = check_region(region)
    if region is None:
        return None
    misses = region_misses(alpha, cams, region)
    worst = int(np.argmax(misses))
    if misses[worst] > _REGION_SLACK:
        raise ValueError(f"region: the sphere (centre {np.round(region[0], 6).tolist()}, radius {region[1]:.6g}) misses "
                         f"{misses[worst]:.0%} of the silhouette of view {worst}: the object must lie inside it, in "
                         "the cameras' units and frame")
    say(f"region: the object lies in the sphere of centre {np.round(region[0], 6).tolist()}, radius {region[1]:.6g}; "
        "the visual hull is cut to it")
    return region


def prepare(images, cams: Cameras, genus: int | None, targets: str | None, options: ReconstructOptions,
            say: Callable[[str], None], views=None, region=None) -> Setup:
    """The `Setup` of a run (see the module doc); `say(line)` reports each finding. `views`: the
    indices into `cams` of the views `images` holds, when this process holds only some (the
    others are held by the other processes joined by `jax.distributed`). `region`: a sphere
    `(centre, radius)` of the world the object lies in (`reconstruct`), or None."""
    held = _held(views, images, cams)
    tg = check_targets(images, cams if held is None else cams[held], targets)
    if held is not None:  # every process must fit the same kind of targets
        kinds = gathered_views(np.full(len(held), TARGET_KINDS.index(tg.kind)), held, len(cams))
        if len(set(kinds.tolist())) > 1:
            raise ValueError(f"targets: the processes' images read as different kinds "
                             f"({sorted({TARGET_KINDS[k] for k in kinds})}); give targets=")
    if options.downsample > 1:
        big, cams = cams, scaled_cameras(cams, options.downsample)
        images, tg = _downsampled_targets(tg, options.downsample)
        say(f"downsample: fitting {big.width}x{big.height} images as {cams.width}x{cams.height} copies "
            f"(1/{options.downsample}), cameras scaled to match")
    factor = _factor(gathered_views(_extents(tg.alpha), held, len(cams)), (48,) + tuple(options.hull_resolutions))
    alpha = gathered_views(pyramid_level(tg.alpha[..., None], factor)[..., 0], held, len(cams))
    if held is not None:
        say(f"views: this process holds {len(held)} of {len(cams)} views; the silhouettes of all at 1/{factor} "
            "for the frame and the visual hulls")
    region = _region_checked(region, alpha, scaled_cameras(cams, factor), say)
    frame = scene_frame(alpha, scaled_cameras(cams, factor), region=region)
    canonical, region = frame.cameras_to_canonical(cams), frame.region_to_canonical(region)
    say(f"frame: object centre {np.round(frame.centre, 6).tolist()}, radius {frame.scale:.6g} (user units); "
        f"targets {tg.kind}{' (inferred)' if tg.inferred else ''}"
        + (f"; silhouettes read at 1/{factor} for the frame and the visual hulls" if factor > 1 else ""))
    hull_cams = scaled_cameras(canonical, factor)
    lo, hi = visual_hull_bounds(alpha, hull_cams, region=region)
    pixel = pixel_footprint(canonical, 0.5 * (lo + hi))
    carve, stereo = _stereo_carve(tg, canonical, (lo, hi), alpha, hull_cams, options, say, region, held)
    hulls = HullTable(alpha, hull_cams, (lo, hi), carve, region)
    notes = _cut_note(alpha, say)
    estimate = _estimated(hulls, options, say) if genus is None else None
    chose = []

    def decide(line):
        chose.append(line)
        say(line)

    thickness, fine = _thin(canonical, hulls, pixel, options, decide)
    options, resolved = _detailed(options.fine() if fine else options, tg, len(cams), hulls, pixel, decide, held)
    return Setup(images=images, targets=tg, world_cams=cams, cams=canonical, frame=frame, bounds=(lo, hi),
                 pixel=pixel, hulls=hulls, genus=int(genus if estimate is None else estimate.genus),
                 estimate=estimate, thickness=thickness, fine=fine, options=options,
                 notes=notes, held=held, stereo=stereo, resolved=resolved, choices=tuple(chose))
